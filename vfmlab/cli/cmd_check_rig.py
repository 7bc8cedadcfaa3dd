"""``vfmlab check-rig``: the pre-flight check of the rig (cameras, instruments, stage), one verdict per device."""

from __future__ import annotations

import click

from vfmlab.cli._common import console, err_console, esc, print_json

EPILOG = """
\b
Nothing moves. Exit code 0 when no device is at FAULT, 1 otherwise (2: bad rig file).
Examples:
  vfmlab check-rig --sim -o check/            # then look at check/cam0.png ...
  vfmlab check-rig --rig lab-rig.toml --seconds 10
"""


@click.command("check-rig", epilog=EPILOG)
@click.option("--rig", "rig", type=click.Path(dir_okay=False), help="Rig configuration (ports, cameras, [stage]).")
@click.option("--sim", is_flag=True, help="Check the simulated rig (faults from its [simulation.faults]).")
@click.option("--sim-seed", type=click.IntRange(min=0), default=None, metavar="N", help="With --sim: its seed.")
@click.option("--seconds", type=click.FloatRange(min=0.5, max=600.0), default=3.0, show_default=True,
              help="How long the instruments are read for their zero offset, noise and drift.")
@click.option("-o", "--out", "out", type=click.Path(file_okay=False),
              help="Folder for the images with their detected markers (PNG) and check.json.")
@click.option("--json", "as_json", is_flag=True, help="Print the verdicts as JSON.")
def command(rig, sim, sim_seed, seconds, out, as_json):
    """Grab a frame from every camera and read every instrument for a few seconds; say what is wrong."""
    from vfmlab.stages.check import check_rig

    check = check_rig(rig=rig, sim=sim, sim_seed=sim_seed, seconds=seconds, out=out, notify=(err_console if as_json else console).print)
    if as_json:
        print_json(check.to_dict())
    else:
        style = {"OK": "green", "CHECK": "yellow", "FAULT": "bold red"}
        for d in check.devices:
            console.print(f"[{style[d.verdict]}]{esc(d.line)}[/]")
        console.print(esc(check.views_line))
    if not check.passed:
        raise click.exceptions.Exit(1)
