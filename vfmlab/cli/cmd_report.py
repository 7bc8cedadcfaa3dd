"""``vfmlab report``: write the HTML report of a session, with its figures as PNG files."""

from __future__ import annotations

import time
from pathlib import Path

import click

from vfmlab.cli._common import CliError, console
from vfmlab.cli._outputs import check_output_dir


@click.command("report")
@click.argument("session", type=click.Path(dir_okay=False))
@click.option("-o", "--out", "out", type=click.Path(file_okay=False),
              help="Output directory [default: <SESSION stem>_report next to the session].")
@click.option("--force", is_flag=True, help="Overwrite the files of an existing report folder.")
def command(session, out, force):
    """Write a self-contained HTML report of SESSION (figures embedded) and the figures as PNG files."""
    from vfmlab.report import ReportError, build_report

    out_dir = Path(out) if out else Path(session).with_name(Path(session).stem + "_report")
    if (out_dir / "report.html").exists() or (out_dir.exists() and not out_dir.is_dir()):
        check_output_dir(out_dir, force=force, inputs=[session])
    t0 = time.perf_counter()
    try:
        with console.status("Building the report..."):
            path = build_report(session, out)
    except ReportError as exc:
        raise CliError(str(exc)) from None
    n_fig = len(list(Path(path).parent.glob("fig*.png")))
    console.print(f"Report written to [bold]{path}[/] ({n_fig} figures in {path.parent}, "
                  f"{time.perf_counter() - t0:.1f} s). Open it in a browser: file://{path.resolve()}")
