"""Where commands write: one check for every output path (``-o/--out``, ``--summary``).

The grammar (docs/decisions/0004-cli-and-console.md): an output path's folder must already exist
(nothing creates missing folders behind the operator's back); a session file or one of the command's
own inputs is never overwritten; any other existing file is overwritten only with ``--force``.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Iterable

from vfmlab.cli._common import CliError


def _is_hdf5(path: Path) -> bool:
    """An HDF5 file, with or without a user block before its superblock."""
    from vfmlab.stages.outputs import hdf5_signature_offset

    return hdf5_signature_offset(path) is not None


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def check_parent(path: str | os.PathLike, option: str = "--out") -> Path:
    """``path`` as a Path, or a CliError when the folder it goes into does not exist (nothing creates it)."""
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise CliError(f"{option} {path}: the folder {parent} does not exist; create it first")
    return path


def _session_note(path: Path) -> str:
    """' being recorded right now (writer pid N)' when a live writer is recording it, else ''."""
    from acquisition.session import SessionError, open_session

    for _attempt in range(3):
        try:
            with open_session(path) as s:
                if s.status == "running":
                    return f" being recorded right now (writer pid {s.file['entry'].attrs.get('writer_pid', '?')})"
                return ""
        except KeyError:
            return ""
        except (SessionError, OSError):
            # a reader catches a live writer mid-append now and then (~4 % of opens: the file looks
            # truncated until the append lands): look again, as the writer's own check does
            time.sleep(0.2)
    return ""


def check_output_path(path: str | os.PathLike, *, force: bool, inputs: Iterable[str | os.PathLike] = (),
                      option: str = "--out", can_force: bool = True, leftover_ok: bool = False) -> Path:
    """Check that the file ``path`` may be written; returns it as a Path or raises CliError.

    Refused: a missing parent folder, an existing folder, one of ``inputs``, an HDF5 (session) file
    (two writers never share a file: a session being recorded is named as such); an existing other
    file unless ``force``. ``can_force=False``: the command has no --force (the message does not
    offer it). ``leftover_ok``: the few bytes a run killed while creating its file left may be replaced.
    """
    path = check_parent(path, option)
    if path.is_dir():
        raise CliError(f"{option} {path}: is a folder; give a file name")
    if not path.exists():
        return path
    if any(source is not None and _same_file(path, Path(source)) for source in inputs):
        raise CliError(f"{option} {path}: is an input of this command; refusing to overwrite it")
    if leftover_ok:
        from acquisition.session import incomplete_leftover

        if incomplete_leftover(path):
            return path
    if _is_hdf5(path):
        raise CliError(f"{option} {path}: is an HDF5 session file{_session_note(path)}; vfmlab never overwrites "
                       "a session, even with --force")
    if not force:
        raise CliError(f"{option} {path}: file exists; " + ("pass --force to overwrite it" if can_force
                                                             else "choose another name"))
    return path


def check_output_dir(path: str | os.PathLike, *, force: bool, inputs: Iterable[str | os.PathLike] = (),
                     option: str = "--out") -> Path:
    """Check that the folder ``path`` may receive this command's files; returns it or raises CliError.

    The folder itself may be new, but its parent must exist; an existing non-empty folder needs ``force``.
    """
    path = check_parent(path, option)
    if path.exists() and not path.is_dir():
        raise CliError(f"{option} {path}: is a file; give a folder")
    if any(source is not None and _same_file(path, Path(source)) for source in inputs):
        raise CliError(f"{option} {path}: is an input of this command; choose another folder")
    if path.is_dir() and any(path.iterdir()) and not force:
        raise CliError(f"{option} {path}: folder exists and is not empty; pass --force to overwrite its files, "
                       "or choose another folder")
    return path
