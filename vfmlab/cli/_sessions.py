"""Opening sessions from the CLI.

A :class:`~acquisition.session.SessionError` (missing, foreign, damaged file: bad input) propagates
to the CLI entry, which prints its one line and exits with code 2 (decision 0007).
"""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path

from acquisition.session import Session, open_session
from vfmlab.cli._common import CliInputError


@contextmanager
def cli_session(path: str | Path):
    """Open a session for reading; a SessionError from opening or reading it ends the command (exit 2)."""
    session = open_session(path)
    try:
        yield session
    finally:
        session.close()


def latest_markers(session: Session) -> dict:
    """The newest "markers" result, or a CliInputError saying how to make one."""
    result = session.latest("markers")
    if result is None:
        raise CliInputError(
            f"{session.path}: no marker tracks yet; run 'vfmlab reconstruct {session.path}' "
            "or build the session with 'vfmlab import-markers'"
        )
    return result
