"""``vfmlab calibrate``: calibrate all cameras jointly from calibration-board images (the stage:
:mod:`vfmlab.stages.calibrate`); this module parses the options and prints the outcome."""

from __future__ import annotations

from pathlib import Path

import click

from vfmlab.cli._common import CliError, CliInputError, console, esc, print_json
from vfmlab.cli._outputs import check_output_path


EPILOG = """
\b
Examples:
  vfmlab calibrate a1.h5                                  # board views stored in the session
  vfmlab calibrate --images boards/ --squares 8x6 --square-size-mm 4.5 -o calibration.toml
  vfmlab calibrate a1.h5 --import calibration.toml --import-units mm
  vfmlab calibrate a1.h5 --refine-window                  # through the rig file's [window], its plane refined
  vfmlab calibrate a1.h5 --import openptv-project/ --body fixed   # OpenPTV cameras + window, refined on its body
  vfmlab calibrate a1.h5 --import openptv-project/ --self-calibrate 10000-10004   # then on the particles
"""


@click.command(epilog=EPILOG)
@click.argument("session", required=False, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--images", "images_dir", type=click.Path(file_okay=False, path_type=Path),
              help="Board images as DIR/<camera>/<view>.png (views matched by file name across cameras). "
                   "Default: the calibration images stored in SESSION.")
@click.option("--board", type=click.Choice(["charuco", "chessboard", "circles", "acircles"]), default="charuco",
              show_default=True, help="Target type.")
@click.option("--squares", default="8x6", show_default=True,
              help="COLSxROWS: squares of a ChArUco board; inner corners of a chessboard; circles of a grid.")
@click.option("--square-size-mm", type=float, default=4.5, show_default=True, help="Square side / circle spacing, mm.")
@click.option("--marker-size-mm", type=float, default=3.4, show_default=True, help="ArUco marker side (ChArUco), mm.")
@click.option("--dictionary", default="DICT_4X4_50", show_default=True, help="OpenCV ArUco dictionary (ChArUco).")
@click.option("--subpix-window", type=int, default=5, show_default=True,
              help="Half-window (px) of cornerSubPix; keep it below a quarter of a square in pixels.")
@click.option("--reference", default=None, help="Camera whose frame is the world frame (default: the first).")
@click.option("--world-view", type=int, default=None,
              help="Express the calibration in the board frame of this view instead (e.g. a view with the board "
                   "aligned to the specimen axis).")
@click.option("--fix-k3/--free-k3", default=None,
              help="Keep the 6th-order radial term at zero, or fit it [default: free only if it predicts held-out "
                   "board views better; an unphysical distortion is refused either way].")
@click.option("-o", "--out", "out", type=click.Path(dir_okay=False, path_type=Path),
              help="Write the calibration to this file: .toml (aniposelib) or .yaml/.yml (OpenCV FileStorage).")
@click.option("--force", is_flag=True, help="Overwrite --out if it exists.")
@click.option("--units", type=click.Choice(["mm", "m"]), default="mm", show_default=True,
              help="Length unit of the translations in --out.")
@click.option("--store/--no-store", default=True, show_default=True,
              help="Store the result in SESSION (as a new 'calibration' result) when a session is given.")
@click.option("--import", "import_file", type=click.Path(exists=True, path_type=Path),
              help="Take the calibration from a file instead of board images: aniposelib calibration.toml, "
                   "OpenCV FileStorage .yaml/.yml/.xml/.json, or an OpenPTV working folder (parameters/ptv.par, "
                   "cal/*.ori + .addpar: cameras with their glass/water window). Store it in SESSION and/or convert it with -o.")
@click.option("--body", type=click.Choice(["fixed", "free", "selected"]), default=None,
              help="With an OpenPTV folder: refine every camera on its image of the 3-D calibration body "
                   "(cal/camN.tif, cal/target_on_a_side.txt) through the window; 'fixed' keeps the imported focal "
                   "length, 'free' refines it too and refuses the result if one view cannot determine it; 'selected' "
                   "refines per camera only the terms the dots determine over the whole image (the better seed for "
                   "--self-calibrate; a few minutes).")
