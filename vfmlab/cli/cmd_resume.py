"""``vfmlab resume``: continue an interrupted session from its last completed step."""

from __future__ import annotations

import click

from vfmlab.cli._common import console, err_console
from vfmlab.cli.cmd_run import finish_session, require_answers

EPILOG = """
\b
An interrupted session is one whose runner stopped without finishing: killed process, power cut,
'quit' at a pause. Earlier steps are never rewritten; the instruments must answer with the same
identity as when the session started. A session recorded on the simulated rig resumes on it.
Examples:
  vfmlab resume a1.h5 --yes
  vfmlab resume artery-07.h5 --rig lab-rig.toml
"""


@click.command(epilog=EPILOG)
@click.argument("session", type=click.Path(exists=True, dir_okay=False))
@click.option("--rig", "rig", type=click.Path(dir_okay=False),
              help="Rig configuration; default: the rig file stored in the session.")
@click.option("--sim", is_flag=True, hidden=True,
              help="A session recorded on the simulated rig resumes on it anyway.")
@click.option("--sim-speed", type=click.FloatRange(min=0.1, max=100.0), default=1.0, show_default=True,
              help="For a simulated session: how much faster than real time the simulated pressure settles.")
@click.option("--speed", "old_speed", type=click.FloatRange(min=0.1, max=100.0), default=None, hidden=True,
              help="Same as --sim-speed.")
@click.option("--yes", "-y", is_flag=True, help="Unattended: no prompts.")
@click.option("--detect/--no-detect", default=True, show_default=True,
              help="Count markers in each capture for the live view.")
@click.option("--json", "as_json", is_flag=True,
              help="Progress on stderr; print the outcome (status, path, n_steps, elapsed_s) as JSON on stdout.")
def command(session: str, rig: str | None, sim: bool, sim_speed: float, old_speed: float | None, yes: bool,
            detect: bool, as_json: bool) -> None:
    """Continue SESSION (.h5) where it stopped."""
    from vfmlab.operate import detector_from_reconstruction, resume_session

    require_answers(yes)
    finish_session(lambda: resume_session(session, rig_path=rig, sim=sim, yes=yes,
                                          sim_speed=old_speed if old_speed is not None else sim_speed,
                                          console=err_console if as_json else console,
                                          detector=detector_from_reconstruction() if detect else None), as_json)
