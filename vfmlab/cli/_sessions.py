"""Opening sessions from the CLI.

A :class:`~acquisition.session.SessionError` (missing, foreign, damaged file: bad input) becomes a
one-line :class:`CliInputError`, exit code 2 (decision 0007).
"""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path

from acquisition.session import SessionError, open_session
from vfmlab.cli._common import CliInputError
from vfmlab.stages.outputs import latest_markers  # noqa: F401 - for the commands


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
