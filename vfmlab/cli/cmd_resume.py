"""``vfmlab resume``: continue an interrupted session from its last completed step."""

from __future__ import annotations

import click

from vfmlab.cli._common import CliError, console

EPILOG = """
\b
An interrupted session is one whose runner stopped without finishing: killed process, power cut,
'quit' at a pause. Earlier steps are never rewritten; the instruments must answer with the same
identity as when the session started. Example:
  vfmlab resume a1.h5 --sim --yes
"""


@click.command(epilog=EPILOG)
@click.argument("session", type=click.Path(exists=True, dir_okay=False))
@click.option("--rig", "rig", type=click.Path(dir_okay=False),
              help="Rig configuration; default: the rig file stored in the session.")
@click.option("--sim", is_flag=True, help="The session was recorded on the simulated rig.")
@click.option("--sim-speed", type=click.FloatRange(min=0.1, max=100.0), default=1.0, show_default=True,
              help="With --sim: how much faster than real time the simulated pressure settles.")
@click.option("--yes", "-y", is_flag=True, help="Unattended: no prompts.")
@click.option("--detect/--no-detect", default=True, show_default=True,
              help="Count markers in each capture for the live view.")
def command(session: str, rig: str | None, sim: bool, sim_speed: float, yes: bool, detect: bool) -> None:
    """Continue SESSION (.h5) where it stopped."""
    from vfmlab.operate import OperateError, detector_from_reconstruction, resume_session

    try:
        outcome = resume_session(session, rig_path=rig, sim=sim, yes=yes, sim_speed=sim_speed, console=console,
                                 detector=detector_from_reconstruction() if detect else None)
    except OperateError as exc:
        error = CliError(str(exc))
        error.exit_code = exc.exit_code
        raise error from None
    if outcome.failed:
        raise click.exceptions.Exit(1)
