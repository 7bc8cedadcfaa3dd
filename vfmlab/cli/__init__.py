"""The ``vfmlab`` command line.

Each subcommand lives in its own module ``vfmlab/cli/cmd_<name>.py`` that defines a click
command named ``command``; modules are imported only when their command runs, so
``vfmlab --help`` stays fast and one broken optional dependency cannot take down the rest.
"""

from __future__ import annotations

import importlib
import importlib.util
import logging
import sys

import click

from vfmlab import __version__

# name -> (module, one-line help). Order is the order shown in --help.
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("cmd_demo", "Run a complete simulated test end to end (no hardware)."),
    "run": ("cmd_run", "Run a test protocol on the rig (or --sim) into a session file."),
    "resume": ("cmd_resume", "Continue an interrupted session from its last completed step."),
    "monitor": ("cmd_monitor", "Show live readings of the pressure transducer and load cell."),
    "sim-rig": ("cmd_sim_rig", "Serve simulated instruments on pseudo-terminals."),
    "calibrate": ("cmd_calibrate", "Calibrate the cameras from calibration-board images."),
    "reconstruct": ("cmd_reconstruct", "Reconstruct and track 3-D marker positions in a session."),
    "identify": ("cmd_identify", "Identify constitutive parameters with the Virtual Fields Method."),
    "reprocess": ("cmd_reprocess", "Re-run stages on stored sessions with new settings."),
    "results": ("cmd_results", "List and compare derived results stored in a session."),
    "report": ("cmd_report", "Write an HTML report with figures for a session."),
    "export": ("cmd_export", "Export meshes and fields for ParaView (VTK/PLY)."),
    "info": ("cmd_info", "Summarise a session file."),
    "import-markers": ("cmd_import_markers", "Build a session from marker positions measured elsewhere (CSV)."),
    "export-markers": ("cmd_export_markers", "Write a session's latest marker tracks as CSV."),
    "import-images": ("cmd_import_images", "Build a session from images taken with another rig."),
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


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="vfmlab")
@click.option("-v", "--verbose", count=True, help="More log output (-v info, -vv debug).")
def cli(verbose: int) -> None:
    """vfmlab: inflation/extension testing of arterial segments, from the instruments
    to the material parameters (Virtual Fields Method)."""
    level = logging.WARNING - 10 * min(verbose, 2)
    from vfmlab.cli._common import log_handler

    # Logs go to stderr: stdout carries results (tables, --json) that scripts parse.
    logging.basicConfig(level=level, format="%(message)s", force=True, handlers=[log_handler()])


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script; returns the process exit code.

    Exit codes: 0 success, 1 a failure the command explains (bad input, device fault),
    2 usage error, 130 interrupted by the user.
    """
    try:
        # With standalone_mode=False click *returns* the code of a command's Exit(n).
        rv = cli.main(args=argv, prog_name="vfmlab", standalone_mode=False)
        if isinstance(rv, int) and not isinstance(rv, bool):
            return rv
    except click.exceptions.Exit as exc:
        return exc.exit_code
    except click.ClickException as exc:
        exc.show()
        return exc.exit_code
    except click.Abort:
        click.echo("Aborted.", err=True)
        return 130
    except KeyboardInterrupt:
        click.echo("Interrupted.", err=True)
        return 130
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
