"""``vfmlab calibrate``: calibrate all cameras jointly from calibration-board images."""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path

import click
import numpy as np
from rich.progress import Progress
from rich.table import Table

from vfmlab.cli._common import CliError, CliInputError, console, err_console, esc, print_json
from vfmlab.cli._outputs import check_output_path

log = logging.getLogger(__name__)

_IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm"}


def _folder_views(images_dir: Path) -> tuple[list[str], list[str], dict[str, dict[str, Path]]]:
    """Camera names, view stems and ``{camera: {stem: path}}`` from ``DIR/<camera>/<view>.<ext>``."""
    if not images_dir.is_dir():
        raise CliInputError(f"--images: {images_dir} is not a folder (expected DIR/<camera>/<view>.png)")
    cams = sorted(p.name for p in images_dir.iterdir() if p.is_dir())
    if not cams:
        raise CliInputError(f"--images: {images_dir} has no camera sub-folders (expected DIR/<camera>/<view>.png)")
    files = {c: {p.stem: p for p in sorted((images_dir / c).iterdir()) if p.suffix.lower() in _IMAGE_SUFFIXES} for c in cams}
    stems = sorted(set().union(*[set(f) for f in files.values()]))
    if not stems:
        raise CliInputError(f"--images: no images ({', '.join(sorted(_IMAGE_SUFFIXES))}) under {images_dir}/<camera>/")
    return cams, stems, files


def _board_spec(board, squares, square_size_mm, marker_size_mm, dictionary, subpix):
    from reconstruction import BoardSpec, TargetError

    try:
        cols, rows = (int(v) for v in squares.lower().split("x"))
    except ValueError:
        raise CliInputError(f"--squares must look like 8x6 (columns x rows); got {squares!r}") from None
    try:
        return BoardSpec(board, cols, rows, square_size_mm * 1e-3, marker_size_mm * 1e-3, dictionary, subpix)
    except TargetError as exc:
        raise CliInputError(str(exc)) from None


def _table(result) -> Table:
    t = Table(title="Calibration (joint bundle adjustment)")
    for col in ("camera", "views", "RMS (px)", "init RMS (px)", "fx (px)", "fy (px)", "cx (px)", "cy (px)", "k1", "k2"):
        t.add_column(col, justify="right" if col != "camera" else "left")
    for i, (row, cam) in enumerate(zip(result.summary(), result.cameras)):
        t.add_row(esc(row["camera"]), str(row["views"]), f"{row['rms_px']:.3f}", f"{result.initial_rms[i]:.3f}",
                  f"{row['fx']:.1f}±{row['fx_std']:.1f}", f"{row['fy']:.1f}±{row['fy_std']:.1f}",
                  f"{row['cx']:.1f}±{row['cx_std']:.1f}", f"{row['cy']:.1f}±{row['cy_std']:.1f}",
                  f"{cam.dist[0]:+.4f}", f"{cam.dist[1]:+.4f}")
    return t


def _read_calibration(path: Path, file_units: str, body: str | None) -> tuple[list, dict]:
    """Cameras and metadata of ``--import``: a TOML/YAML file or an OpenPTV folder (optionally refined on its body)."""
    from reconstruction import CalibrationFileError, cameras_from_toml, cameras_from_yaml
    from vfmlab import openptv

    try:
        if path.is_dir():
            cams = openptv.load_cameras(path)
            return (cams, {"units": "m"}) if body is None else _refine_on_body(path, cams, body)
        if body is not None:
            raise CliError("--body needs an OpenPTV folder for --import (its cal/camN.tif and cal/target_on_a_side.txt)")
        reader = cameras_from_toml if path.suffix.lower() == ".toml" else cameras_from_yaml
        return reader(path.read_text(), units=file_units)
    except (CalibrationFileError, UnicodeDecodeError, OSError) as exc:
        raise CliInputError(f"--import {path}: {exc}") from None


