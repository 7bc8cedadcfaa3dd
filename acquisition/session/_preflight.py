"""The structure walk in a child process that guards every open of a session file.

HDF5 can loop without end on some corrupted object headers (no exception or signal interrupts it),
so :func:`acquisition.session.open_session` first walks the file's structure in a forked child.

Module state, kept on purpose: ``_verified`` (files this process walked cleanly, keyed by their stat)
and ``_pending`` (the walk :func:`start_preflight` began ahead). Both carry a result from one call to a
later one within the process: ``start_preflight`` is called early by the CLI and the walk it began is
consumed by the later ``open_session`` (which takes no handle), and an unchanged file is not walked
twice. They hold only process-local facts (child pids, stat keys), never file content.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import time
from pathlib import Path
from typing import Any

from acquisition.session._opening import _h5_open_read
from acquisition.session._schema import DamagedSessionError

PREFLIGHT_TIMEOUT = 20.0  # s; walking the structure of a sound session takes well under a second


def _walk_structure(path: Path) -> None:
    """Read every object header and attribute of the file (not the data)."""
    with _h5_open_read(path) as f:
        def visit(_name: str, obj: Any) -> None:
            for key in obj.attrs:
                obj.attrs[key]
        for key in f.attrs:
            f.attrs[key]
        f.visititems(visit)


#: Stat fields that change whenever a file's bytes do (or the file is replaced).
_StatKey = tuple[int, int, int, int, int]
#: A file whose last change is older than this (s) when its structure walk starts keeps the walk's
#: verdict while its stat is unchanged: any later write then moves its mtime/ctime by more than the
#: time stamps' resolution (the kernel's coarse clock tick, <= 10 ms, plus the file system's: 1 ns on
#: ext4/xfs/btrfs/tmpfs, 2 s on FAT), so "same stat" means "same bytes". A file changed more recently
#: is simply walked again at its next open.
QUIET_BEFORE_WALK = 2.5
#: Files of this process whose structure walk finished cleanly: real path -> stat key before the walk.
_verified: dict[str, _StatKey] = {}
#: The one structure walk started ahead by :func:`start_preflight`: (real path, child pid, stat key,
#: quiet, monotonic start time, pid of the process that forked it), or None.
_pending: tuple[str, int, _StatKey, bool, float, int] | None = None
_drop_registered = False


def _stat_key(path: Path) -> tuple[_StatKey, bool]:
    """The file's stat key and whether it had been quiet (unchanged for ``QUIET_BEFORE_WALK`` s)."""
    now = time.time()
    st = os.stat(path)
    key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)
    return key, now - max(st.st_mtime_ns, st.st_ctime_ns) * 1e-9 > QUIET_BEFORE_WALK


def start_preflight(path: str | os.PathLike) -> None:
    """Start the structure walk of :func:`open_session` on ``path`` now, in a child process, so that it
    runs while this process does other work (imports, option checks) on the machine's other core.

    Nothing of the file is read by this process: the next :func:`open_session` of ``path`` waits for
    this walk's verdict (and walks again if the file changed meanwhile). Does nothing where there is
    no ``fork`` or the file cannot be stat'ed (``open_session`` reports that).
    """
    global _pending, _drop_registered
    if not hasattr(os, "fork"):  # pragma: no cover - Windows: no preflight
        return
    _drop_pending()
    path = Path(path)
    try:
        real = os.path.realpath(path)
        key, quiet = _stat_key(path)
    except OSError:
        return
    if _verified.get(real) == key:
        return
    _pending = (real, _fork_walk(path, PREFLIGHT_TIMEOUT), key, quiet, time.monotonic(), os.getpid())
    if not _drop_registered:
        atexit.register(_drop_pending)
        _drop_registered = True


