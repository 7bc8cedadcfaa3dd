"""How a stage tells its caller what it is doing, without printing: a note callback and a progress factory.

``notify(text)``: a line for the user (the command line prints it on stderr; the Python API logs it).
``progress(description, total)``: a context manager around a long loop, yielding
``update(done=None, total=None, description=None)``; ``update()`` with no argument means one more done.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager

__all__ = ["Notify", "ProgressFactory", "log_notes", "no_progress"]

log = logging.getLogger("vfmlab")

Notify = Callable[[str], None]
ProgressFactory = Callable[[str, "int | None"], AbstractContextManager]


def log_notes(text: str) -> None:
    """The Python API's ``notify``: an info log line."""
    log.info("%s", text)


@contextmanager
def no_progress(description: str, total: int | None = None) -> Iterator[Callable[..., None]]:
    """The Python API's ``progress``: nothing shown."""
    yield lambda done=None, total=None, description=None: None
