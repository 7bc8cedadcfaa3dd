"""Scheduling priority of the browser view's server process."""

from __future__ import annotations

import logging
import os

log = logging.getLogger(__name__)

__all__ = ["idle_priority"]


def _threads() -> list[int]:
    """Native ids of every thread of this process (Linux), else [0] (the calling thread)."""
    try:
        return [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        return [0]


def idle_priority() -> None:
    """Run this process at the lowest ordinary priority (nice 19) for every thread it has (imported libraries start
    worker pools: OpenCV, BLAS) and, inherited, every thread it starts later; no-op where not permitted.

    Not Linux's SCHED_IDLE: with every core busy (other jobs on the rig PC, a test suite) an idle-class process
    gets no CPU at all and the page stops answering. At nice 19 it weighs 15 against a normal process's 1024 in
    the scheduler: the capture loop keeps its cadence and the page still answers, slowly.
    """
    for tid in _threads():
        try:
            os.setpriority(os.PRIO_PROCESS, tid, 19)
        except (AttributeError, OSError) as exc:  # pragma: no cover - not permitted
            log.debug("web view: could not lower the priority of thread %d (%s)", tid, exc)
