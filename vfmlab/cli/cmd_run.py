"""``vfmlab run``: run a test protocol on the rig (or the simulated rig) into a session file."""

from __future__ import annotations

import click

from vfmlab.cli._common import CliError, console

EPILOG = """
\b
Examples:
  vfmlab run examples/paper-protocol.toml --specimen examples/specimen.toml --out a1.h5 --sim --yes
  vfmlab run protocol.toml --specimen artery-07.toml --out artery-07.h5 --rig lab-rig.toml

Ctrl-C pauses at the next safe point and offers: resume, retake the last step, quit (resume later
with 'vfmlab resume'), abort. Abort and every other ending vent the pressure controller.
Exit codes: 0 complete or quit (resumable), 1 aborted (safety limit: vented and resumable; operator:
final), disk full (resumable once space is freed) or a file/instrument error, 2 bad input files.
"""


@click.command(epilog=EPILOG)
@click.argument("protocol", type=click.Path(dir_okay=False))
@click.option("--specimen", "specimen", required=True, type=click.Path(dir_okay=False),
              help="Specimen file (TOML: id, radius_mm, length_mm, thickness_mm, notes).")
@click.option("--out", "out", required=True, type=click.Path(dir_okay=False), help="New session file (.h5).")
@click.option("--rig", "rig", type=click.Path(dir_okay=False),
              help="Rig configuration (ports, cameras, safety limits). Default with --sim: 4 simulated cameras.")
@click.option("--sim", is_flag=True, help="Use the simulated rig (instruments on pseudo-terminals, rendered cameras).")
@click.option("--sim-speed", type=click.FloatRange(min=0.1, max=100.0), default=1.0, show_default=True,
              help="With --sim: how much faster than real time the simulated pressure settles.")
@click.option("--yes", "-y", is_flag=True,
              help="Unattended: no prompts (capture anyway when a level does not settle; Ctrl-C quits resumably).")
@click.option("--detect/--no-detect", default=True, show_default=True,
              help="Count markers in each capture for the live view.")
def command(protocol: str, specimen: str, out: str, rig: str | None, sim: bool, sim_speed: float, yes: bool,
            detect: bool) -> None:
    """Run PROTOCOL (TOML) on the rig, writing every step to the session file --out as it happens."""
    from vfmlab.cli._outputs import check_output_path
    from vfmlab.operate import OperateError, detector_from_reconstruction, run_session

    check_output_path(out, force=False, inputs=[protocol, specimen, rig], can_force=False, leftover_ok=True)
    try:
        outcome = run_session(protocol, specimen, out, rig_path=rig, sim=sim, yes=yes, sim_speed=sim_speed,
                              console=console, detector=detector_from_reconstruction() if detect else None)
    except OperateError as exc:
        error = CliError(str(exc))
        error.exit_code = exc.exit_code
        raise error from None
    if outcome.failed:
        raise click.exceptions.Exit(1)
