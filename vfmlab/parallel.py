"""Independent computations of one command on the machine's cores: :func:`fork_map`.

The bootstrap of ``vfmlab identify`` re-identifies 16 re-simulated measurements, each independent of
the others (~15 ms each on a rendered session). :func:`fork_map` hands them to a
:class:`concurrent.futures.ProcessPoolExecutor` whose workers are forked: they inherit the loaded modules
and the prepared data (the function and its items are left in a module variable before the pool forks),
so nothing is imported or pickled on the way in, only the item indices and the small results. The items
are dealt one at a time (``chunksize=1``): a worker that gets less of a busy machine computes fewer.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import threading
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

log = logging.getLogger(__name__)

__all__ = ["fork_map", "usable_cores"]

#: (fn, items) of the running fork_map, read by the forked workers (set before the pool forks them)
_WORK: tuple[Callable[[Any], Any], list] | None = None


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - no affinity on this platform
        return max(1, os.cpu_count() or 1)


def _ignore_sigint() -> None:
    """Worker initializer: Ctrl-C is the parent's to handle (it stops the pool); a worker does not die of it."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _compute(i: int) -> Any:
    """In a worker: item ``i`` of the fork_map it was forked from."""
    if _WORK is None:  # pragma: no cover - fork_map sets it before the pool forks
        raise RuntimeError("_compute runs only in a worker forked by fork_map")
    fn, items = _WORK
    return fn(items[i])


def fork_map(fn: Callable[[Any], Any], items: Iterable[Any], workers: int | None = None) -> list:
    """``list(map(fn, items))``, the items computed by ``workers`` forked processes (default: the usable
    cores, at most the number of items).

    The results, and any exception ``fn`` raises, are those of the builtin ``map`` (same order, same
    values: each item is computed by the same code on the same data); only the wall time differs. Results
    must pickle. Items a worker did not return because it died (killed, out of memory) are computed here.

    Serial (the builtin ``map``) where forking is unsafe or useless: one core, one item, no fork start
    method, or other threads running in this process (a forked child would inherit their locks).
    """
    global _WORK
    items = list(items)
    n = min(usable_cores() if workers is None else int(workers), len(items))
    if (n < 2 or "fork" not in multiprocessing.get_all_start_methods() or threading.active_count() > 1
            or _WORK is not None):  # a fork_map inside a fork_map's item: serial
        return [fn(item) for item in items]
    _WORK = (fn, items)
    done: dict[int, Any] = {}
    pool = ProcessPoolExecutor(n, mp_context=multiprocessing.get_context("fork"), initializer=_ignore_sigint)
    try:
        futures = [pool.submit(_compute, i) for i in range(len(items))]
        for i, future in enumerate(futures):
            try:
                done[i] = future.result()
            except BrokenProcessPool:
                log.debug("fork_map: a worker died; item %d and those left are computed here", i)
                break
    finally:
        _WORK = None
        pool.shutdown(wait=True, cancel_futures=True)
    return [done[i] if i in done else fn(items[i]) for i in range(len(items))]
