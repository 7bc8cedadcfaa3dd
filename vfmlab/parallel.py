"""Independent computations of one command on the machine's cores: :func:`fork_map`.

The bootstrap of ``vfmlab identify`` re-identifies 16 re-simulated measurements, each independent of
the others (~40 ms each on a rendered session): on two idle cores half of them run in a forked child
(benchmarks/bench_cli.py). Forking, not a process pool: the child inherits the loaded modules and the
prepared data, so nothing is imported or pickled on the way in, only the small results on the way out.
"""

from __future__ import annotations

import logging
import os
import pickle
import signal
import threading
from collections.abc import Callable, Iterable
from typing import Any

log = logging.getLogger(__name__)

__all__ = ["fork_map", "usable_cores"]


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - no affinity on this platform
        return max(1, os.cpu_count() or 1)


def fork_map(fn: Callable[[Any], Any], items: Iterable[Any], workers: int | None = None) -> list:
    """``list(map(fn, items))``, the items shared out between this process and forked children.

    The results, and any exception ``fn`` raises, are those of the builtin ``map`` (same order, same
    values: each item is computed by the same code on the same data); only the wall time differs.
    Items are dealt round-robin to ``workers`` processes (default: the usable cores, at most the
    number of items); this process computes its own share, then collects the children's. A child
    that fails (killed, out of memory, an exception in ``fn``) has its share recomputed here, so an
    exception surfaces exactly as in ``map``.

    Serial (the builtin ``map``) where forking is unsafe or useless: one core, one item, no
    ``os.fork``, or other threads running in this process (a forked child would inherit their locks).
    """
    items = list(items)
    n = min(usable_cores() if workers is None else int(workers), len(items))
    if n < 2 or not hasattr(os, "fork") or threading.active_count() > 1:
        return [fn(item) for item in items]
    shares = [list(range(k, len(items), n)) for k in range(n)]
    children: list[dict] = []
    results: list[Any] = [None] * len(items)
    try:
        for share in shares[1:]:
            pid, fd = _fork_share(fn, [items[i] for i in share])
            children.append({"pid": pid, "fd": fd, "share": share, "reaped": False})
        for i in shares[0]:
            results[i] = fn(items[i])
        for child in children:
            values = _collect(child, len(child["share"]))
            if values is None:  # the child failed: its share computed here, exceptions and all
                values = [fn(items[i]) for i in child["share"]]
            for i, value in zip(child["share"], values):
                results[i] = value
    finally:
        for child in children:
            _discard(child)
    return results


def _fork_share(fn: Callable[[Any], Any], items: list) -> tuple[int, int]:
    """Fork a child computing ``fn`` over ``items``; (pid, read end of its result pipe)."""
    read_fd, write_fd = os.pipe()
    main_thread = threading.current_thread() is threading.main_thread()
    if main_thread:  # Ctrl-C during fork() would be raised in an at-fork hook and lost: hold it
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        pid = os.fork()
        if pid == 0:  # the child: never returns into the caller's code; SIGINT stays blocked (the parent kills it)
            code = 0
            try:
                os.close(read_fd)
                payload = pickle.dumps([fn(item) for item in items], protocol=pickle.HIGHEST_PROTOCOL)
                with os.fdopen(write_fd, "wb") as out:
                    out.write(payload)
            except BaseException:  # noqa: BLE001 - the parent recomputes this share and sees the error itself
                code = 3
            os._exit(code)
    finally:
        if main_thread:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    os.close(write_fd)
    return pid, read_fd


def _collect(child: dict, n: int) -> list | None:
    """The child's ``n`` results (read to the end of its pipe, then reaped), or None if it failed."""
    chunks = []
    while True:
        chunk = os.read(child["fd"], 1 << 16)
        if not chunk:
            break
        chunks.append(chunk)
    _, status = os.waitpid(child["pid"], 0)
    child["reaped"] = True
    if not (os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0):
        log.debug("fork_map: worker %d failed (wait status %d); its share is recomputed", child["pid"], status)
        return None
    try:
        values = pickle.loads(b"".join(chunks))
    except Exception:  # noqa: BLE001 - a truncated or garbled result: recompute
        return None
    return values if isinstance(values, list) and len(values) == n else None


def _discard(child: dict) -> None:
    """Close the pipe and make sure the child is gone (killed if not reaped yet, then reaped)."""
    try:
        os.close(child["fd"])
    except OSError:
        pass
    if not child["reaped"]:  # an exception (or Ctrl-C) here before its results were collected
        try:
            os.kill(child["pid"], signal.SIGKILL)
            os.waitpid(child["pid"], 0)
        except OSError:
            pass
        child["reaped"] = True
