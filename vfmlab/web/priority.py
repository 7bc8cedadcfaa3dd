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
    """Run this process only on CPU time nobody else wants: Linux SCHED_IDLE (allowed without
    privileges) for every thread it has (imported libraries start worker pools: OpenCV, BLAS) and,
    inherited, every thread it starts later; else the lowest nice value; no-op elsewhere.
    The capture loop of the run then never waits for the view, even with every core busy."""
    for tid in _threads():
        try:
            os.sched_setscheduler(tid, os.SCHED_IDLE, os.sched_param(0))  # type: ignore[attr-defined]
            continue
        except (AttributeError, OSError) as exc:
            log.debug("web view: no SCHED_IDLE for thread %d (%s); lowering its nice value instead", tid, exc)
        try:
            os.setpriority(os.PRIO_PROCESS, tid, 19)
        except (AttributeError, OSError):  # pragma: no cover - not permitted
            pass
