"""The stages' feedback (:mod:`vfmlab.stages.feedback`) on the CLI's stderr console: notes and progress.

On a terminal a bar with the time left; otherwise (a log, a pipe) one line per stage, when it starts or changes.
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
    """Progress of one stage on ``console`` (default stderr), yielding ``update(done=None, total=None,
    description=None)`` (no argument: one more done; a new description: a new stage). ``clock`` for tests."""
    from rich import progress as rp

    from vfmlab.cli._common import err_console

    console = console or err_console
    shown = [esc(description)]
    if not console.is_terminal:
        console.print(f"{shown[0]} ...", soft_wrap=True)

        def line(done: int | None = None, total: int | None = None, description: str | None = None) -> None:
            if description and esc(description) != shown[0]:
                shown[0] = esc(description)
                console.print(f"{shown[0]} ...", soft_wrap=True)

        yield line
        return
    columns = (rp.TextColumn("{task.description}"), rp.BarColumn(), rp.MofNCompleteColumn(), rp.TimeElapsedColumn(),
               rp.TextColumn("left"), rp.TimeRemainingColumn())
    with rp.Progress(*columns, console=console, transient=True, get_time=clock) as bar:
        task = bar.add_task(shown[0], total=total)

        def update(done: int | None = None, total: int | None = None, description: str | None = None) -> None:
            if done is None and total is None and description is None:
                bar.advance(task)
            elif description is not None and esc(description) != shown[0]:  # a new stage: its own time left
                shown[0] = esc(description)
                bar.reset(task, total=total, completed=done or 0, description=shown[0])
            else:
                bar.update(task, completed=done, total=total)

        yield update
