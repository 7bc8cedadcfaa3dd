"""``vfmlab demo``: a complete simulated test, no hardware needed."""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path

import click

from vfmlab.cli._common import CliError, ModelChoice, console, print_json
from vfmlab.cli._outputs import check_output_dir

EPILOG = """
\b
Examples:
  vfmlab demo                                  # into ./demo-output
  vfmlab demo -o /tmp/demo --material hgo --models hgo,fung --sim-speed 10
  vfmlab demo --json > demo.json               # progress on stderr, the outcome as JSON on stdout
"""


@click.command("demo", epilog=EPILOG)
@click.option("-o", "--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=Path("demo-output"),
              show_default=True, help="Folder for the session, the report and the files the demo used (its parent "
                                      "folder must exist; every run adds a new time-stamped session).")
@click.option("--material", type=ModelChoice(), default="fung",
              show_default=True, help="Law of the simulated specimen (seed paper's Table-1 parameters).")
@click.option("--models", default="fung,delfino,hgo", show_default=True, help="Models to identify, comma-separated.")
@click.option("--cameras", "n_cameras", type=click.IntRange(3, 12), default=6, show_default=True,
              help="Cameras in the simulated ring.")
@click.option("--resolution", default="1224x1024", show_default=True, help="Simulated camera resolution, WxH px.")
@click.option("--markers", "n_markers", type=click.IntRange(30, 1000), default=300, show_default=True,
              help="Markers glued on the simulated artery.")
@click.option("--clamped/--homogeneous", default=False, show_default=True,
              help="Simulated tube clamped on cannulae (strain varies along the axis) or homogeneous.")
@click.option("--sim-speed", "sim_speed", type=click.FloatRange(1.0, 50.0), default=10.0, show_default=True,
              help="How much faster than real time the simulated pressure settles (as 'vfmlab run --sim-speed').")
@click.option("--speed", "old_speed", type=click.FloatRange(1.0, 50.0), default=None, hidden=True,
              help="Old spelling of --sim-speed.")
@click.option("--json", "as_json", is_flag=True,
              help="Progress on stderr; print the outcome (files, identified vs true parameters in SI, stage "
                   "times in s) as JSON on stdout.")
def command(out_dir, material, models, n_cameras, resolution, n_markers, clamped, sim_speed, old_speed, as_json):
    """Run a complete simulated test: simulated instruments over pseudo-terminals and rendered
    cameras, the operator protocol (preconditioning, 2 axial stretches x 8 pressure levels),
    calibration, marker reconstruction, identification of Fung, Delfino and HGO, and a report;
    then print identified against true parameters."""
    from vfmlab.demo import DemoError, DemoSettings, parse_models, parse_size, run_demo, summarize, truth_table

    check_output_dir(out_dir, force=True)
    try:
        settings = DemoSettings(n_cameras=n_cameras, image_size=parse_size(resolution), n_markers=n_markers,
                                material=material, clamped=clamped, models=parse_models(models),
                                sim_speed=old_speed if old_speed is not None else sim_speed)
        # with --json everything the stages print goes to stderr; stdout carries the JSON alone
        with contextlib.redirect_stdout(sys.stderr) if as_json else contextlib.nullcontext():
            outcome = run_demo(out_dir, console=console, settings=settings)
    except (DemoError, ValueError) as exc:
        raise CliError(str(exc)) from None
    if as_json:
        from vfmlab.results import parameter_units

        _, rows = truth_table(outcome.session, material)
        for row in rows:  # value, stderr and true are SI: say in which unit
            row["unit"] = parameter_units(row["model"], [row["parameter"]])[0]
        print_json({"session": str(outcome.session), "report": str(outcome.report), "results": outcome.results,
                    "parameters": rows, "stage_seconds": outcome.stage_seconds})
        return
    summarize(console, outcome, settings)
