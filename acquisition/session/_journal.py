"""Crash-safe appends to an existing HDF5 file: a rollback journal and a waiting file lock.

Appending a group to an HDF5 file rewrites metadata in place (superblock, B-tree nodes, object
headers, the free-space manager). A process killed, or a disk that fills, half-way through such
a write leaves a file HDF5 cannot open. :func:`journaled_h5` makes the append atomic the way
SQLite's rollback journal does:

1. ``<file>.journal`` is created with the file's original size and fsynced (and its folder);
2. every write that would overwrite bytes of the original file first copies the original
   4 KiB page into the journal (fsynced before the file is touched); writes past the original
   end need no copy: rolling back truncates them away;
3. commit = fsync the file, then delete the journal (the deletion is the commit point).

If the process dies between 1 and 3, the journal is "hot": :func:`recover` (called by every
reader before it opens the file, and by resume) copies the saved pages back and truncates the
file to its original size, which restores the file byte for byte. A journal record is only
trusted if its checksum verifies; a torn last record is from a page that was never overwritten.

Writers and readers share the file through advisory ``flock`` locks: HDF5 itself takes a shared
lock for readers and an exclusive one for writers, and :func:`wait_lock` waits (bounded, with a
message) for another vfmlab job instead of failing at once.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import logging
import os
import struct
import time
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path

import h5py

__all__ = ["JournalError", "LockTimeout", "WriteFailed", "journal_path", "journaled_h5", "lock_timeout", "recover",
           "wait_lock", "LOCK_TIMEOUT_S"]

log = logging.getLogger(__name__)

PAGE = 4096
_MAGIC = b"VFMLAB-H5-JOURNAL-1\n"
_HEADER = struct.Struct("<20sQ")  # magic, original size (bytes)
_RECORD = struct.Struct("<QII")  # page offset, length, crc32 of the data
#: How long a job waits for another job's lock on the same file, s (VFMLAB_LOCK_TIMEOUT_S overrides).
LOCK_TIMEOUT_S = 300.0


class JournalError(OSError):
    """A hot journal could not be rolled back (file not writable, journal unreadable)."""


class WriteFailed(OSError):
    """A journaled append failed on a disk write (and was rolled back); ``needed`` bytes it wanted."""

    def __init__(self, cause: OSError, needed: int):
        super().__init__(cause.errno, cause.strerror or str(cause))
        self.needed = needed


class LockTimeout(OSError):
    """Another job held the file longer than the lock timeout."""


def journal_path(path: str | os.PathLike) -> Path:
    """``<file>.journal``: where the rollback journal of ``path`` lives."""
    path = Path(path)
    return path.with_name(path.name + ".journal")


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


# -------------------------------------------------------------------------------- writing
class _JournaledFile:
    """A file object for h5py's ``fileobj`` driver that journals the original bytes it overwrites."""

    def __init__(self, fh, journal, original_size: int):
        self._fh = fh
        self._journal = journal
        self._size0 = original_size
        self._saved: set[int] = set()
        self._pos = 0
        #: The first failed disk write (disk full, I/O error). From then on writes are dropped and
        #: the append is rolled back at the end: HDF5 never sees an error it would handle badly.
        self.error: OSError | None = None
        self.end = original_size  # the highest byte the append writes (its size once written)
        self._overlay: list[tuple[int, bytes]] = []  # writes kept in memory after a failure, in order

    # The disk writes of one append, in order; tests patch this to inject faults.
    def _io(self, kind: str, fh, offset: int | None, data: bytes) -> None:
        if offset is not None:
            fh.seek(offset)
        fh.write(data)
        fh.flush()
        if kind == "journal":
            os.fsync(fh.fileno())

    def save_original(self, start: int, end: int) -> None:
        """Copy the original pages covering ``[start, end)`` into the journal (once each)."""
        first, last = start // PAGE, (min(end, self._size0) - 1) // PAGE
        for page in range(first, last + 1):
            if page in self._saved:
                continue
            offset = page * PAGE
            self._fh.seek(offset)
            data = self._fh.read(min(PAGE, self._size0 - offset))
            self._io("journal", self._journal, None, _RECORD.pack(offset, len(data), zlib.crc32(data)) + data)
            self._saved.add(page)

    # -- the file-object interface h5py's fileobj driver uses ---------------------------
    def seek(self, offset: int, whence: int = 0) -> int:
        if whence == os.SEEK_END:  # the end HDF5 believes in, dropped writes included
            self._pos = max(self._fh.seek(0, os.SEEK_END), self.end) + offset
        else:
            self._pos = self._fh.seek(offset, whence)
        return self._pos

    def tell(self) -> int:
        return self._pos

    def _read_at(self, pos: int, size: int) -> bytes:
        """Bytes at ``pos``: the file, with the writes kept in memory after a failure laid over it
        (HDF5 reads back what it believes it wrote, so it never meets inconsistent metadata)."""
        self._fh.seek(pos)
        data = self._fh.read(size)
        if not self._overlay:
            return data
        want = min(size if size >= 0 else self.end - pos, max(self.end - pos, 0))
        buf = bytearray(data) + bytearray(max(0, want - len(data)))
        for off, chunk in self._overlay:
            lo, hi = max(off, pos), min(off + len(chunk), pos + len(buf))
            if lo < hi:
                buf[lo - pos:hi - pos] = chunk[lo - off:hi - off]
        return bytes(buf)

    def read(self, size: int = -1) -> bytes:
        data = self._read_at(self._pos, size)
        self._pos += len(data)
        return data

    def readinto(self, buffer) -> int:
        view = memoryview(buffer).cast("B")
        data = self._read_at(self._pos, len(view))
        view[:len(data)] = data
        self._pos += len(data)
        return len(data)

    def write(self, data) -> int:
        data = bytes(data)
        if self.error is None:
            try:
                if self._pos < self._size0:
                    self.save_original(self._pos, self._pos + len(data))
                self._io("file", self._fh, self._pos, data)
            except OSError as exc:
                self.error = exc
        if self.error is not None:
            self._overlay.append((self._pos, data))
        self._pos += len(data)
        self.end = max(self.end, self._pos)
        return len(data)

    def truncate(self, size: int | None = None) -> int:
        size = self._pos if size is None else size
        if self.error is None:
            try:
                if size < self._size0:
                    self.save_original(size, self._size0)
                self._fh.truncate(size)
            except OSError as exc:
                self.error = exc
        return size

    def flush(self) -> None:
        self._fh.flush()


