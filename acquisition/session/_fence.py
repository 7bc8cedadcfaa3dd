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
import ctypes
import errno
import logging
import os
import re
from collections.abc import Iterator

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


def vfd_handle(f: h5py.File) -> int:
    """HDF5's file descriptor of ``f`` (-1 if unknown); read it while the file is sound."""
    try:
        return int(f.id.get_vfd_handle())
    except Exception:  # noqa: BLE001 - another driver
        return -1


def fence(f: h5py.File, fd: int, close: bool = True) -> None:
    """Close ``f`` without writing another byte to its file (see the module docstring).

    ``close=False`` when closing it is what failed: h5py must not close it twice (that crashes);
    HDF5 closes it at exit, its writes then going nowhere.
    """
    if fd >= 0:
        null = os.open(os.devnull, os.O_RDWR)
        try:
            os.dup2(null, fd)
        finally:
            os.close(null)
    if not close:
        return
    try:
        f.close()
    except Exception as exc:  # noqa: BLE001 - nothing reaches the file any more
        log.debug("closing a fenced file: %s", exc)


@contextlib.contextmanager
def fenced(f: h5py.File) -> Iterator[h5py.File]:
    """Use and close ``f``; a failed disk write on the way fences it and raises OSError (ENOSPC, EIO...)."""
    closing, fd = False, vfd_handle(f)
    try:
        yield f
        closing = True
        f.close()
    except Exception as exc:
        if not is_write_failure(exc):
            with contextlib.suppress(Exception):
                f.close()
            raise
        fence(f, fd, close=not closing)
        code = failure_errno(exc)
        raise OSError(code, os.strerror(code)) from None


#: Space allocated ahead of the writes beyond what they are estimated to need (HDF5 metadata), bytes.
MARGIN = 1 << 20


_libc: ctypes.CDLL | None = None


def _fallocate_keep_size(fd: int, offset: int, length: int) -> None:
    """Linux ``fallocate(FALLOC_FL_KEEP_SIZE)``: blocks reserved past the end, the file's size unchanged."""
    global _libc
    if _libc is None:
        _libc = ctypes.CDLL(None, use_errno=True)
        _libc.fallocate.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_longlong, ctypes.c_longlong]
    libc = _libc
    if libc.fallocate(fd, 1, offset, length) != 0:
        code = ctypes.get_errno()
        raise OSError(code, os.strerror(code))



def reserve(fd: int, nbytes: int) -> None:
    """Reserve the disk blocks for ``nbytes`` + :data:`MARGIN` past the file's end before HDF5 writes there.

    HDF5 then never meets a full disk (its error paths crash the process at exit): the disk-full
    error is raised here, before any write, as OSError(ENOSPC). The file's size is unchanged.
    """
    if fd < 0:
        return
    try:
        _fallocate_keep_size(fd, os.fstat(fd).st_size, int(nbytes) + MARGIN)
    except (OSError, AttributeError) as exc:
        code = getattr(exc, "errno", None)
        if code in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
            raise OSError(code, os.strerror(code)) from None
        # EOPNOTSUPP, no fallocate (not Linux): a file system that cannot reserve; the fence still guards
