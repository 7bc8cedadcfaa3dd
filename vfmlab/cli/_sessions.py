"""Opening sessions from the CLI.

A :class:`~acquisition.session.SessionError` (missing, foreign, damaged file: bad input) becomes a
one-line :class:`CliInputError`, exit code 2 (decision 0007).
"""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path

from acquisition.session import Session, SessionError, open_session
from vfmlab.cli._common import CliInputError


@contextmanager
def cli_session(path: str | Path):
    """Open a session for reading; a SessionError from opening or reading it (missing, foreign, damaged)
    becomes a CliInputError: one line, exit code 2 (decision 0007), also under click's own runner."""
    try:
        session = open_session(path)
    except SessionError as exc:
        raise CliInputError(str(exc)) from exc
    try:
        yield session
    except SessionError as exc:
        raise CliInputError(str(exc)) from exc
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