def _refine_on_body(folder: Path, cams: list, focal: str) -> tuple[list, dict]:
    """Refine the imported cameras on the calibration body, through the window; refuse an ill-posed result."""
    from vfmlab import openptv

    if focal == "selected":
        return _select_on_body(folder, cams)
    media, note = _body_media(cams)
    err_console.print(f"media assumed: {note}")
    res = openptv.calibrate_body_folder(folder, cams, media=media, **{**openptv.BODY_FIT, "fix_focal": focal == "fixed"})
    for r in res:
        err_console.print(r.message)
    bad = [r.camera.name for r in res if not r.well_posed]
    if bad:
        raise CliInputError(f"--body: calibration of {bad} is ill-posed (focal length not determined by one view of this body); "
                       "use --body fixed to keep the imported focal length")
    return [r.camera for r in res], {"units": "m", "rms_px": [r.rms for r in res],
                                     "body_calibration": f"{folder}/cal (focal {focal})", "media_assumed": note,
                                     "body_rms_px": {r.camera.name: float(r.rms) for r in res}}


def _select_on_body(folder: Path, cams: list) -> tuple[list, dict]:
    """``--body selected``: per camera only the terms the body's dots determine over the whole image, media as
    in ptv.par (as OpenPTV's calibration was made)."""
    from vfmlab import openptv

    window = next((c.window for c in cams if c.window is not None), None)
    note = f"{openptv.describe_media(window)} (as in ptv.par)"
    err_console.print(f"media assumed: {note}")
    with Progress(console=err_console, transient=True) as progress:
        task = progress.add_task("body model selection (32 models per camera)", total=len(cams))
        sel = openptv.select_body_folder(folder, cams, progress=lambda d, t, name: progress.update(task, completed=d))
    for s in sel:
        err_console.print(f"{s.calibration.camera.name}: model {s.chosen}, RMS {s.calibration.rms:.3f} px "
                          f"(cross-validated {s.table[s.chosen]['cv_rms_px']:.3f} px)")
    return [s.calibration.camera for s in sel], {
        "units": "m", "rms_px": [s.calibration.rms for s in sel], "body_calibration": f"{folder}/cal (selected models)",
        "media_assumed": note, "body_rms_px": {s.calibration.camera.name: float(s.calibration.rms) for s in sel},
        "body_models": {s.calibration.camera.name: s.chosen for s in sel}}


def _body_media(cams: list) -> tuple[dict | None, str]:
    """Media for the body fit (ptv.par's indices swapped to physical order when glass < water) and a sentence."""
    from vfmlab import openptv

    window = next((c.window for c in cams if c.window is not None), None)
    media = openptv.physical_media(window)
    if media is None:
        return None, f"{openptv.describe_media(window)} (as in ptv.par)"
    fixed = replace(window, **media)
    return media, (f"{openptv.describe_media(fixed)} (ptv.par lists glass {window.indices[0]:.3f} and water "
                   f"{window.n_bath:.3f}: swapped to the physical order, glass denser than water)")


