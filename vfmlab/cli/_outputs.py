"""The output-path guard every command that writes a file goes through.

Rules (issue 16): an output never replaces a session file or one of the command's own inputs,
whatever the options; any other existing file (or non-empty folder) is replaced only with
``--force``. A refusal is bad input: exit code 2, one sentence saying what to do instead.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from vfmlab.cli._common import CliError

__all__ = ["OutputPathError", "check_output_path", "check_output_dir"]

_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


class OutputPathError(CliError):
    """An output path that would destroy data; exit code 2 (bad input)."""

    exit_code = 2


def _same(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def _is_hdf5(path: Path) -> bool:
    try:
        with open(path, "rb") as fh:
            return fh.read(8) == _HDF5_SIGNATURE
    except OSError:
        return False


def _leftover(path: Path) -> bool:
    from acquisition.session import incomplete_leftover

    return incomplete_leftover(path)


def _session_note(path: Path) -> str:
    """' (being recorded by process N)' when a live writer is recording it, else ''."""
    try:
        from acquisition.session import SessionError, open_session

        with open_session(path) as s:
            if s.status == "running":
                return f" being recorded right now (writer pid {s.file['entry'].attrs.get('writer_pid', '?')})"
    except (SessionError, OSError, KeyError):
        pass
    return ""


def check_output_path(path: str | os.PathLike, *, force: bool, inputs: Iterable[str | os.PathLike] = (),
                      option: str = "--out", can_force: bool = True, leftover_ok: bool = False) -> Path:
    """Check that writing the file ``path`` destroys nothing; returns it as a Path.

    Raises :class:`OutputPathError` (exit code 2) when ``path`` is one of ``inputs``, an existing
    session (HDF5) file, a folder, or any other existing file without ``force``. With
    ``leftover_ok``, the few bytes a run killed while creating its file left behind may be replaced.
    """
    path = Path(path)
    for source in inputs:
        if source is not None and (_same(path, Path(source)) or path.absolute() == Path(source).absolute()):
            raise OutputPathError(f"{option} {path}: is an input of this command; it is never overwritten "
                                  "(choose another output file)")
    if not path.exists():
        return path
    if path.is_dir():
        raise OutputPathError(f"{option} {path}: is a folder; give a file name")
    if leftover_ok and _leftover(path):
        return path
    if _is_hdf5(path):
        raise OutputPathError(f"{option} {path}: is a session (HDF5) file{_session_note(path)}; vfmlab never "
                              "overwrites a session, even with --force (choose another output file)")
    if not force:
        raise OutputPathError(f"{option} {path}: file exists; " + ("add --force to overwrite it, or " if can_force else "")
                              + "choose another name")
    return path


def check_output_dir(path: str | os.PathLike, *, force: bool, inputs: Iterable[str | os.PathLike] = (),
                     option: str = "--out") -> Path:
    """As :func:`check_output_path` for an output folder: an existing non-empty folder needs ``force``."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        kind = "a session (HDF5) file" if _is_hdf5(path) else "a file"
        raise OutputPathError(f"{option} {path}: is {kind}, not a folder (choose another output folder)")
    for source in inputs:
        if source is not None and _same(path, Path(source)):
            raise OutputPathError(f"{option} {path}: is an input of this command; choose another output folder")
    if path.is_dir() and any(path.iterdir()) and not force:
        raise OutputPathError(f"{option} {path}: folder exists and is not empty; add --force to overwrite its files, "
                              "or choose another folder")
    return path
