"""``vfmlab export-markers``: write a session's latest marker tracks as CSV."""

from __future__ import annotations

import click
import numpy as np

from acquisition.markers_csv import write_markers_csv
from vfmlab.cli._common import console
from vfmlab.cli._outputs import check_output_path
from vfmlab.cli._sessions import cli_session, latest_markers


@click.command("export-markers")
@click.argument("session", type=click.Path(dir_okay=False))
@click.option("-o", "--out", required=True, type=click.Path(dir_okay=False), help="CSV file to write.")
@click.option("--result", default=None, help="A specific markers result (e.g. markers_002) [default: latest].")
@click.option("--force", is_flag=True, help="Overwrite an existing output file (never a session or an input).")
def command(session, out, result, force):
    """Write the latest marker tracks of SESSION (imported or reconstructed) as
    marker_id,step,x_mm,y_mm,z_mm."""
    check_output_path(out, force=force, inputs=[session])
    with cli_session(session) as s:
        res = s.result(result) if result else latest_markers(s)
    arrays = res["arrays"]
    positions = arrays["positions"]
    labels = arrays.get("marker_label", arrays.get("marker_id", np.arange(positions.shape[1])))
    steps = arrays.get("step_number", arrays.get("step_index", np.arange(positions.shape[0])))
    write_markers_csv(out, np.asarray(labels).astype(str), np.asarray(steps), positions)
    console.print(f"Wrote {positions.shape[1]} markers x {positions.shape[0]} steps from {res['name']} to {out}")