def _import(path: Path, file_units: str, session, store: bool, out, units: str, as_json: bool, body: str | None = None,
            selfcal: dict | None = None) -> None:
    """``--import``: read a calibration, check it against the session's cameras, optionally refine it on the
    particles (``selfcal``: options of :func:`_self_calibrate`), store and/or convert it."""
    from reconstruction import cameras_to_arrays, cameras_to_toml, cameras_to_yaml

    if selfcal is not None:
        _check_selfcal_folder(path)
    cams, meta = _read_calibration(path, file_units, body)
    if out is not None and any(c.window is not None for c in cams):  # before a self-calibration's minute of work
        raise CliInputError(f"-o {out}: TOML/YAML files hold no window (refraction); store the calibration in a session instead")
    if selfcal is not None:
        cams, meta = _self_calibrate(path, cams, meta, **selfcal)
    stored = None
    if session is not None and store:
        from acquisition.session import SessionError, write_result
        from vfmlab.cli._sessions import cli_session

        with cli_session(session) as s:
            wanted = s.camera_names
            sizes = {c.name: (c.width, c.height) for c in s.cameras}
        names = [c.name for c in cams]
        missing = [n for n in wanted if n not in names]
        if missing:
            raise CliInputError(f"--import {path}: the session's cameras {missing} are not in the file (it has {names})")
        bad = [c.name for c in cams if c.name in sizes and tuple(sizes[c.name]) != tuple(c.image_size)]
        if bad:
            raise CliInputError(f"--import {path}: image size differs from the session's for cameras {bad}")
        cams = [next(c for c in cams if c.name == n) for n in wanted]
        rms = meta.get("rms_px")
        rms = np.asarray(rms, float) if isinstance(rms, list) and len(rms) == len(names) else None
        arrays = cameras_to_arrays(cams, None if rms is None else [rms[names.index(c.name)] for c in cams])
        try:
            params = {"source": str(path), "imported": True, "file_units": meta.get("units", file_units)}
            attrs = {"converged": True, "n_observations": 0, "n_outliers": 0}
            for key in ("body_calibration", "body_models", "media_assumed"):
                if key in meta:
                    params[key] = meta[key]
            if "self_calibration" in meta:
                params["self_calibration"] = meta["self_calibration_settings"]
                attrs["self_calibration"] = meta["self_calibration"]
            stored = write_result(session, "calibration", arrays, params, attrs,
                                  units={"K": "px", "tvec": "m", "rvec": "rad", "rms": "px", "image_size": "px",
                                         "window_offset": "m", "window_thickness": "m", "window_normal": "1", "window_index": "1"})
        except SessionError as exc:
            raise CliError(str(exc)) from None
    if out is not None:
        meta = {k: v for k, v in meta.items() if k not in ("units", "self_calibration", "self_calibration_settings")}
        meta["imported_from"] = str(path)
        writer = cameras_to_toml if out.suffix.lower() == ".toml" else cameras_to_yaml
        out.write_text(writer(cams, units=units, metadata=meta))
    summary = {"cameras": [c.name for c in cams], "imported_from": str(path), "stored_as": stored,
               "out": str(out) if out else None}
    if "body_rms_px" in meta:
        summary["body_rms_px"] = meta["body_rms_px"]
        summary["media_assumed"] = meta["media_assumed"]
    if "body_models" in meta:
        summary["body_models"] = meta["body_models"]
    if "self_calibration" in meta:
        summary["self_calibration"] = {**meta["self_calibration_settings"], **meta["self_calibration"]}
    if as_json:
        print_json(summary)
        return
    console.print(f"imported {len(cams)} cameras from {esc(path)}: {esc(', '.join(c.name for c in cams))}")
    if "body_rms_px" in meta:
        console.print("calibration body RMS: " + ", ".join(f"{esc(n)} {r:.3f} px" for n, r in meta["body_rms_px"].items())
                      + f"; media assumed: {esc(meta['media_assumed'])}")
    if "self_calibration" in meta:
        _print_selfcal(meta["self_calibration"])
    if stored:
        console.print(f"stored as {stored} in {esc(session)}")
    if out is not None:
        console.print(f"wrote {esc(out)}")
    if not stored and out is None:
        console.print("nothing stored: give a SESSION (or -o for a calibration without a window) to keep these cameras")


# ------------------------------------------------------------------------------------- --self-calibrate

def _parse_frames(text: str) -> list[int]:
    """``10000-10004`` or ``10000,10002`` (or both mixed) -> frame numbers."""
    frames: list[int] = []
    try:
        for part in text.split(","):
            lo, _, hi = part.strip().partition("-")
            frames += list(range(int(lo), int(hi) + 1)) if hi else [int(lo)]
    except ValueError:
        raise CliInputError(f"--self-calibrate must list frame numbers like 10000-10004 or 10000,10002; got {text!r}") from None
    if not frames:
        raise CliInputError(f"--self-calibrate must name at least one frame; got {text!r}")
    return sorted(set(frames))


