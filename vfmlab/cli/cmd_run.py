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
Exit codes: 0 complete or quit (resumable), 1 aborted or a file/instrument error.
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
@click.option("--live-models", default="fung", show_default=True, metavar="MODELS",
              help="Models identified while the test runs (comma-separated: fung, delfino, hgo, neohookean; "
                   "'none' to switch off): each step is reconstructed in the background (cameras calibrated from "
                   "the board views) and the final parameters are stored as identification results.")
def command(protocol: str, specimen: str, out: str, rig: str | None, sim: bool, sim_speed: float, yes: bool,
            detect: bool, live_models: str) -> None:
    """Run PROTOCOL (TOML) on the rig, writing every step to the session file --out as it happens."""
    from vfmlab.operate import OperateError, detector_from_reconstruction, run_session

    models = tuple(m.strip() for m in live_models.split(",") if m.strip() and m.strip() != "none")
    unknown = [m for m in models if m not in ("fung", "delfino", "hgo", "neohookean")]
    if unknown:
        raise CliError(f"--live-models must be among fung, delfino, hgo, neohookean or 'none'; got {unknown}")
    try:
        outcome = run_session(protocol, specimen, out, rig_path=rig, sim=sim, yes=yes, sim_speed=sim_speed,
                              console=console, detector=detector_from_reconstruction() if detect else None,
                              live_models=models)
    except OperateError as exc:
        raise CliError(str(exc)) from None
    if outcome.status == "aborted":
        raise click.exceptions.Exit(1)
