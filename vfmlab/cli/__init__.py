"""The ``vfmlab`` command line.

Each subcommand lives in its own module ``vfmlab/cli/cmd_<name>.py`` that defines a click
command named ``command``; modules are imported only when their command runs, so
``vfmlab --help`` stays fast and one broken optional dependency cannot take down the rest.
"""

from __future__ import annotations

import importlib
import importlib.util
import logging
import os
import sys
import warnings

# The command line's linear algebra is thousands of small solves (smoothing bases, Gauss-Newton steps):
# OpenBLAS's second thread only contends with the other core (under load a gauss-newton identify took
# 6-10 s instead of 1 s). Set before numpy is imported; a user's own setting wins.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import click

# Exit codes (decision 0007); the same numbers as acquisition.errors.EXIT_*, which this module
# does not import up front so that ``vfmlab --help`` stays fast.
EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130

# name -> (module, one-line help). Order is the order shown in --help.
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("cmd_demo", "Run a complete simulated test end to end (no hardware)."),
    "run": ("cmd_run", "Run a test protocol on the rig (or --sim) into a session file."),
    "resume": ("cmd_resume", "Continue an interrupted session from its last completed step."),
    "watch": ("cmd_watch", "Show a session in a browser while it is recorded (or afterwards)."),
    "monitor": ("cmd_monitor", "Show live readings of the pressure transducer and load cell."),
    "sim-rig": ("cmd_sim_rig", "Serve simulated instruments on pseudo-terminals."),
    "check-rig": ("cmd_check_rig", "Check the rig before a test: cameras, markers, instruments, stage."),
    "calibrate": ("cmd_calibrate", "Calibrate the cameras from calibration-board images."),
    "reconstruct": ("cmd_reconstruct", "Reconstruct and track 3-D marker positions in a session."),
    "identify": ("cmd_identify", "Identify constitutive parameters with the Virtual Fields Method."),
    "design": ("cmd_design", "Predict how precisely a protocol can identify a law, and which added steps help."),
    "reprocess": ("cmd_reprocess", "Re-run stages on stored sessions with new settings."),
    "results": ("cmd_results", "List and compare derived results stored in a session."),
    "report": ("cmd_report", "Write an HTML report with figures for a session."),
    "export": ("cmd_export", "Export meshes and fields for ParaView, PyVista, meshio (VTU/PVD, VTK, PLY)."),
    "info": ("cmd_info", "Summarise a session file."),
    "import-markers": ("cmd_import_markers", "Build a session from marker positions measured elsewhere (CSV)."),
    "import-dic": ("cmd_import_dic", "Build a session from another lab's DIC points (DuoDIC, MultiDIC, VIC-3D, tables)."),
    "export-markers": ("cmd_export_markers", "Write a session's latest marker tracks as CSV."),
    "export-loads": ("cmd_export_loads", "Write a session's step loads as CSV (what import-markers reads)."),
    "import-images": ("cmd_import_images", "Build a session from images taken with another rig."),
    "detect-particles": ("cmd_detect_particles", "Detect small particles in grey images (counts, reject reasons, CSV)."),
}


class LazyGroup(click.Group):
    """A click group whose subcommands are imported on first use."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return [name for name, (module, _) in COMMANDS.items() if _module_exists(module)]

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        if name not in COMMANDS or not _module_exists(COMMANDS[name][0]):
            return None
        module = importlib.import_module(f"vfmlab.cli.{COMMANDS[name][0]}")
        return module.command

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        rows = [(name, COMMANDS[name][1]) for name in self.list_commands(ctx)]
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)


def _module_exists(module: str) -> bool:
    return importlib.util.find_spec(f"vfmlab.cli.{module}") is not None


def _show_version(ctx: click.Context, _param: click.Parameter, value: bool) -> None:
    """``--version``: as click's ``version_option``, with the version looked up only when asked for."""
    if not value or ctx.resilient_parsing:
        return
    from vfmlab import __version__

    click.echo(f"vfmlab, version {__version__}")
    ctx.exit()


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--version", is_flag=True, expose_value=False, is_eager=True, callback=_show_version,
              help="Show the version and exit.")