def _parse_volume(text: str | None):
    """``XMIN,XMAX,YMIN,YMAX,ZMIN,ZMAX`` in mm -> ``(lo, hi)`` in m, or None."""
    if text is None:
        return None
    try:
        v = np.array([float(x) for x in text.split(",")]) * 1e-3
    except ValueError:
        v = np.zeros(0)
    if v.shape != (6,) or not np.all(np.isfinite(v)) or np.any(v[1::2] <= v[0::2]):
        raise CliInputError(f"--volume-mm must be XMIN,XMAX,YMIN,YMAX,ZMIN,ZMAX in mm with each min < max; got {text!r}")
    return v[0::2], v[1::2]


def _check_selfcal_folder(path: Path) -> None:
    from vfmlab import openptv

    if not openptv.is_openptv_folder(path):
        raise CliInputError(f"--self-calibrate needs an OpenPTV folder for --import (its particle images, cal/camN.tif "
                            f"and cal/target_on_a_side.txt); got {path}")


def _self_calibrate(folder: Path, cams: list, meta: dict, *, frames: str, images: str, body_weight: float,
                    volume: str | None, body_sides: bool) -> tuple[list, dict]:
    """Refine ``cams`` on the particles of ``frames`` (volume self-calibration) with progress; the cameras and
    ``meta`` with ``self_calibration`` (figures, SI/px keys) and ``self_calibration_settings``."""
    from vfmlab import openptv

    numbers, bounds = _parse_frames(frames), _parse_volume(volume)
    if not body_weight > 0:
        raise CliInputError(f"--body-weight must be > 0 (the body's dots fix the gauge); got {body_weight}")
    no_window = [c.name for c in cams if c.window is None]
    if no_window:
        raise CliInputError(f"--self-calibrate: cameras {no_window} of --import {folder} have no window (ptv.par's media "
                            "are all air?); the self-calibration refines the window's tilt through glass and water")
    with Progress(console=err_console, transient=True) as progress:
        task = progress.add_task("self-calibration", total=None)

        def tick(done, total, what):
            progress.update(task, completed=done, total=total, description=f"self-calibration: {esc(what)}")

        try:
            sc, bounds, pts, px, dets = openptv.self_calibrate_folder(folder, cams, numbers, images=images,
                                                                      body_weight=body_weight, bounds=bounds, progress=tick,
                                                                      body_sides=body_sides)
        except FileNotFoundError as exc:
            raise CliInputError(f"--self-calibrate {frames} (--particle-images {images}): {exc}") from None
        except ValueError as exc:
            raise CliInputError(f"--self-calibrate {frames}: {exc}") from None
    if not sc.particle_rms_px:
        raise CliError(f"--self-calibrate: {sc.message}; nothing stored (more frames, or a calibration closer to "
                       "consistent, e.g. --body)")
    out = _selfcal_meta(sc, cams, numbers, images, body_weight, bounds, pts, px, dets, body_sides)
    if not out["self_calibration"]["disparity_improved"]:
        err_console.print("warning: --self-calibrate made the cameras less consistent (disparity peaks "
                          f"{sc.maps[0].rms_peak_offset_px:.3f} -> {sc.check_map.rms_peak_offset_px:.3f} px RMS at the first "
                          "pass's tolerances); a calibration whose distortion extrapolates (e.g. --body fixed) is a poor seed")
    return sc.cameras, {**meta, **out}


