"""Helpers shared by the CLI commands: the console, error reporting and output formats."""

from __future__ import annotations

import json
import math
from typing import Any

import click
import numpy as np
from rich.console import Console

console = Console(highlight=False)
err_console = Console(stderr=True, highlight=False)


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
    from rich.markup import escape

    err_console.print(f"[bold red]Error:[/] {escape(message)}", markup=True, soft_wrap=True)


def show_warning(message: str) -> None:
    """Print ``message`` as a warning the user should read (unusual but accepted input), on stderr."""
    from rich.markup import escape

    err_console.print(f"[yellow]Warning:[/] {escape(message)}", markup=True, soft_wrap=True)


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
