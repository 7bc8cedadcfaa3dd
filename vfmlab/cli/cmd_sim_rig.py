"""``vfmlab sim-rig``: serve the simulated pressure controller and load cell until Ctrl-C."""

from __future__ import annotations

import json

import click

from vfmlab.cli._common import console, esc

MMHG_PA = 133.322387415


EPILOG = """
\b
Examples:
  vfmlab sim-rig                           # then: vfmlab monitor --pressure PORT --load-cell PORT
  vfmlab sim-rig --manual --pressure-mmhg 80 --stretch 1.2 --json --duration 60
"""


@click.command(epilog=EPILOG)
@click.option("--socket", "use_socket", is_flag=True,
              help="Serve on socket://127.0.0.1:PORT instead of pseudo-terminals.")
@click.option("--manual", is_flag=True,
              help="Pressure set by the operator (a Mensor CPG2500 indicator) instead of a CPC controller "
                   "that follows its set-point.")
@click.option("--pressure-mmhg", default=0.0, show_default=True, type=float,
              help="Operator pressure (with --manual).")
@click.option("--stretch", default=1.0, show_default=True, type=click.FloatRange(min=0.5, max=3.0),
              help="Axial stretch of the simulated specimen (sets the force).")
@click.option("--load-cell-measures", type=click.Choice(["wall", "total"]), default="wall", show_default=True,
              help="What the simulated cell reads: the wall force, or the total force behind a closed cannula "
                   "(wall force minus pressure x lumen area).")
@click.option("--seed", default=0, show_default=True, type=int, help="Seed of the simulated noise.")
@click.option("--duration", default=None, type=click.FloatRange(min=0.0),
              help="Stop after this many seconds (default: run until Ctrl-C).")
@click.option("--json", "as_json", is_flag=True, help="Print the ports as one JSON line (for scripts).")
def command(use_socket, manual, pressure_mmhg, stretch, load_cell_measures, seed, duration, as_json):
    """Serve simulated instruments (Mensor pressure, Mark-10 load cell) in the foreground.

    Prints the ports to connect to, e.g. `vfmlab monitor --pressure PORT --load-cell PORT`, and runs until
    Ctrl-C. The pressure follows the controller's set-point (`Mode control`, `Setpt`) with a first-order
    response, or with --manual the value given by --pressure-mmhg.
    """
    from vfmlab.simrig import serve_until, simulated_instruments

    rig = simulated_instruments(use_socket, manual, load_cell_measures, seed)
    with rig:
        rig.set_stretch(stretch)
        if manual:
            rig.set_operator_pressure(pressure_mmhg * MMHG_PA)
        if as_json:
            click.echo(json.dumps({"pressure": rig.pressure_port, "load_cell": rig.load_cell_port,
                                   "pressure_serial": rig.pressure_serial,
                                   "load_cell_serial": rig.load_cell_serial,
                                   "pressure_device": rig.device_path("pressure"),
                                   "load_cell_device": rig.device_path("force")}))
        else:
            kind = "CPG2500 indicator (manual pressure)" if manual else "CPC6050 controller"
            console.print(f"pressure  (Mensor {kind}, s/n {esc(rig.pressure_serial)}): {esc(rig.pressure_port)}")
            console.print(f"load cell (Mark-10 M5-20, s/n {esc(rig.load_cell_serial)}): {esc(rig.load_cell_port)}")
            console.print(f"\ntry:  vfmlab monitor --pressure {esc(rig.pressure_port)} "
                          f"--load-cell {esc(rig.load_cell_port)}\n\nCtrl-C to stop.")
        serve_until(duration)
    if not as_json:
        console.print("simulated instruments stopped")
