"""Guards of a session file: who writes it (and is that writer still alive), and read faults turned
into :class:`DamagedSessionError` naming the damaged part."""

from __future__ import annotations

import functools
import os
import socket
from collections.abc import Callable
from pathlib import Path
from typing import Any

import h5py

from acquisition.session._schema import DamagedSessionError, SessionError


def _boot_id() -> str:
    try:
        return Path("/proc/sys/kernel/random/boot_id").read_text().strip()
    except OSError:
        return ""


def _start_ticks(pid: int) -> int:
    """Start time of process ``pid`` in clock ticks since boot (/proc/<pid>/stat field 22), or -1."""
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[19])
    except (OSError, IndexError, ValueError):
        return -1


def _stamp_writer(entry: h5py.Group) -> None:
    """Record who writes: pid, host, boot id and the process start time (a reused pid is not us)."""
    entry.attrs["writer_pid"] = os.getpid()
    entry.attrs["writer_host"] = socket.gethostname()
    entry.attrs["writer_boot_id"] = _boot_id()
    entry.attrs["writer_start_ticks"] = _start_ticks(os.getpid())


def _writer_alive(pid: int, host: str, boot_id: str = "", start_ticks: int = -1) -> bool:
    """Is the process that recorded ``status = running`` still running (on this machine, this boot)?"""
    if host != socket.gethostname():
        return False  # another machine wrote it; nobody here is still writing
    if boot_id and _boot_id() and boot_id != _boot_id():
        return False  # the machine rebooted since: every writer of that boot is gone
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    if start_ticks >= 0 and _start_ticks(pid) not in (-1, start_ticks):
        return False  # the pid was reused by another process
    try:
        state = Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0]
        return state != "Z"  # a zombie has exited
    except OSError:
        return True


# What h5py raises when a dataset or attribute of a file that opened cannot be read (bit flips,
# a truncated copy, a foreign writer): metadata checksum errors surface as KeyError or RuntimeError,
# undecodable data as OSError, malformed content as ValueError/TypeError/IndexError.
_READ_FAULTS = (OSError, KeyError, RuntimeError, ValueError, TypeError, IndexError, AttributeError)


def _reads(what: str) -> Callable:
    """Decorate a :class:`Session` reader: a read fault becomes a :class:`DamagedSessionError` naming ``what``.

    ``what`` names the part of the file read, e.g. ``"the step table (/entry/steps)"``; it may use the
    reader's positional arguments as ``{0}``, ``{1}``.
    """
    def decorate(method: Callable) -> Callable:
        @functools.wraps(method)
        def guarded(self: Any, *args: Any, **kwargs: Any) -> Any:
            try:
                return method(self, *args, **kwargs)
            except SessionError:
                raise
            except _READ_FAULTS as exc:
                raise damaged_error(self.path, what.format(*args), exc) from None
        return guarded
    return decorate


def damaged_error(path: Path, what: str, exc: BaseException) -> DamagedSessionError:
    """The one-line error for a part of a session file that cannot be read, with the way to see the rest."""
    reason = str(exc).strip().strip("'\"") or type(exc).__name__
    return DamagedSessionError(f"{path}: {what} is damaged and cannot be read ({reason}); "
                               f"'vfmlab info {path}' lists what is still readable")
