"""A whole session built under a temporary name and published by one rename: all or nothing.

``import-markers`` (and the synthetic sessions of the tests) build a complete session, steps and
first results at once. :func:`staged_session` gives them a private temporary path next to the
target; only when everything is written and fsynced is it renamed onto the target. A kill or a full
disk at any write leaves the target as it was (absent, or the session it held before) and at most a
hidden ``.<name>.staging-<pid>`` file, which the next staging of that name removes once its
process is gone.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from acquisition.session import _guards, _store
from acquisition.session._fence import fenced, reserve
from acquisition.session._results import write_result_group
from acquisition.session._schema import SessionError
from acquisition.session._writer import _refuse_live_session

log = logging.getLogger("acquisition.session")


class StagedSession:
    """A session being built at :attr:`path` (a temporary name) for :func:`staged_session` to publish."""

    def __init__(self, path: Path, target: Path):
        self.path = path
        self.target = target

    def add_result(self, kind: str, arrays: Mapping[str, Any], parameters: Mapping[str, Any],
                   attrs: Mapping[str, Any] | None = None, units: Mapping[str, str] | None = None) -> str:
        """Store a first result inside the file being built (it is published with it); returns its name.

        Same arguments as :func:`acquisition.session.write_result`. Call it after the writer is closed.
        """
        if not kind.isidentifier():
            raise ValueError(f"kind must be an identifier like 'markers'; got {kind!r}")
        with open(self.path, "r+b") as fh:  # the space first: HDF5 must not meet a full disk
            reserve(fh.fileno(), sum(np.asarray(v).nbytes for v in arrays.values()) + 65536)
        with fenced(h5py.File(self.path, "r+")) as f:
            return write_result_group(f, kind, arrays, parameters, attrs, units)


def _remove_stale(target: Path) -> None:
    """Delete the staging files an earlier, killed build of ``target`` left (their process is gone)."""
    prefix = f".{target.name}.staging-"
    for leftover in target.parent.glob(prefix + "*"):
        pid = leftover.name[len(prefix):]
        if pid.isdigit() and not _guards._writer_alive(int(pid), socket.gethostname()):
            with contextlib.suppress(OSError):
                leftover.unlink()


@contextlib.contextmanager
def staged_session(path: str | os.PathLike, *, overwrite: bool = False) -> Iterator[StagedSession]:
    """Build a session at a temporary name; on success rename it onto ``path`` (fsynced), else delete it.

    Refuses an existing ``path`` unless ``overwrite``, and always refuses to replace a session that
    is being recorded. When ``path`` is replaced, the derived results beside it (``<path>.results``)
    belonged to the old session: they are moved aside to ``<path>.results.replaced-N``, never deleted.
    """
    target = Path(path)
    if target.exists() and not overwrite:
        raise SessionError(f"{target}: file exists; refusing to overwrite a session (choose another --out)")
    target.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale(target)
    staged = StagedSession(target.with_name(f".{target.name}.staging-{os.getpid()}"), target)
    staged.path.unlink(missing_ok=True)
    try:
        yield staged
        with open(staged.path, "rb+") as fh:
            os.fsync(fh.fileno())
        if target.exists():
            _refuse_live_session(target)
        os.replace(staged.path, target)
    except BaseException:
        with contextlib.suppress(OSError):
            staged.path.unlink()
        raise
    _store._io("fsync_dir", target.parent)
    _move_old_results_aside(target)


def _move_old_results_aside(target: Path) -> None:
    folder = _store.results_dir(target)
    if not folder.exists():
        return
    n = 1
    while folder.with_name(f"{folder.name}.replaced-{n}").exists():
        n += 1
    aside = folder.with_name(f"{folder.name}.replaced-{n}")
    os.rename(folder, aside)
    log.warning("%s: the results of the session this file replaced were moved to %s", target, aside)


def import_failure(path: str | os.PathLike, exc: OSError) -> str:
    """One sentence for a staged build that failed on a disk write (nothing was published)."""
    import errno
    import shutil

    target = Path(path)
    before = "the file it held before is unchanged" if target.exists() else "no session was created"
    if exc.errno in (errno.ENOSPC, errno.EDQUOT) or "No space left" in str(exc):
        free = shutil.disk_usage(target.parent).free
        return (f"{target}: disk full while writing the session ({free / 1e6:.1f} MB free); {before}. "
                "Free some space and run the command again")
    import os
    import re

    found = re.search(r"errno = (\d+)", str(exc))
    code = exc.errno or (int(found.group(1)) if found else None)
    if code and not target.exists() and ("create" in str(exc) or code in (errno.EROFS, errno.EACCES, errno.EPERM)):
        return f"{target}: cannot create the file: {os.strerror(code)}"  # the staging file could not be made
    return f"{target}: cannot write the session ({exc}); {before}"
