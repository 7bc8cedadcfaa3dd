"""``vfmlab report``: write the HTML report of a session, with its figures as PNG files."""

from __future__ import annotations

import time
from pathlib import Path

import click

from vfmlab.cli._common import console


@click.command("report")
@click.argument("session", type=click.Path(dir_okay=False))
@click.option("-o", "--out", "out", type=click.Path(file_okay=False),
              help="Output directory [default: <SESSION stem>_report next to the session].")
def command(session, out):
    """Write a self-contained HTML report of SESSION (figures embedded) and the figures as PNG files."""
    from vfmlab.report import build_report

    t0 = time.perf_counter()
    with console.status("Building the report..."):
        path = build_report(session, out)
    n_fig = len(list(Path(path).parent.glob("fig*.png")))
    console.print(f"Report written to [bold]{path}[/] ({n_fig} figures in {path.parent}, "
                  f"{time.perf_counter() - t0:.1f} s). Open it in a browser: file://{path.resolve()}")
