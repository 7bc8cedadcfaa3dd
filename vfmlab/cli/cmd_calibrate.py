"""``vfmlab calibrate``: calibrate all cameras jointly from calibration-board images (the stage:
:mod:`vfmlab.stages.calibrate`); this module parses the options and prints the outcome."""

from __future__ import annotations

from pathlib import Path

import click

from vfmlab.cli._common import CliError, CliInputError, console, print_json
from vfmlab.cli._outputs import check_output_path


EPILOG = """
\b
Examples:
  vfmlab calibrate a1.h5                                  # board views stored in the session
  vfmlab calibrate --images boards/ --squares 8x6 --square-size-mm 4.5 -o calibration.toml
  vfmlab calibrate a1.h5 --import calibration.toml --import-units mm    # or a MATLAB calibrationSession.mat
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
              help="Take the calibration from a file instead of board images: aniposelib .toml, OpenCV FileStorage "
                   ".yaml/.yml/.xml/.json, a MATLAB stereo calibrationSession.mat (DuoDIC), or an OpenPTV folder (ptv.par, "
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
    from vfmlab.views.calibrate import board_lines, import_lines
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
        for line in import_lines(outcome, session):
            console.print(line)
    else:
        import numpy as np

        for line in board_lines(outcome, session):
            console.print(line)
        if not np.all(np.isfinite(outcome.result.rms)):
            raise CliError("some cameras have no inlier observations")