@click.option("-v", "--verbose", count=True, help="More log output (-v info, -vv debug).")
def cli(verbose: int) -> None:
    """vfmlab: inflation/extension testing of arterial segments, from the instruments
    to the material parameters (Virtual Fields Method)."""
    level = logging.WARNING - 10 * min(verbose, 2)
    from vfmlab.cli._common import log_handler

    # Logs go to stderr: stdout carries results (tables, --json) that scripts parse.
    logging.basicConfig(level=level, format="%(message)s", force=True, handlers=[log_handler()])


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script; returns the process exit code (decision 0007).

    Exit codes: 0 success, 1 a failed operation (device fault, unwritable file, computation that
    failed), 2 bad input (usage, malformed/damaged/implausible file or value), 130 interrupted by
    the user (Ctrl-C). Every error is one line on stderr, never a traceback (``-vv`` logs it).
    Warnings from NumPy and other libraries never reach the user: they are logged at debug level.
    Without ``argv`` (the arguments of this process: the console script, ``python -m vfmlab``) the
    process ends after the command, which lets a command leave its loaded modules to the exit
    (``vfmlab/cli/_startup.py``).
    """
    if argv is None:
        from vfmlab.cli._startup import process_ends_after_command

        process_ends_after_command()
        code = _main(argv)
        if code == EXIT_INTERRUPTED:  # interrupted: end now, before any exit hook can be interrupted in turn
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code)
        return code
    return _main(argv)


def _main(argv: list[str] | None) -> int:
    with warnings.catch_warnings(), _InterruptGuard() as interrupt:
        warnings.simplefilter("default")
        warnings.showwarning = _log_library_warning
        try:
            # With standalone_mode=False click *returns* the code of a command's Exit(n).
            rv = cli.main(args=argv, prog_name="vfmlab", standalone_mode=False)
        except BaseException as exc:  # noqa: BLE001 - the one place exceptions become exit codes
            return _report_exception(exc)
        if interrupt.seen:  # a Ctrl-C whose KeyboardInterrupt a library swallowed: still an interruption
            return _report_exception(KeyboardInterrupt())
    if isinstance(rv, int) and not isinstance(rv, bool):
        return rv
    return EXIT_OK


class _InterruptGuard:
    """Remember Ctrl-C while a command runs, and keep Python's "Exception ignored" reports of a
    KeyboardInterrupt raised where it cannot propagate (e.g. in an at-fork hook) off the screen."""

    def __enter__(self) -> _InterruptGuard:
        import signal
        import threading

        self.seen = False
        self._previous_hook = sys.unraisablehook
        sys.unraisablehook = self._unraisable
        self._previous_handler = None
        if threading.current_thread() is threading.main_thread() and \
                signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            self._previous_handler = signal.signal(signal.SIGINT, self._on_sigint)
        return self

    def _on_sigint(self, signum, frame) -> None:
        self.seen = True
        raise KeyboardInterrupt

    def _unraisable(self, unraisable) -> None:
        if isinstance(unraisable.exc_value, KeyboardInterrupt):
            self.seen = True
            return
        self._previous_hook(unraisable)

    def __exit__(self, *exc: object) -> None:
        import signal

        sys.unraisablehook = self._previous_hook
        if self._previous_handler is not None:
            signal.signal(signal.SIGINT, self._previous_handler)


def exit_code_for(exc: BaseException) -> int:
    """The exit code for an exception that ended a command: the one mapping (decision 0007)."""
    if isinstance(exc, click.exceptions.Exit):
        return exc.exit_code
    if isinstance(exc, SystemExit):
        return exc.code if isinstance(exc.code, int) else EXIT_FAILED
    for kind, code in _exit_codes():
        if isinstance(exc, kind):
            return exc.exit_code if isinstance(exc, click.ClickException) else code
    return EXIT_FAILED


def _exit_codes() -> tuple[tuple[type[BaseException], int], ...]:
    """Exception type -> exit code. Order matters: first match wins (a SessionWriteError is both a
    SessionError, i.e. an InputError, and an OperationError: a failed write)."""
    from acquisition.errors import InputError, OperationError

    return (
        (KeyboardInterrupt, EXIT_INTERRUPTED),
        (click.Abort, EXIT_INTERRUPTED),
        (click.ClickException, EXIT_FAILED),  # its own exit_code: UsageError 2, CliError 1, CliInputError 2
        (OperationError, EXIT_FAILED),
        (InputError, EXIT_BAD_INPUT),
        (OSError, EXIT_FAILED),
    )


def _report_exception(exc: BaseException) -> int:
    """Print the one-line message for ``exc`` (none for a clean exit) and return its exit code."""
    from acquisition.errors import InputError, OperationError
    from vfmlab.cli._common import show_error

    code = exit_code_for(exc)
    if isinstance(exc, (click.exceptions.Exit, SystemExit)):
        return code
    if isinstance(exc, (KeyboardInterrupt, click.Abort)):
        click.echo("Interrupted.", err=True)
    elif isinstance(exc, click.ClickException):
        exc.show()
    elif isinstance(exc, (InputError, OperationError)):
        show_error(str(exc))
    elif isinstance(exc, OSError):
        show_error(describe_os_error(exc))
    else:
        logging.getLogger("vfmlab").debug("unexpected error", exc_info=exc)
        show_error(f"internal error ({type(exc).__name__}: {exc}); this is a bug in vfmlab, please report it "
                   "with the command that caused it (run with -vv for the details)")
    return code


def describe_os_error(exc: OSError) -> str:
    """One sentence for a file-system error: the file first, then what the system said.

    HDF5 reports as ``Unable to synchronously create file (unable to open file: name = 'x.h5',
    errno = 30, error message = 'Read-only file system', ...)``: the name and errno are taken from it.
    """
    import os
    import re

    reason = exc.strerror or str(exc)
    found = re.search(r"name = '([^']*)', errno = (\d+)", str(exc))
    if exc.filename is None and found:
        action = "cannot create" if "create" in str(exc) else "cannot open"
        return f"{found.group(1)}: {action} the file: {os.strerror(int(found.group(2)))}"
    if exc.filename is not None:
        return f"{exc.filename}: {reason}"
    return reason


def _log_library_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """``warnings.showwarning`` for the CLI: library warnings go to the debug log, never to the user."""
    logging.getLogger("vfmlab").debug("%s: %s (%s:%s)", category.__name__, message, filename, lineno)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
