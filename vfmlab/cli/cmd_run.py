"""``vfmlab run``: run a test protocol on the rig (or the simulated rig) into a session file."""

from __future__ import annotations

import sys

import click

from vfmlab.cli._common import CliError, console, err_console
from vfmlab.cli._outputs import check_output_path

EPILOG = """
\b
Examples:
  vfmlab run examples/paper-protocol.toml --specimen examples/specimen.toml -o a1.h5 --sim --yes
  vfmlab run examples/paper-protocol.toml --specimen examples/specimen.toml -o a2.h5 --sim --sim-seed 2 --yes
  vfmlab run protocol.toml --specimen artery-07.toml -o artery-07.h5 --rig lab-rig.toml

Ctrl-C pauses at the next safe point and offers: resume, retake the last step, quit (resume later
with 'vfmlab resume'), abort. Abort and every other ending vent the pressure controller.
Without a terminal on stdin (scripts, CI) nobody can answer the questions: pass --yes.
Exit codes: 0 complete or quit (resumable), 1 aborted (safety limit: vented and resumable; operator:
final), disk full (resumable once space is freed) or a file/instrument error, 2 bad input files.
"""


def require_answers(yes: bool) -> None:
    """An attended run asks the operator; refuse early, and say what to pass, when nobody can answer."""
    if not yes and not sys.stdin.isatty():
        raise CliError("standard input is not a terminal, so the questions of an attended run (start, a level "
                       "that does not settle, the Ctrl-C menu) cannot be answered; pass --yes (-y) to run "
                       "unattended, or start it from a terminal")


@click.command(epilog=EPILOG)
@click.argument("protocol", type=click.Path(dir_okay=False))
@click.option("--specimen", "specimen", required=True, type=click.Path(dir_okay=False),
              help="Specimen file (TOML: id, radius_mm, length_mm, thickness_mm, notes).")
@click.option("-o", "--out", "out", required=True, type=click.Path(dir_okay=False),
              help="New session file (.h5); never overwritten (continue one with 'vfmlab resume').")
@click.option("--rig", "rig", type=click.Path(dir_okay=False),
              help="Rig configuration (ports, cameras, safety limits). Default with --sim: 4 simulated cameras.")
@click.option("--sim", is_flag=True, help="Use the simulated rig (instruments on pseudo-terminals, rendered cameras).")
@click.option("--sim-speed", type=click.FloatRange(min=0.1, max=100.0), default=1.0, show_default=True,
              help="With --sim: how much faster than real time the simulated pressure settles.")
@click.option("--sim-seed", type=click.IntRange(min=0), default=None, metavar="N",
              help="With --sim: seed of the simulated rig (marker layout, camera-ring imperfections, image and "
                   "instrument noise), replacing the rig file's [simulation] seed (default 0); the session records it. "
                   "Repeat a simulated test with other noise by changing it.")
@click.option("--speed", "old_speed", type=click.FloatRange(min=0.1, max=100.0), default=None, hidden=True,
              help="Same as --sim-speed (the demo's old spelling).")
@click.option("--yes", "-y", is_flag=True,
              help="Unattended: no prompts (capture anyway when a level does not settle; Ctrl-C quits resumably).")
@click.option("--detect/--no-detect", default=True, show_default=True,
              help="Count markers in each capture for the live view.")
@click.option("--live-models", default="fung", show_default=True, metavar="MODELS",
              help="Models identified while the test runs (comma-separated: fung, delfino, hgo, neohookean; "
                   "'none' to switch off): each step is reconstructed in the background (cameras calibrated from "
                   "the board views; off when the protocol has none) and the final parameters are stored as "
                   "identification results. The capture never waits for it; a failure there is logged.")
@click.option("--web", "web", is_flag=False, flag_value=8765, default=None, type=click.IntRange(0, 65535),
              metavar="[PORT]", help="Also show the test in a browser: a read-only page on this machine only "
                                     "(http://127.0.0.1:PORT/, default 8765) served by a separate process "
                                     "(docs/guide/live-web.md).")
@click.option("--json", "as_json", is_flag=True,
              help="Progress on stderr; print the outcome (status, path, n_steps, elapsed_s) as JSON on stdout.")
def command(protocol: str, specimen: str, out: str, rig: str | None, sim: bool, sim_speed: float,
            sim_seed: int | None, old_speed: float | None, yes: bool, detect: bool, live_models: str, web: int | None,
            as_json: bool) -> None:
    """Run PROTOCOL (TOML) on the rig, writing every step to the session file --out as it happens."""
    from vfmlab.stages.batch import check_sim_seed, run
    from vfmlab.stages.settings import RunSettings

    require_answers(yes)
    settings = RunSettings(rig=rig, sim=sim, sim_speed=old_speed if old_speed is not None else sim_speed,
                           sim_seed=sim_seed, yes=yes, detect=detect, live_models=live_models)
    check_sim_seed(settings)
    check_output_path(out, force=False, inputs=[protocol, specimen, rig], can_force=False, leftover_ok=True)
    with _web_hooks(out, web, err_console if as_json else console) as hooks:
        finish_session(lambda: run(protocol, specimen, out, settings, console=err_console if as_json else console,
                                   hooks=hooks), as_json)


def _web_hooks(out: str, port: int | None, shown):
    """``--web``: the page's server in its own process while the run lasts (vfmlab.web); no-op without it."""
    import contextlib

    if port is None:
        return contextlib.nullcontext({})
    from vfmlab.web.feed import WebError, web_view

    try:
        return web_view(out, port, say=shown.print)
    except WebError as exc:
        raise CliError(str(exc)) from None


def finish_session(operate, as_json: bool) -> None:
    """Run ``operate()`` (a run or a resume), print its outcome as JSON if asked, and end with
    exit code 1 when the session aborted or failed, 130 when Ctrl-C stopped an unattended one (decision 0007)."""
    from vfmlab.operate import OperateError, as_json as outcome_json

    try:
        outcome = operate()
    except OperateError as exc:
        error = CliError(str(exc))
        error.exit_code = exc.exit_code
        raise error from None
    if as_json:
        click.echo(outcome_json(outcome))
    if outcome.exit_code:
        raise click.exceptions.Exit(outcome.exit_code)
