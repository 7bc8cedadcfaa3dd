"""``vfmlab report``: write the HTML report of a session, with its figures as PNG files."""

from __future__ import annotations

from pathlib import Path

import click

from vfmlab.cli._common import console, esc, print_json
from vfmlab.cli._outputs import check_output_dir

EPILOG = """
\b
Examples:
  vfmlab report a1.h5                          # into a1_report/ next to the session
  vfmlab report a1.h5 -o reports/a1 --strain-scale per-step   # replaces an earlier report there
"""


@click.command("report", epilog=EPILOG)
@click.argument("session", type=click.Path(dir_okay=False))
@click.option("-o", "--out", "out", type=click.Path(file_okay=False),
              help="Output directory [default: <SESSION stem>_report next to the session]; its parent must exist.")
@click.option("--strain-scale", type=click.Choice(["shared", "per-step"]), default="shared", show_default=True,
              help="Colour scale of the strain and stress maps: one scale for all steps (compare steps) or one per step "
                   "(detail within a step); the figure says which.")
@click.option("--force", is_flag=True, help="Write into an existing folder that is not a report folder (its other files "
                                           "are kept); an earlier report is replaced without it.")
@click.option("--json", "as_json", is_flag=True, help="Print the files written as JSON.")
def command(session, out, strain_scale, force, as_json):
    """Write a self-contained HTML report of SESSION (figures embedded) and each figure as SVG, 300 dpi PNG and
    JSON data. Re-running replaces the earlier report; an interrupted run leaves it as it was."""
    from vfmlab.cli._feedback import progress_bar
    from vfmlab.report import is_report_dir
    from vfmlab.stages.feedback import no_progress
    from vfmlab.stages.outputs import default_out, report
    from vfmlab.stages.settings import ReportSettings

    out_dir = default_out(session, out, "report")
    check_output_dir(out_dir, force=force or is_report_dir(out_dir), inputs=[Path(session)])
    o = report(session, ReportSettings(out=out_dir, strain_scale=strain_scale),
               progress=no_progress if as_json else progress_bar)
    if as_json:
        print_json(o.to_dict())
        return
    html = o.html
    console.print(f"Report written to [bold]{esc(html)}[/] ({len(o.figures)} figures in {esc(html.parent)}, "
                  f"{o.seconds:.1f} s). Open it in a browser: {esc(html.resolve().as_uri())}")