def _fsync_dir(path: Path) -> None:
    fd = os.open(path.parent if str(path.parent) else ".", os.O_RDONLY)
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover - some file systems refuse directory fsync
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def journaled_h5(path: str | os.PathLike, *, prepare: Callable[[_JournaledFile], None] | None = None,
                 timeout: float | None = None) -> Iterator[h5py.File]:
    """Open ``path`` for appending so that the change is all-or-nothing.

    Yields an ``h5py.File`` (mode ``r+``). On normal exit the change is committed; on an
    exception (disk full included) the file is rolled back to its exact original bytes before
    the exception propagates; if the process dies, the next :func:`recover` rolls it back.
    ``prepare(jf)`` runs before HDF5 opens the file (e.g. to clear a dead writer's flags through
    ``jf.save_original`` first).
    """
    path = Path(path)
    jpath = journal_path(path)
    with open(path, "r+b", buffering=0) as fh:
        wait_lock(fh.fileno(), path, exclusive=True, timeout=timeout)
        _recover_locked(path, fh)
        size0 = os.fstat(fh.fileno()).st_size
        with open(jpath, "xb", buffering=0) as journal:
            try:
                journal.write(_HEADER.pack(_MAGIC, size0))
                os.fsync(journal.fileno())
                _fsync_dir(jpath)
                jf = _JournaledFile(fh, journal, size0)
                if prepare is not None:
                    prepare(jf)
                f = h5py.File(jf, "r+", libver=("v110", "v110"), locking=False)
            except BaseException:
                _rollback(path, fh, jpath)
                raise
            try:
                yield f
                f.close()
                if jf.error is not None:
                    raise WriteFailed(jf.error, needed=jf.end - size0 + len(jf._saved) * (PAGE + _RECORD.size))
                os.fsync(fh.fileno())
            except BaseException as exc:
                with contextlib.suppress(Exception):
                    f.close()
                _rollback(path, fh, jpath)
                if jf.error is not None and not isinstance(exc, WriteFailed):
                    raise WriteFailed(jf.error, needed=jf.end - size0) from None  # HDF5 tripped over it
                raise
        jpath.unlink()
        _fsync_dir(jpath)


# -------------------------------------------------------------------------------- recovery
def _read_journal(jpath: Path) -> tuple[int | None, list[tuple[int, bytes]]]:
    """(original size, [(offset, page bytes)]) of the verified records; size None if no header."""
    blob = jpath.read_bytes()
    if len(blob) < _HEADER.size:
        return None, []
    magic, size0 = _HEADER.unpack_from(blob)
    if magic != _MAGIC:
        raise JournalError(errno.EINVAL, f"{jpath}: not a vfmlab journal; move it away and retry")
    records, pos = [], _HEADER.size
    while pos + _RECORD.size <= len(blob):
        offset, length, crc = _RECORD.unpack_from(blob, pos)
        data = blob[pos + _RECORD.size: pos + _RECORD.size + length]
        if len(data) != length or zlib.crc32(data) != crc:
            break  # torn last record: its page was never overwritten
        records.append((offset, data))
        pos += _RECORD.size + length
    return size0, records


def _rollback(path: Path, fh, jpath: Path) -> None:
    size0, records = _read_journal(jpath)
    if size0 is not None:
        for offset, data in records:
            fh.seek(offset)
            fh.write(data)
        fh.truncate(size0)
        fh.flush()
        os.fsync(fh.fileno())
        log.warning("%s: an unfinished result write was rolled back (%d page(s) restored)", path, len(records))
    jpath.unlink()
    _fsync_dir(jpath)


def _recover_locked(path: Path, fh) -> bool:
    jpath = journal_path(path)
    if not jpath.exists():
        return False
    _rollback(path, fh, jpath)
    return True


def recover(path: str | os.PathLike, timeout: float | None = None) -> bool:
    """Roll back an unfinished result write left by a dead process; True if one was rolled back.

    Waits (bounded) while a live job holds the file. Raises :class:`JournalError` when a hot
    journal exists but the file cannot be written (read-only copy): the message says what to do.
    """
    path = Path(path)
    if not journal_path(path).exists():
        return False
    try:
        fh = open(path, "r+b", buffering=0)
    except OSError as exc:
        raise JournalError(exc.errno, f"{path}: an unfinished result write must be rolled back first, but the file "
                                      f"cannot be written ({exc.strerror}); make it writable and retry") from None
    with fh:
        wait_lock(fh.fileno(), path, exclusive=True, timeout=timeout, what="recover")
        return _recover_locked(path, fh)
