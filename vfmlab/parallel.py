"""Independent computations of one command on the machine's cores: :func:`fork_map`.

The bootstrap of ``vfmlab identify`` re-identifies 16 re-simulated measurements, each independent of
the others (~15 ms each on a rendered session): this process and a forked child take them one after
the other as each is free, so on two idle cores each computes about half, and on a busy machine the
process that gets more CPU computes more (benchmarks/bench_cli.py). Forking, not a process pool: the child inherits the loaded modules and the
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
    The items are dealt as they are asked for: every process (this one and ``workers - 1`` children;
    default: the usable cores, at most the number of items) takes the next item when it has finished
    its last, so a worker that gets less of a busy machine computes fewer of them and nobody waits
    for a fixed share (``_Queue``). This process then collects the children's results. Items a child
    took but did not return (killed, out of memory, an exception in ``fn``) are computed here, so an
    exception surfaces exactly as in ``map``.

    Serial (the builtin ``map``) where forking is unsafe or useless: one core, one item, no
    ``os.fork``, or other threads running in this process (a forked child would inherit their locks).
    """
    items = list(items)
    n = min(usable_cores() if workers is None else int(workers), len(items))
    if n < 2 or not hasattr(os, "fork") or threading.active_count() > 1:
        return [fn(item) for item in items]
    queue = _Queue(len(items))
    children: list[dict] = []
    done: dict[int, Any] = {}
    try:
        for _ in range(n - 1):
            pid, fd = _fork_worker(fn, items, queue)
            children.append({"pid": pid, "fd": fd, "reaped": False})
        for i in queue:
            done[i] = fn(items[i])
        for child in children:
            done.update(_collect(child))
        return [done[i] if i in done else fn(items[i]) for i in range(len(items))]  # a failed child's: here
    finally:
        queue.close()
        for child in children:
            _discard(child)


class _Queue:
    """The indices 0 .. n-1 of the items, taken in order by any of the processes forked after it was made.

    A pipe holding one 4-byte token per block of consecutive indices (at most ``MAX_TOKENS`` blocks,
    so that all fit in the pipe before anyone reads): a ``read`` of 4 bytes is atomic between
    processes, and the write end is closed before the fork, so an empty pipe reads as the end.
    """

    MAX_TOKENS = 4096  # 16 KiB: within the smallest pipe buffer of Linux (64 KiB) and macOS (16 KiB)

    def __init__(self, n: int) -> None:
        self.block = -(-n // self.MAX_TOKENS)
        self.n = n
        self.read_fd, write_fd = os.pipe()
        try:
            os.write(write_fd, b"".join(k.to_bytes(4, "little") for k in range(-(-n // self.block))))
        finally:
            os.close(write_fd)

    def __iter__(self):
        while token := os.read(self.read_fd, 4):
            start = int.from_bytes(token, "little") * self.block
            yield from range(start, min(start + self.block, self.n))

    def close(self) -> None:
        try:
            os.close(self.read_fd)
        except OSError:
            pass


def _fork_worker(fn: Callable[[Any], Any], items: list, queue: _Queue) -> tuple[int, int]:
    """Fork a child computing ``fn`` over the items it takes from ``queue``; (pid, read end of its result pipe)."""
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
                payload = pickle.dumps({i: fn(items[i]) for i in queue}, protocol=pickle.HIGHEST_PROTOCOL)
                with os.fdopen(write_fd, "wb") as out:
                    out.write(payload)
            except BaseException:  # noqa: BLE001 - the parent recomputes what it took and sees the error itself
                code = 3
            os._exit(code)
    finally:
        if main_thread:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    os.close(write_fd)
    return pid, read_fd


def _collect(child: dict) -> dict:
    """The child's results ``{index: value}`` (read to the end of its pipe, then reaped); {} if it failed."""
    chunks = []
    while True:
        chunk = os.read(child["fd"], 1 << 16)
        if not chunk:
            break
        chunks.append(chunk)
    _, status = os.waitpid(child["pid"], 0)
    child["reaped"] = True
    if not (os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0):
        log.debug("fork_map: worker %d failed (wait status %d); its items are recomputed", child["pid"], status)
        return {}
    try:
        values = pickle.loads(b"".join(chunks))
    except Exception:  # noqa: BLE001 - a truncated or garbled result: recompute
        return {}
    return values if isinstance(values, dict) else {}


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
