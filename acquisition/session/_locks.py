"""Waiting file locks shared by the jobs that use one session (and its results folder).

HDF5 takes a shared ``flock`` for readers and an exclusive one for writers; :func:`wait_lock` waits
(bounded, with a message) for another vfmlab job instead of failing at once. Older versions kept a
rollback journal (``<file>.journal``) beside the session for result writes; results are now files
of their own (``_store``), so no journal is written, read, applied or deleted: a leftover one is the
user's file and is left alone.
"""

from __future__ import annotations

import errno
import fcntl
import logging
import os
import time
from pathlib import Path

__all__ = ["LockTimeout", "lock_timeout", "wait_lock", "LOCK_TIMEOUT_S", "legacy_journal"]

log = logging.getLogger(__name__)

#: How long a job waits for another job's lock on the same file, s (VFMLAB_LOCK_TIMEOUT_S overrides).
LOCK_TIMEOUT_S = 300.0
_LEGACY_MAGIC = b"VFMLAB-H5-JOURNAL-1\n"


class LockTimeout(OSError):
    """Another job held the file longer than the lock timeout."""


def legacy_journal(path: str | os.PathLike) -> Path | None:
    """``<file>.journal`` when an older vfmlab left a rollback journal beside ``path`` (never applied), else None."""
    jpath = Path(path).with_name(Path(path).name + ".journal")
    try:
        with open(jpath, "rb") as fh:
            return jpath if fh.read(len(_LEGACY_MAGIC)) == _LEGACY_MAGIC else None
    except OSError:
        return None


def lock_timeout() -> float:
    """How long (s) a job waits for another that holds the file: ``VFMLAB_LOCK_TIMEOUT_S`` or LOCK_TIMEOUT_S."""
    try:
        return float(os.environ.get("VFMLAB_LOCK_TIMEOUT_S", LOCK_TIMEOUT_S))
    except ValueError:
        return LOCK_TIMEOUT_S


def wait_lock(fd: int, path: str | os.PathLike, *, exclusive: bool, timeout: float | None = None,
              what: str = "write to") -> None:
    """``flock`` ``fd`` (shared or exclusive), waiting up to ``timeout`` s while another job holds it.

    Logs one warning when it has to wait; raises :class:`LockTimeout` naming the file and the
    time waited when the other job does not let go.
    """
    timeout = lock_timeout() if timeout is None else timeout
    mode = (fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH) | fcntl.LOCK_NB
    start = time.monotonic()
    warned = False
    while True:
        try:
            fcntl.flock(fd, mode)
            return
        except BlockingIOError:
            waited = time.monotonic() - start
            if waited >= timeout:
                raise LockTimeout(errno.EAGAIN, f"{path}: another vfmlab job is using the file; gave up after "
                                                f"waiting {waited:.0f} s (try again when it has finished)") from None
            if not warned:
                log.warning("%s: another job is using the file; waiting up to %.0f s to %s it", path, timeout, what)
                warned = True
            time.sleep(min(0.1, max(0.0, timeout - waited)))
