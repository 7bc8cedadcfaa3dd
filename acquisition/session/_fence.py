"""What the session writer does when a disk write fails (disk full, I/O error): stop writing, as a kill would.

After a failed write HDF5's in-memory state no longer matches the file, and every later flush (the
status written at the end, closing the file, the interpreter's exit) fails again; h5py then
crashed the process (a segmentation fault at exit). :func:`fence` instead points HDF5's file
descriptor at ``/dev/null`` and closes the file: the writes HDF5 still makes vanish, so the file on
disk stays exactly as it was at the failed write, which is what a process killed at that write
leaves: a session that opens, whose completed steps are intact, reported "interrupted" and resumed
by ``vfmlab resume`` once space is freed. (SWMR writes new data before the metadata that points to
it, so a write cut short at the end of the file is never referenced.)
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import re

import h5py

log = logging.getLogger("acquisition.session")

_FAILED_WRITE = re.compile(r"write failed|errno = (28|5|122)\b|No space left|Disk quota|Input/output error")


def is_write_failure(exc: BaseException) -> bool:
    """Is ``exc`` HDF5 (or the OS) reporting a failed disk write, rather than a programming error?"""
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EIO):
        return True
    return isinstance(exc, (OSError, RuntimeError, ValueError, KeyError)) and bool(_FAILED_WRITE.search(str(exc)))


def failure_errno(exc: BaseException) -> int:
    """The errno of a failed write (ENOSPC when HDF5 only says so in its message)."""
    if isinstance(exc, OSError) and exc.errno:
        return int(exc.errno)
    found = re.search(r"errno = (\d+)", str(exc))
    return int(found.group(1)) if found else errno.ENOSPC


def fence(f: h5py.File) -> None:
    """Close ``f`` without writing another byte to its file (see the module docstring)."""
    fd = None
    with contextlib.suppress(Exception):
        fd = int(f.id.get_vfd_handle())
    if fd is not None and fd >= 0:
        null = os.open(os.devnull, os.O_RDWR)
        try:
            os.dup2(null, fd)
        finally:
            os.close(null)
    try:
        f.close()
    except Exception as exc:  # noqa: BLE001 - nothing reaches the file any more
        log.debug("closing a fenced file: %s", exc)
