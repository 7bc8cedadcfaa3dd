"""``vfmlab demo``: a complete simulated test, no hardware needed."""

from __future__ import annotations

from pathlib import Path

import click

from vfmlab.cli._common import CliError, console


@click.command("demo")
@click.option("-o", "--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=Path("demo-output"),
              show_default=True, help="Folder for the session, the report and the files the demo used.")
@click.option("--material", type=click.Choice(["fung", "delfino", "hgo", "neohookean"]), default="fung",
              show_default=True, help="Law of the simulated specimen (seed paper's Table-1 parameters).")
@click.option("--models", default="fung,delfino,hgo", show_default=True, help="Models to identify, comma-separated.")
@click.option("--cameras", "n_cameras", type=click.IntRange(3, 12), default=6, show_default=True,
              help="Cameras in the simulated ring.")
@click.option("--resolution", default="1224x1024", show_default=True, help="Simulated camera resolution, WxH px.")
@click.option("--markers", "n_markers", type=click.IntRange(30, 1000), default=300, show_default=True,
              help="Markers glued on the simulated artery.")
@click.option("--clamped/--homogeneous", default=False, show_default=True,
              help="Simulated tube clamped on cannulae (strain varies along the axis) or homogeneous.")
@click.option("--speed", type=click.FloatRange(1.0, 50.0), default=10.0, show_default=True,
              help="Time scale of the simulated pressure plant.")
def command(out_dir, material, models, n_cameras, resolution, n_markers, clamped, speed):
    """Run a complete simulated test: simulated instruments over pseudo-terminals and rendered
    cameras, the operator protocol (preconditioning, 2 axial stretches x 8 pressure levels),
    calibration, marker reconstruction, identification of Fung, Delfino and HGO, and a report;
    then print identified against true parameters."""
    from vfmlab.demo import DemoError, DemoSettings, parse_models, parse_size, run_demo, summarize

    try:
        settings = DemoSettings(n_cameras=n_cameras, image_size=parse_size(resolution), n_markers=n_markers,
                                material=material, clamped=clamped, models=parse_models(models), sim_speed=speed)
        outcome = run_demo(out_dir, console=console, settings=settings)
    except (DemoError, ValueError) as exc:
        raise CliError(str(exc)) from None
    summarize(console, outcome, settings)
