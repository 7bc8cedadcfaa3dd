"""Opening sessions from the CLI: SessionError becomes a one-line CliError."""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path

from acquisition.session import Session, SessionError, open_session
from vfmlab.cli._common import CliError


@contextmanager
def cli_session(path: str | Path):
    """Open a session for reading; any SessionError is reported as a plain message."""
    try:
        session = open_session(path)
    except SessionError as exc:
        raise CliError(str(exc)) from None
    try:
        yield session
    finally:
        session.close()


def latest_markers(session: Session) -> dict:
    """The newest "markers" result, or a CliError saying how to make one."""
    result = session.latest("markers")
    if result is None:
        raise CliError(
            f"{session.path}: no marker tracks yet; run 'vfmlab reconstruct {session.path}' "
            "or build the session with 'vfmlab import-markers'"
        )
    return result
