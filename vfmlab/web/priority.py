"""Scheduling priority of the browser view (its server process, the run's feed thread)."""

from __future__ import annotations

import logging
import os

log = logging.getLogger(__name__)

__all__ = ["idle_priority"]


def idle_priority(tid: int = 0) -> None:
    """Run the calling process (``tid`` 0), or thread ``tid``, only on CPU time nobody else wants:
    Linux SCHED_IDLE (allowed without privileges), else the lowest nice value; no-op elsewhere.
    The capture loop of the run then never waits for the view, even on a machine with every core busy."""
    try:
        os.sched_setscheduler(tid, os.SCHED_IDLE, os.sched_param(0))  # type: ignore[attr-defined]
        return
    except (AttributeError, OSError) as exc:
        log.debug("web view: no SCHED_IDLE (%s); lowering the nice value instead", exc)
    try:
        os.setpriority(os.PRIO_PROCESS, tid, 19)
    except (AttributeError, OSError):  # pragma: no cover - not permitted
        pass
