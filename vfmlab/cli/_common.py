"""Helpers shared by the CLI commands: the consoles, error reporting, markup escaping and number formats.

Two rules hold for everything the CLI prints (docs/decisions/0004-cli-and-console.md):

- **Non-terminal output never wraps or truncates.** When stdout/stderr is not a terminal (a log file, CI,
  ``| tee``, ``click.testing``), :class:`CliConsole` renders as if the line were unlimited: no hard wrap,
  no ``…`` cropping, no padding to a width, whatever ``COLUMNS`` says. In a terminal it wraps as usual.
- **Text from users and files is never read as markup.** Every specimen id, note, path, marker id, CSV
  header or error message goes through :func:`esc` (or is printed with ``markup=False``) before it reaches
  a rich string, so ``[table]`` prints as ``[table]`` and ``[/]`` cannot crash a command; and the consoles
  show its control characters escaped (:func:`vfmlab.display.printable`), so an escape sequence in a file
  can neither clear the screen nor retitle the window.
"""

from __future__ import annotations

import datetime as _dt
import json
import logging
import math
import os
import sys
from typing import Any

import click

# re-exported for the commands; the two constants live with the number formats so that _console (which
# needs them too) does not import this module back
from vfmlab.display import LOG_TIME_FORMAT, UNLIMITED_WIDTH, display_quantity, fixed, num, printable, quantity  # noqa: F401


def __getattr__(name: str) -> Any:
    """``console``, ``err_console`` and ``CliConsole`` on first use (PEP 562): rich costs ~20 ms of
    start-up that commands printing no rich output (``identify --json``, ``--help``) need not pay."""
    if name == "CliConsole":
        from vfmlab.cli._console import CliConsole

        return CliConsole
    if name in ("console", "err_console"):
        from vfmlab.cli._console import CliConsole

        value = CliConsole() if name == "console" else CliConsole(stderr=True)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def esc(value: Any) -> str:
    """``value`` as text safe inside a rich markup string: ``[`` is escaped, never read as a tag."""
    from rich.markup import escape

    return escape(str(value))


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
    from vfmlab.cli._common import err_console

    err_console.print(f"[bold red]Error:[/] {esc(message)}", markup=True)


def show_warning(message: str) -> None:
    """Print ``message`` as a warning the user should read (unusual but accepted input), on stderr."""
    from vfmlab.cli._common import err_console

    err_console.print(f"[yellow]Warning:[/] {esc(message)}", markup=True)


class _EchoHandler(logging.Handler):
    """Plain log lines on stderr for non-terminals: ISO time, level, message; never wrapped."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            stamp = _dt.datetime.fromtimestamp(record.created).strftime(LOG_TIME_FORMAT)
            click.echo(f"{stamp} {record.levelname:<8} {printable(self.format(record))}", err=True)
        except Exception:  # noqa: BLE001 - logging must never raise
            self.handleError(record)


def log_handler() -> logging.Handler:
    """The handler of the CLI's log output: rich in a terminal, plain lines elsewhere (both ISO dates)."""
    if not _stderr_may_be_terminal():
        return _EchoHandler()  # what rich would decide too, without importing it
    from vfmlab.cli._common import err_console

    if err_console.is_terminal:
        from rich.logging import RichHandler

        return RichHandler(console=err_console, show_path=False, markup=False, log_time_format=LOG_TIME_FORMAT)
    return _EchoHandler()


def _stderr_may_be_terminal() -> bool:
    """False when rich's ``Console(stderr=True).is_terminal`` is certainly False: stderr is no tty and
    neither TTY_COMPATIBLE=1 nor FORCE_COLOR says otherwise; True when only rich can tell."""
    if os.environ.get("TTY_COMPATIBLE", "") == "1" or os.environ.get("FORCE_COLOR"):
        return True
    try:
        return bool(sys.stderr.isatty())
    except (AttributeError, ValueError):  # no stream, or a closed one
        return False


def to_jsonable(obj: Any) -> Any:
    """Convert numpy scalars/arrays (NaN -> None) into plain JSON-serialisable Python."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    # numpy is not imported for this (the commands load it, under their start-up's paused collector,
    # vfmlab/cli/_startup.py): an object can be a numpy one only if numpy is loaded
    np = sys.modules.get("numpy")
    if np is not None:
        if isinstance(obj, np.ndarray):
            return to_jsonable(obj.tolist())
        if isinstance(obj, (np.bool_,)):
            return bool(obj)
        if isinstance(obj, (np.integer,)):
            return int(obj)
        if isinstance(obj, np.floating):
            obj = float(obj)
    if isinstance(obj, float):
        value = float(obj)
        return None if math.isnan(value) or math.isinf(value) else value
    if isinstance(obj, bytes):
        return obj.decode("utf-8", "replace")
    return obj


def print_json(obj: Any) -> None:
    """Print ``obj`` as JSON on stdout (no colour, no wrapping), for scripts."""
    click.echo(json.dumps(to_jsonable(obj), indent=2, sort_keys=False))


class ModelChoice(click.Choice):
    """``click.Choice`` of the registered constitutive models (:func:`vfmlab.stages.models.model_names`), listed
    on first use: importing a command (``vfmlab identify --help``) does not import the identification package."""

    def __init__(self) -> None:
        super().__init__((), case_sensitive=True)

    @property
    def choices(self) -> tuple[str, ...]:
        from vfmlab.stages.models import model_names

        return tuple(model_names())

    @choices.setter
    def choices(self, value) -> None:  # click.Choice.__init__ assigns it; the registry decides
        pass


def check_model_list(names, option: str, none_ok: bool = False) -> None:
    """A CliInputError naming ``option`` when ``names`` holds a name that is not a registered model."""
    from vfmlab.stages.models import check_models, model_names

    unknown = check_models(names)
    if unknown:
        raise CliInputError(f"{option} must be among {', '.join(model_names())}{' or ' + repr('none') if none_ok else ''}; "
                            f"got {unknown}")
