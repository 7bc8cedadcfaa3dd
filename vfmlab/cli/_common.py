"""Helpers shared by the CLI commands: the consoles, error reporting, markup escaping and number formats.

Two rules hold for everything the CLI prints (docs/decisions/0004-cli-and-console.md):

- **Non-terminal output never wraps or truncates.** When stdout/stderr is not a terminal (a log file, CI,
  ``| tee``, ``click.testing``), :class:`CliConsole` renders as if the line were unlimited: no hard wrap,
  no ``…`` cropping, no padding to a width, whatever ``COLUMNS`` says. In a terminal it wraps as usual.
- **Text from users and files is never read as markup.** Every specimen id, note, path, marker id, CSV
  header or error message goes through :func:`esc` (or is printed with ``markup=False``) before it reaches
  a rich string, so ``[table]`` prints as ``[table]`` and ``[/]`` cannot crash a command.
"""

from __future__ import annotations

import datetime as _dt
import json
import logging
import math
from typing import Any, Iterable

import click
import numpy as np
from rich.console import Console, ConsoleDimensions
from rich.markup import escape as _rich_escape

from vfmlab.display import display_quantity, fixed, num, quantity  # noqa: F401 - re-exported for the commands

#: Width a non-terminal console renders at: wide enough that no table or line ever folds.
UNLIMITED_WIDTH = 100_000
#: ISO 8601 time stamps in every log line (never the locale's month/day order).
LOG_TIME_FORMAT = "%Y-%m-%d %H:%M:%S"


class CliConsole(Console):
    """A rich console that never wraps, crops or pads when its file is not a terminal.

    In a terminal it behaves as :class:`rich.console.Console`. Elsewhere its width is unlimited, long
    text is soft-wrapped (left to the reader), trailing padding is stripped from every line and
    :meth:`rule` prints a short rule instead of one as wide as the console.
    """

    def __init__(self, **kwargs: Any) -> None:
        kwargs.setdefault("highlight", False)
        kwargs.setdefault("log_path", False)
        kwargs.setdefault("log_time_format", f"[{LOG_TIME_FORMAT}]")
        self._soft_wrap_terminal = bool(kwargs.pop("soft_wrap", False))
        super().__init__(**kwargs)

    @property
    def size(self) -> ConsoleDimensions:
        dims = super().size
        return dims if self.is_terminal else ConsoleDimensions(UNLIMITED_WIDTH, dims.height)

    @size.setter
    def size(self, new_size: tuple[int, int]) -> None:
        Console.size.fset(self, new_size)

    @property
    def soft_wrap(self) -> bool:  # read by Console.print when soft_wrap is not given
        return self._soft_wrap_terminal or not self.is_terminal

    @soft_wrap.setter
    def soft_wrap(self, value: bool) -> None:
        self._soft_wrap_terminal = bool(value)

    def rule(self, title: str = "", *args: Any, **kwargs: Any) -> None:
        if self.is_terminal:
            super().rule(title, *args, **kwargs)
        else:
            self.print(f"── {title} ──" if title else "──────")

    def _render_buffer(self, buffer: Iterable) -> str:
        text = super()._render_buffer(buffer)
        if self.is_terminal:
            return text
        return "\n".join(line.rstrip(" ") for line in text.split("\n"))


console = CliConsole()
err_console = CliConsole(stderr=True)


def esc(value: Any) -> str:
    """``value`` as text safe inside a rich markup string: ``[`` is escaped, never read as a tag."""
    return _rich_escape(str(value))


class CliError(click.ClickException):
    """A failed operation the user can act on: printed as one message, exit code 1 (decision 0007)."""

    exit_code = 1

    def show(self, file=None) -> None:  # noqa: D401 - click API
        show_error(self.message)


class CliInputError(CliError):
    """Bad input (an option, a file's content) found by a command: one message, exit code 2 (decision 0007)."""

    exit_code = 2


def show_error(message: str) -> None:
    """Print ``message`` as the one-line error of the command, on stderr."""
    err_console.print(f"[bold red]Error:[/] {esc(message)}", markup=True)


def show_warning(message: str) -> None:
    """Print ``message`` as a warning the user should read (unusual but accepted input), on stderr."""
    err_console.print(f"[yellow]Warning:[/] {esc(message)}", markup=True)


class _EchoHandler(logging.Handler):
    """Plain log lines on stderr for non-terminals: ISO time, level, message; never wrapped."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            stamp = _dt.datetime.fromtimestamp(record.created).strftime(LOG_TIME_FORMAT)
            click.echo(f"{stamp} {record.levelname:<8} {self.format(record)}", err=True)
        except Exception:  # noqa: BLE001 - logging must never raise
            self.handleError(record)


def log_handler() -> logging.Handler:
    """The handler of the CLI's log output: rich in a terminal, plain lines elsewhere (both ISO dates)."""
    if err_console.is_terminal:
        from rich.logging import RichHandler

        return RichHandler(console=err_console, show_path=False, markup=False, log_time_format=LOG_TIME_FORMAT)
    return _EchoHandler()


def to_jsonable(obj: Any) -> Any:
    """Convert numpy scalars/arrays (NaN -> None) into plain JSON-serialisable Python."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        value = float(obj)
        return None if math.isnan(value) or math.isinf(value) else value
    if isinstance(obj, bytes):
        return obj.decode("utf-8", "replace")
    return obj


def print_json(obj: Any) -> None:
    """Print ``obj`` as JSON on stdout (no colour, no wrapping), for scripts."""
    click.echo(json.dumps(to_jsonable(obj), indent=2, sort_keys=False))