@click.option("--self-calibrate", "selfcal_frames", metavar="FRAMES", default=None,
              help="With an OpenPTV folder for --import: refine the cameras (imported, or refined on the body with "
                   "--body) on the particles of these frames, e.g. 10000-10004 or 10000,10002 (volume "
                   "self-calibration: pose, k1, principal point and window tilt per camera, jointly with the "
                   "calibration body's dots; 15-45 s for 5 frames on 2 cores). The figures before/after are stored with "
                   "the calibration.")
@click.option("--particle-images", default="img_1/cam{camera}.{frame}", show_default=True,
              help="With --self-calibrate: the particle images inside the --import folder; {camera} = 1, 2, ..., "
                   "{frame} = the frame number.")
@click.option("--body-weight", type=float, default=0.5, show_default=True,
              help="With --self-calibrate: weight of a calibration-body dot's residual against a particle's.")
@click.option("--body-sides/--one-body", default=True, show_default=True,
              help="With --self-calibrate: cameras looking at the calibration body from its other side see it offset "
                   "along its normal by a distance refined with the cameras (a body whose dots are seen from both "
                   "faces, the target file giving one; test_cavity: 1.8-2.0 mm), or one body for all cameras.")
@click.option("--volume-mm", metavar="XMIN,XMAX,YMIN,YMAX,ZMIN,ZMAX", default=None,
              help="With --self-calibrate: the measurement volume, mm (world frame of the calibration). Default: "
                   "the region seen by >= 3 cameras within criteria.par's depth range (Zmin/Zmax) +- 5 mm.")
@click.option("--import-units", type=click.Choice(["m", "cm", "mm", "um"]), default="mm", show_default=True,
              help="Length unit of an imported file's translations when the file does not say (aniposelib does not).")