def _selfcal_meta(sc, before: list, frames, images, body_weight, bounds, pts, px, dets, body_sides: bool) -> dict:
    """What the session and --json keep of a self-calibration (SI and px, the unit in every key)."""
    from reconstruction import body_rms
    from vfmlab import openptv

    names = [c.name for c in before]
    settings = {"frames": frames, "particle_images": images, "body_weight": body_weight,
                "refined": list(openptv.SELFCAL_SETTINGS["free"]),
                "schedule_px": [list(t) for t in openptv.SELFCAL_SETTINGS["schedule"]], "body_sides": body_sides,
                "volume_min_m": [float(v) for v in bounds[0]], "volume_max_m": [float(v) for v in bounds[1]]}
    figures = {"message": sc.message, "passes_run": len(sc.particle_rms_px),
               "particles_per_frame": {str(f): [len(d) for d in row] for f, row in zip(frames, dets)},
               "candidates": sc.n_candidates, "consistent": sc.n_used,
               "particle_rms_px": [float(r) for r in sc.particle_rms_px],
               "disparity_peak_rms_px_before": sc.maps[0].rms_peak_offset_px,
               "disparity_peak_rms_px_after": sc.check_map.rms_peak_offset_px,
               "disparity_peak_max_px_before": sc.maps[0].max_peak_offset_px,
               "disparity_peak_max_px_after": sc.check_map.max_peak_offset_px,
               "disparity_improved": bool(sc.check_map.rms_peak_offset_px < sc.maps[0].rms_peak_offset_px),
               "body_offset_m": sc.body_offset_m,
               "body_far_side_cameras": [] if sc.far_side is None else [n for n, f in zip(names, sc.far_side) if f],
               "body_rms_px_before": dict(zip(names, body_rms(before, pts, px).tolist())),
               "body_rms_px_after": dict(zip(names, sc.body_rms_px.tolist()))}
    return {"self_calibration": figures, "self_calibration_settings": settings, "rms_px": sc.body_rms_px.tolist()}


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
@click.option("--fix-k3/--free-k3", default=False, show_default=True, help="Keep the 6th-order radial term at zero.")
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
def command(session, images_dir, board, squares, square_size_mm, marker_size_mm, dictionary, subpix_window, reference,
            world_view, fix_k3, out, force, units, store, import_file, selfcal_frames, particle_images, body_weight,
            body_sides, volume_mm, import_units, body, refine_window, as_json):
    """Calibrate the cameras jointly from calibration-board images.

    Each camera is initialised alone (OpenCV), camera poses are chained through shared board
    views, then one bundle adjustment refines all intrinsics (fx, fy, cx, cy, k1, k2, p1, p2, k3)
    and all camera and board poses together, rejecting outliers. Prints the RMS reprojection error
    per camera; writes --out and/or stores the result in SESSION.
    """
    from reconstruction import CalibrationError, calibrate_from_detections

    if out is not None and out.suffix.lower() not in (".toml", ".yaml", ".yml"):
        raise CliInputError(f"--out must end in .toml, .yaml or .yml; got {out.name!r}")
    if out is not None:
        check_output_path(out, force=force, inputs=[session, import_file])
    if import_file is not None:
        if images_dir is not None:
            raise CliInputError("--import and --images exclude each other: calibrate from images or import a calibration")
        selfcal = None if selfcal_frames is None else dict(frames=selfcal_frames, images=particle_images,
                                                           body_weight=body_weight, volume=volume_mm,
                                                           body_sides=body_sides)
        _import(import_file, import_units, session, store, out, units, as_json, body, selfcal)
        return
    if selfcal_frames is not None:
        raise CliInputError("--self-calibrate needs --import FOLDER (an OpenPTV folder with its particle images)")
    if session is None and images_dir is None:
        raise CliInputError("give a SESSION (its calibration images) or --images DIR")
    spec = _board_spec(board, squares, square_size_mm, marker_size_mm, dictionary, subpix_window)
    window = _session_window(session, refine_window)
    if window is not None and out is not None:
        raise CliInputError(f"-o {out}: TOML/YAML files hold no window (refraction); store the calibration in the session")
    if images_dir is not None:
        detections, sizes, source = _detect_in_folder(images_dir, spec)
    else:
        detections, sizes, source = _detect_in_session(session, spec)
    for c in detections:
        if c not in sizes:
            raise CliInputError(f"camera {c!r}: no readable images")
    names = list(detections)
    ref = _reference_index(names, reference)
    found = {c: sum(len(d) > 0 for d in detections[c]) for c in names}
    log.info("board found per camera: %s", ", ".join(f"{c} in {n} views" for c, n in found.items()))
    try:
        result = calibrate_from_detections(detections, spec, sizes, reference=ref, world_view=world_view, fix_k3=fix_k3,
                                           windows=window, refine_window=refine_window)
    except CalibrationError as exc:
        raise CliError(f"calibration failed: {exc} (board views found per camera: "
                       f"{', '.join(f'{c} {n}' for c, n in found.items())})") from None
    if result.window_fit is not None and not result.window_fit.well_posed:
        raise CliError(f"--refine-window: {result.window_fit.message}. Nothing stored; calibrate without "
                       "--refine-window to keep the rig file's window")
    if out is not None:
        _write_file(out, result, units, {"created_by": "vfmlab calibrate", "source": source,
                                         "rms_px": result.rms.tolist(), "board": f"{board} {squares} {square_size_mm} mm"})
    stored = None
    if session is not None and store:
        params = dict(board=board, squares=squares, square_size_m=spec.square_size, marker_size_m=spec.marker_size,
                      dictionary=dictionary, subpix_window=subpix_window, reference=names[ref], world_view=world_view,
                      fix_k3=fix_k3, source=source, window=None if window is None else window.to_dict(),
                      refine_window=refine_window)
        stored = _store(session, result, params)
    _report(result, found, out, session, stored, as_json)


