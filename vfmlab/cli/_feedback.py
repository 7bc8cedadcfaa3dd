"""The stages' feedback (:mod:`vfmlab.stages.feedback`) on the CLI's stderr console: notes and progress.

On a terminal, a progress bar with the time left; otherwise (a log file, a pipe) one line per stage: the
description when it starts or changes, so a log says what ran without a line per tick.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager

from vfmlab.cli._common import esc


def notify(text: str) -> None:
    """A stage's note, printed on stderr."""
    from vfmlab.cli._common import err_console

    err_console.print(text)


@contextmanager
def progress_bar(description: str, total: int | None = None, *, console=None,
                 clock: Callable[[], float] | None = None) -> Iterator[Callable[..., None]]:
    """Progress of one stage on ``console`` (default: stderr), yielding ``update(done=None, total=None,
    description=None)`` (no argument: one more done). ``clock`` (seconds) for tests."""
    from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn,
                               TimeRemainingColumn)

    from vfmlab.cli._common import err_console

    console = console or err_console
    if not console.is_terminal:
        shown = [description]
        console.print(esc(f"{description} ..."), soft_wrap=True)

        def line(done: int | None = None, total: int | None = None, description: str | None = None) -> None:
            if description and description != shown[0]:
                shown[0] = description
                console.print(esc(f"{description} ..."), soft_wrap=True)

        yield line
        return
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
               TextColumn("left"), TimeRemainingColumn())
    with Progress(*columns, console=console, transient=True,
                  **({"get_time": clock} if clock is not None else {})) as progress:
        task = progress.add_task(esc(description), total=total)

        def update(done: int | None = None, total: int | None = None, description: str | None = None) -> None:
            if done is None and total is None and description is None:
                progress.advance(task)
            elif description is not None and esc(description) != progress.tasks[0].description:
                progress.reset(task, total=total, completed=done or 0, description=esc(description))  # a new stage
            else:
                progress.update(task, completed=done, total=total)

        yield update

