"""``vfmlab reconstruct``: detect, match, triangulate and track the markers of a session."""

from __future__ import annotations

import logging
from pathlib import Path

import click
import numpy as np
from rich.table import Table

from vfmlab.cli._common import console, esc, print_json

log = logging.getLogger(__name__)


def _summary_table(res, step_numbers, camera_names) -> Table:
    d = res.diagnostics
    t = Table(title=f"Markers: {res.visible.shape[1]} tracked identities (counts of markers per step)")
    for col in ("step", "detected (all cameras)", "reconstructed", "tracked", "lost", "recovered",
                "reprojection median (px)", "median uncertainty (mm)"):
        t.add_column(col, justify="right")
    for k, s in enumerate(step_numbers):
        u = res.uncertainty[k][res.visible[k]]
        t.add_row(str(s), str(int(d["detected"][k].sum())), str(int(d["reconstructed"][k])), str(int(d["tracked"][k])),
                  str(int(d["lost"][k])), str(int(d["recovered"][k])), f"{d['reprojection_rms_median'][k]:.3f}",
                  f"{np.median(u) * 1e3:.4f}" if u.size else "–")
    return t


EPILOG = """
\b
Examples:
  vfmlab reconstruct a1.h5
  vfmlab reconstruct a1.h5 --calibration calibration.toml --marker-diameter-mm 0.4 --json
"""


@click.command(epilog=EPILOG)
@click.argument("session", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--marker-diameter-mm", type=float, default=None,
              help="Diameter of the spherical markers, mm [default: from the session (import-images), else 0.4].")
@click.option("--calibration", type=click.Path(dir_okay=False, path_type=Path),
              help="Calibration file (.toml aniposelib / .yaml OpenCV) [default: latest calibration in SESSION].")
@click.option("--calibration-units", type=click.Choice(["mm", "m", "cm", "um"]), default=None,
              help="Length unit of a calibration file without a units key [default: mm].")
@click.option("--frame", type=click.Choice(["specimen", "calibration"]), default="specimen", show_default=True,
              help="Output frame: the rig frame (z on the fitted specimen axis, origin at mid-length) or the "
                   "calibration's world frame.")
@click.option("--flip-axis", is_flag=True, help="Reverse +z of the specimen frame (towards the other cannula).")
@click.option("--normals", type=click.Choice(["local", "cylinder"]), default="local", show_default=True,
              help="Surface normals for the marker-centre offset.")
@click.option("--epipolar-px", type=float, default=2.0, show_default=True, help="Epipolar gate of candidate matches, px.")
@click.option("--max-reprojection-px", type=float, default=1.5, show_default=True,
              help="Largest reprojection error of a view accepted in a point, px.")
@click.option("--include-superseded", is_flag=True, help="Also reconstruct steps that were retaken.")
@click.option("--store/--no-store", default=True, show_default=True, help="Write a 'markers' result into SESSION.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
def command(session, marker_diameter_mm, calibration, calibration_units, frame, flip_axis, normals, epipolar_px,
            max_reprojection_px, include_superseded, store, as_json):
    """Reconstruct the 3-D marker positions of every step of SESSION and track their identities.

    Detects the dark spherical markers in each camera image with sub-pixel centres, matches them
    across cameras, triangulates them (with uncertainty), follows each marker from the reference
    step (step 0) through all steps, and moves each sphere centre one marker radius back onto the
    wall. Writes positions (n_steps, n_markers, 3), visibility and uncertainty as a new "markers"
    result; markers not seen in a step are NaN there.
    """
    from vfmlab.cli._common import show_warning
    from vfmlab.cli._feedback import progress_bar
    from vfmlab.stages.feedback import no_progress
    from vfmlab.stages.reconstruct import reconstruct, resolve_cameras
    from vfmlab.stages.settings import ReconstructSettings

    settings = ReconstructSettings(marker_diameter_mm=marker_diameter_mm, calibration=calibration,
                                   calibration_units=calibration_units, frame=frame, flip_axis=flip_axis,
                                   normals=normals, epipolar_px=epipolar_px, max_reprojection_px=max_reprojection_px,
                                   include_superseded=include_superseded, store=store)
    cameras = resolve_cameras(session, settings, show_warning)  # before the progress bars, as its messages
    with (no_progress if as_json else progress_bar)("reconstruct", None) as update:  # a bar per stage, time left
        outcome = reconstruct(session, settings, progress=lambda step, n, stage: update(step + 1, n, stage),
                              cameras=cameras, invoked_by="reconstruct")
    summary = outcome.to_dict()
    if as_json:
        print_json(summary)
        return
    console.print(_summary_table(outcome.result, outcome.rows, outcome.names))
    rej = ", ".join(f"{k} {v}" for k, v in summary["rejects"].items() if v)
    console.print(f"Rejected blobs: {esc(rej or 'none')}. Calibration: {esc(outcome.source)}.")
    if outcome.stored:
        console.print(f"Stored as [bold]{esc(outcome.stored)}[/] in {esc(session)}.")