def _detect_in_folder(images_dir: Path, spec) -> tuple[dict, dict, str]:
    """Board detections ``{camera: [BoardDetection per view]}``, image sizes and the source, from DIR/<camera>/<view>."""
    import cv2

    from reconstruction import BoardDetection, detect_board

    detections: dict = {}
    sizes: dict = {}
    cams, stems, files = _folder_views(images_dir)
    with Progress(console=err_console, transient=True) as progress:
        task = progress.add_task("detecting board", total=len(cams) * len(stems))
        for c in cams:
            dets = []
            for stem in stems:
                path = files[c].get(stem)
                if path is None:
                    dets.append(BoardDetection.empty())
                else:
                    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
                    if img is None:
                        raise CliInputError(f"cannot read image {path}")
                    sizes.setdefault(c, (img.shape[1], img.shape[0]))
                    dets.append(detect_board(img, spec))
                progress.advance(task)
            detections[c] = dets
    return detections, sizes, str(images_dir)


def _detect_in_session(session: Path, spec) -> tuple[dict, dict, str]:
    """Board detections, image sizes and the source, from the calibration images stored in SESSION."""
    from vfmlab.cli._sessions import cli_session
    from vfmlab.pipeline import session_board_detections

    with cli_session(session) as s:
        with Progress(console=err_console, transient=True) as progress:
            task = progress.add_task("detecting board", total=None)
            try:
                detections, sizes = session_board_detections(s, spec, lambda: progress.advance(task))
            except ValueError as exc:
                raise CliInputError(f"{session}: {exc}; use --images DIR") from None
    return detections, sizes, f"{session} (calibration images)"


def _session_window(session: Path | None, refine: bool):
    """The window the session's rig settings record (``[window]`` of the rig file), or None; ``--refine-window``
    without one is an input error. Board images from ``--images`` stored into a session are taken as seen
    through that session's window too."""
    window = None
    if session is not None:
        from reconstruction import Window
        from vfmlab.cli._sessions import cli_session

        with cli_session(session) as s:
            record = (s.rig_settings or {}).get("window")
        window = Window.from_dict(record) if record else None
    if refine and window is None:
        raise CliInputError("--refine-window: no window to refine (" + ("the session's rig file has no [window] table"
                            if session is not None else "give the SESSION whose rig file states it") + ")")
    return window


def _window_rows(result) -> list[dict]:
    """The windows of the result, one row per plane (mm, deg), for people and --json."""
    if result.window_fit is not None:
        return result.window_fit.summary()
    wins = {}
    for c in result.cameras:
        if c.window is not None:
            wins.setdefault(repr(c.window.to_dict()), (c.window, []))[1].append(c.name)
    return [dict(cameras=names, plane_distance_mm=1e3 * w.offset, normal=[float(v) for v in w.normal], refined=False)
            for w, names in wins.values()]


