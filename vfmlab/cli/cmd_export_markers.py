"""``vfmlab export-markers``: write a session's latest marker tracks as CSV."""

from __future__ import annotations

import click
import numpy as np

from acquisition.markers_csv import write_markers_csv
from vfmlab.cli._common import console, esc, print_json
from vfmlab.cli._outputs import check_output_path
from vfmlab.cli._sessions import cli_session, latest_markers
from vfmlab.stages.outputs import marker_labels

EPILOG = """
\b
Examples:
  vfmlab export-markers a1.h5 -o a1-markers.csv                 # x_m,y_m,z_m (SI)
  vfmlab export-markers a1.h5 -o a1-markers.csv --units mm --result markers_002 --force
"""


@click.command("export-markers", epilog=EPILOG)
@click.argument("session", type=click.Path(dir_okay=False))
@click.option("-o", "--out", required=True, type=click.Path(dir_okay=False), help="CSV file to write.")
@click.option("--result", default=None, help="A specific markers result (e.g. markers_002) [default: latest].")
@click.option("--units", type=click.Choice(["m", "mm"]), default="m", show_default=True,
              help="Unit of the coordinates, named in the header (x_m or x_mm); import-markers reads both.")
@click.option("--force", is_flag=True, help="Overwrite OUT if it exists (never a session file).")
@click.option("--json", "as_json", is_flag=True, help="Print what was written as JSON.")
def command(session, out, result, units, force, as_json):
    """Write the latest marker tracks of SESSION (imported or reconstructed) as
    marker_id,step,x_m,y_m,z_m (or x_mm,y_mm,z_mm with --units mm), one row per marker and step."""
    check_output_path(out, force=force, inputs=[session])
    with cli_session(session) as s:
        res = s.result(result) if result else latest_markers(s)
    arrays = res["arrays"]
    positions = arrays["positions"]
    labels = marker_labels(res, session)
    steps = arrays.get("step_number", arrays.get("step_index", np.arange(positions.shape[0])))
    write_markers_csv(out, np.asarray(labels).astype(str), np.asarray(steps), positions, units=units)
    if as_json:
        print_json({"out": str(out), "result": res["name"], "n_markers": int(positions.shape[1]),
                    "n_steps": int(positions.shape[0]), "units": units})
        return
    console.print(f"Wrote {positions.shape[1]} markers × {positions.shape[0]} steps from {esc(res['name'])} "
                  f"to {esc(out)} (coordinates in {units})")
