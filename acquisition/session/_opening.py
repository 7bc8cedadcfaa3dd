"""Opening a session file's HDF5 for reading: waiting for result writers' locks, SWMR for a live
writer, and telling a truncated file from one caught mid-append."""

from __future__ import annotations

import fcntl
import time
from pathlib import Path

import h5py

from acquisition.session._locks import LockTimeout, lock_timeout, wait_lock
from acquisition.session._schema import SessionError


def _h5_open_read(path: Path) -> h5py.File:
    """``h5py.File(path, "r")``, waiting (bounded: the lock timeout in all) while other jobs append results.

    Raises :class:`LockTimeout` when they hold the file longer than that.
    """
    deadline = time.monotonic() + lock_timeout()
    while True:
        try:
            return _h5_open_read_once(path)
        except OSError as exc:
            if "unable to lock file" not in str(exc):
                raise
        # Another job is appending a result (an exclusive lock for a moment): wait for it, then open
        # again; a third job may take the lock in between (1 open in ~30 with 6 concurrent writers), so loop.
        with open(path, "rb") as fh:
            wait_lock(fh.fileno(), path, exclusive=False, what="read", timeout=max(0.0, deadline - time.monotonic()))
            fcntl.flock(fh.fileno(), fcntl.LOCK_UN)


def _h5_open_read_once(path: Path) -> h5py.File:
    try:
        return h5py.File(path, "r")
    except OSError as exc:
        if "already open for write" in str(exc):
            # A live SWMR writer, or one killed mid-session: SWMR readers see a consistent file.
            return h5py.File(path, "r", libver=("v110", "v110"), swmr=True)
        raise


def _open_possibly_growing(path: Path) -> h5py.File:
    """The HDF5 file opened for reading; a SessionError naming a truncated or damaged file.

    A file a live writer is appending to looks truncated to a reader that catches it mid-append
    (about 1 open in 25 against a writer appending continuously): if the file grew meanwhile it is
    opened again (up to 3 times), so only a file that stays short is reported as truncated.
    """
    for attempt in range(4):
        size = path.stat().st_size
        try:
            return _h5_open_read(path)
        except LockTimeout as exc:
            raise SessionError(str(exc)) from None
        except OSError as exc:
            reason = str(exc)
        if not ("truncated" in reason or "eof" in reason.lower()):
            raise SessionError(f"{path}: damaged HDF5 file, cannot be opened ({reason})") from None
        if attempt < 3:
            time.sleep(0.05)
            if path.stat().st_size != size:
                continue
        raise SessionError(f"{path}: the file is truncated (incomplete copy or disk full?); cannot read it") from None
    raise AssertionError("unreachable")  # pragma: no cover