def _reference_index(names: list[str], reference: str | None) -> int:
    if reference is None:
        return 0
    if reference not in names:
        raise CliInputError(f"--reference must be one of {names}; got {reference!r}")
    return names.index(reference)


def _write_file(out: Path, result, units: str, meta: dict) -> None:
    from reconstruction import cameras_to_toml, cameras_to_yaml

    text = (cameras_to_toml if out.suffix.lower() == ".toml" else cameras_to_yaml)(result.cameras, units=units, metadata=meta)
    out.write_text(text)


def _store(session: Path, result, params: dict) -> str:
    """Store the board calibration as a new 'calibration' result of SESSION; its name."""
    from acquisition.session import SessionError, write_result
    from reconstruction import cameras_to_arrays

    arrays = cameras_to_arrays(result.cameras, result.rms)
    arrays["rms_per_view"] = result.rms_per_view
    arrays["board_rvecs"] = result.board_rvecs
    arrays["board_tvecs"] = result.board_tvecs
    attrs = dict(rms_total=result.rms_total, n_observations=result.n_observations, n_outliers=result.n_outliers,
                 converged=result.converged, message=result.message)
    fit = result.window_fit
    if fit is not None:  # SI, the unit in the key
        attrs["window_fit"] = [dict(cameras=fit.cameras[g], plane_distance_m=w.offset, normal=[float(v) for v in w.normal],
                                    plane_distance_std_m=float(fit.offset_std[g]), normal_std_rad=float(fit.normal_std[g]),
                                    nominal_plane_distance_m=fit.nominal[g].offset,
                                    nominal_normal=[float(v) for v in fit.nominal[g].normal],
                                    max_correlation=float(np.max(fit.max_correlation[g])))
                               for g, w in enumerate(fit.refined)]
        attrs["window_message"] = fit.message
    try:
        return write_result(session, "calibration", arrays, params, attrs,
                            units={"K": "px", "tvec": "m", "rvec": "rad", "rms": "px", "rms_per_view": "px",
                                   "image_size": "px", "board_tvecs": "m", "board_rvecs": "rad", "window_offset": "m",
                                   "window_thickness": "m", "window_normal": "1", "window_index": "1"})
    except SessionError as exc:
        raise CliError(str(exc)) from None


def _report(result, found: dict, out, session, stored, as_json: bool) -> None:
    """Print the per-camera table (or JSON); exit 1 when a camera kept no observation."""
    summary = {"cameras": result.summary(), "rms_total_px": result.rms_total, "n_observations": result.n_observations,
               "n_outliers": result.n_outliers, "converged": result.converged, "views_found": found,
               "out": str(out) if out else None, "stored_as": stored}
    windows = _window_rows(result)
    if windows:
        summary["windows"] = windows
    if as_json:
        print_json(summary)
        return
    console.print(_table(result))
    for w in windows:
        line = f"window ({esc(', '.join(w['cameras']))}): plane distance {w['plane_distance_mm']:.3f} mm"
        if "plane_distance_std_mm" in w:
            line += (f" ± {w['plane_distance_std_mm']:.3f} mm (moved {w['plane_shift_mm']:+.3f} mm), normal ± "
                     f"{w['normal_std_deg']:.3f} deg (turned {w['normal_change_deg']:.3f} deg), refined")
        else:
            line += ", as the rig file states (not refined)"
        console.print(line)
    console.print(f"total RMS {result.rms_total:.3f} px over {result.n_observations} observations; "
                  f"{result.n_outliers} outliers rejected; converged: {result.converged}")
    if out is not None:
        console.print(f"wrote {esc(out)}")
    if stored:
        console.print(f"stored as {stored} in {esc(session)}")
    if not np.all(np.isfinite(result.rms)):
        raise CliError("some cameras have no inlier observations")
