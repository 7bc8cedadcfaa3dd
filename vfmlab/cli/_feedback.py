"""The stages' feedback (:mod:`vfmlab.stages.feedback`) on the CLI's stderr console: notes and progress bars."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager

from vfmlab.cli._common import esc


def notify(text: str) -> None:
    """A stage's note, printed on stderr."""
    from vfmlab.cli._common import err_console

    err_console.print(text)


@contextmanager
def progress_bar(description: str, total: int | None = None) -> Iterator[Callable[..., None]]:
    """A transient rich progress bar on stderr for one loop of a stage."""
    from rich.progress import Progress

    from vfmlab.cli._common import err_console

    with Progress(console=err_console, transient=True) as progress:
        task = progress.add_task(esc(description), total=total)

        def update(done: int | None = None, total: int | None = None, description: str | None = None) -> None:
            if done is None and total is None and description is None:
                progress.advance(task)
            else:
                progress.update(task, completed=done, total=total,
                                description=None if description is None else esc(description))

        yield update