@click.option("--refine-window", is_flag=True,
              help="Also refine the window the session's rig file states ([window]: plane distance and normal, one "
                   "plane shared by all cameras); refused if the board views cannot determine it. Without the flag a "
                   "recorded window is used as it is; a session without one calibrates with straight rays.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
def command(session, as_json, force, **options):
    """Calibrate the cameras jointly from calibration-board images.

    Each camera is initialised alone (OpenCV), camera poses are chained through shared board
    views, then one bundle adjustment refines all intrinsics (fx, fy, cx, cy, k1, k2, p1, p2, k3)
    and all camera and board poses together, rejecting outliers. Prints the RMS reprojection error
    per camera; writes --out and/or stores the result in SESSION.
    """
    from vfmlab.cli._feedback import notify, progress_bar
    from vfmlab.stages.calibrate import calibrate
    from vfmlab.stages.settings import CalibrateSettings

    out = options["out"]
    if out is not None and out.suffix.lower() not in (".toml", ".yaml", ".yml"):
        raise CliInputError(f"--out must end in .toml, .yaml or .yml; got {out.name!r}")
    if out is not None:
        check_output_path(out, force=force, inputs=[session, options["import_file"]])
    outcome = calibrate(session, CalibrateSettings(**options), notify=notify, progress=progress_bar)
    if as_json:
        print_json(outcome.summary)
    elif outcome.result is None:
        _print_import(outcome, session)
    else:
        _print_board(outcome, session)




def _table(result):
    from rich.table import Table

    t = Table(title="Calibration (joint bundle adjustment)")
    for col in ("camera", "views", "RMS (px)", "init RMS (px)", "fx (px)", "fy (px)", "cx (px)", "cy (px)", "k1", "k2"):
        t.add_column(col, justify="right" if col != "camera" else "left")
    for i, (row, cam) in enumerate(zip(result.summary(), result.cameras)):
        t.add_row(esc(row["camera"]), str(row["views"]), f"{row['rms_px']:.3f}", f"{result.initial_rms[i]:.3f}",
                  f"{row['fx']:.1f}±{row['fx_std']:.1f}", f"{row['fy']:.1f}±{row['fy_std']:.1f}",
                  f"{row['cx']:.1f}±{row['cx_std']:.1f}", f"{row['cy']:.1f}±{row['cy_std']:.1f}",
                  f"{cam.dist[0]:+.4f}", f"{cam.dist[1]:+.4f}")
    return t


def _print_board(outcome, session) -> None:
    """The per-camera table, the windows and the totals of a board calibration; exit 1 when a camera kept
    no observation."""
    import numpy as np

    result, summary = outcome.result, outcome.summary
    console.print(_table(result))
    for w in summary.get("windows", []):
        line = f"window ({esc(', '.join(w['cameras']))}): plane distance {w['plane_distance_mm']:.3f} mm"
        if "plane_distance_std_mm" in w:
            line += (f" ± {w['plane_distance_std_mm']:.3f} mm (moved {w['plane_shift_mm']:+.3f} mm), normal ± "
                     f"{w['normal_std_deg']:.3f} deg (turned {w['normal_change_deg']:.3f} deg), refined")
        else:
            line += ", as the rig file states (not refined)"
        console.print(line)
    console.print(f"total RMS {result.rms_total:.3f} px over {result.n_observations} observations; "
                  f"{result.n_outliers} outliers rejected; converged: {result.converged}")
    console.print(f"distortion: {esc(summary['distortion_choice'])}")
    if summary["out"] is not None:
        console.print(f"wrote {esc(summary['out'])}")
    if outcome.stored:
        console.print(f"stored as {outcome.stored} in {esc(session)}")
    if not np.all(np.isfinite(result.rms)):
        raise CliError("some cameras have no inlier observations")


def _print_import(outcome, session) -> None:
    """What an import read, refined, stored and wrote."""
    cams, meta, path, out = outcome.cameras, outcome.meta, outcome.summary["imported_from"], outcome.summary["out"]
    console.print(f"imported {len(cams)} cameras from {esc(path)}: {esc(', '.join(c.name for c in cams))}")
    if "body_rms_px" in meta:
        console.print("calibration body RMS: " + ", ".join(f"{esc(n)} {r:.3f} px" for n, r in meta["body_rms_px"].items())
                      + f"; media assumed: {esc(meta['media_assumed'])}")
    if "self_calibration" in meta:
        _print_selfcal(meta["self_calibration"])
    if outcome.stored:
        console.print(f"stored as {outcome.stored} in {esc(session)}")
    if out is not None:
        console.print(f"wrote {esc(out)}")
    if not outcome.stored and out is None:
        console.print("nothing stored: give a SESSION (or -o for a calibration without a window) to keep these cameras")


def _print_selfcal(f: dict) -> None:
    console.print(f"self-calibration: {esc(f['message'])}; particle RMS after the last pass {f['particle_rms_px'][-1]:.3f} px")
    console.print(f"disparity peaks at the first pass's tolerances: {f['disparity_peak_rms_px_before']:.3f} px RMS "
                  f"(max {f['disparity_peak_max_px_before']:.3f} px) before, {f['disparity_peak_rms_px_after']:.3f} px RMS "
                  f"(max {f['disparity_peak_max_px_after']:.3f} px) after")
    if f["body_far_side_cameras"]:
        console.print(f"body as {esc(', '.join(f['body_far_side_cameras']))} see it (its other side): offset "
                      f"{1e3 * f['body_offset_m']:+.3f} mm along its normal")
    console.print("calibration body RMS before -> after: " + ", ".join(
        f"{esc(n)} {f['body_rms_px_before'][n]:.3f} -> {r:.3f} px" for n, r in f["body_rms_px_after"].items()))