def _drop_pending() -> None:
    """Kill and reap a walk started ahead that nobody waited for (only this process's own child)."""
    global _pending
    if _pending is not None:
        pid, owner = _pending[1], _pending[5]
        _pending = None
        if owner == os.getpid():
            with contextlib.suppress(OSError):
                os.kill(pid, 9)
                os.waitpid(pid, 0)


def _preflight(path: Path, timeout: float | None = None) -> None:
    """Walk the file's structure in a child process first: HDF5 can loop without end (holding the
    interpreter) on some corrupted headers, which no exception or signal can interrupt.

    A child that does not finish within ``timeout`` s (default ``PREFLIGHT_TIMEOUT``, read at the
    call) is killed and the file reported as damaged;
    every other outcome (including errors, which the parent reports with context) passes.

    The walk is not repeated for a file this process has walked cleanly and that has not changed
    since (``_verified``: same stat key, and quiet for ``QUIET_BEFORE_WALK`` s before the walk, so
    the key cannot miss a write); a walk :func:`start_preflight` began on the same unchanged file is
    waited for instead of starting another. Either way no byte of a file reaches this process's
    HDF5 library before a walk of those very bytes has finished.
    """
    global _pending
    timeout = PREFLIGHT_TIMEOUT if timeout is None else timeout
    if not hasattr(os, "fork"):  # pragma: no cover - Windows: no preflight
        return
    real = os.path.realpath(path)
    try:
        key, quiet = _stat_key(path)
    except OSError:  # gone meanwhile: walk anyway, the open after it says what is wrong
        key, quiet = None, False
    if key is not None and _verified.get(real) == key:
        return
    remaining = timeout
    if _pending is not None and _pending[0] == real and _pending[2] == key and _pending[5] == os.getpid():
        _, pid, _, quiet, started, _ = _pending
        _pending = None
        remaining = max(timeout - (time.monotonic() - started), 0.0)
    else:
        _drop_pending()
        pid = _fork_walk(path, timeout)
    status = _wait_child(pid, remaining)
    if status is None:
        raise DamagedSessionError(f"{path}: damaged session file: HDF5 does not finish reading its structure "
                                  f"(gave up after {timeout:g} s)")
    if status == 0 and quiet and _unchanged(path, key):  # walked cleanly, and nothing wrote meanwhile
        _verified[real] = key


def _unchanged(path: Path, key: _StatKey | None) -> bool:
    try:
        return key is not None and _stat_key(path)[0] == key
    except OSError:
        return False


def _fork_walk(path: Path, timeout: float) -> int:
    """Fork a child that walks ``path``'s structure (exit 0: clean, 3: an error) and return its pid.

    The child also ends itself by SIGALRM after ``timeout`` s (+2), so that no parent fate (killed,
    interrupted) can leave it looping in HDF5.
    """
    import signal
    import threading

    # Ctrl-C during fork() would be raised inside logging's at-fork hook and lost: hold it until after.
    main_thread = threading.current_thread() is threading.main_thread()
    if main_thread:
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        pid = os.fork()
        if pid == 0:  # the child: never returns into the caller's code
            code = 0
            try:
                signal.signal(signal.SIGALRM, signal.SIG_DFL)
                signal.alarm(int(timeout) + 2)
                _walk_structure(path)
            except BaseException:  # noqa: BLE001 - the parent reports errors itself
                code = 3
            os._exit(code)
    finally:
        if main_thread:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    return pid


def _wait_child(pid: int, timeout: float) -> int | None:
    """Wait up to ``timeout`` s for child ``pid``; its exit code (-1: killed by a signal), or None
    after killing it when it did not end in time. Killed on any exception too."""
    deadline = time.monotonic() + timeout
    try:
        while True:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                return os.WEXITSTATUS(status) if os.WIFEXITED(status) else -1
            if time.monotonic() >= deadline:
                break
            time.sleep(0.001)
    except BaseException:
        os.kill(pid, 9)
        os.waitpid(pid, 0)
        raise
    os.kill(pid, 9)
    os.waitpid(pid, 0)
    return None
