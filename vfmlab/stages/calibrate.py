"""The calibrate stage: all cameras jointly from calibration-board images (a folder or the session's), or an
imported calibration (:mod:`vfmlab.stages.calibrate_import`); stored in the session and/or written to a file.

Lengths in the settings in mm as on the command line (``vfmlab calibrate``), SI in the stored result.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from vfmlab.stages.calibration_files import CalibrationOutcome, write_cameras
from vfmlab.stages.errors import StageError, StageFailed
from vfmlab.stages.feedback import Notify, ProgressFactory, log_notes, no_progress
from vfmlab.stages.settings import CalibrateSettings, settings_with

log = logging.getLogger(__name__)

__all__ = ["CalibrationOutcome", "calibrate", "window_rows"]

_IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm"}
def calibrate(session: str | Path | None, settings: CalibrateSettings | None = None, *, notify: Notify = log_notes,
              progress: ProgressFactory = no_progress, **overrides: Any) -> CalibrationOutcome:
    """Calibrate (or import) the cameras and store them as a new "calibration" result of ``session``
    (``settings.store``) and/or write ``settings.out`` (.toml aniposelib, .yaml/.yml OpenCV): ``vfmlab calibrate``,
    its defaults :class:`CalibrateSettings`. An existing ``out`` is overwritten."""
    s = settings_with(CalibrateSettings, settings, overrides)
    session = None if session is None else Path(session)
    if s.import_file is not None:
        if s.images_dir is not None:
            raise StageError("--import and --images exclude each other: calibrate from images or import a calibration")
        from vfmlab.stages.calibrate_import import import_calibration

        return import_calibration(Path(s.import_file), session, s, notify=notify, progress=progress)
    if s.selfcal_frames is not None:
        raise StageError("--self-calibrate needs --import FOLDER (an OpenPTV folder with its particle images)")
    if session is None and s.images_dir is None:
        raise StageError("give a SESSION (its calibration images) or --images DIR")
    return _calibrate_from_board(session, s, progress)


def _calibrate_from_board(session: Path | None, s: CalibrateSettings, progress: ProgressFactory) -> CalibrationOutcome:
    from reconstruction.calibration import CalibrationError, calibrate_from_detections

    spec = board_spec(s)
    window = session_window(session, s.refine_window)
    if window is not None and s.out is not None:
        raise StageError(f"-o {s.out}: TOML/YAML files hold no window (refraction); store the calibration in the session")
    if s.images_dir is not None:
        detections, sizes, source = detect_in_folder(Path(s.images_dir), spec, progress)
    else:
        detections, sizes, source = detect_in_session(session, spec, progress)
    for c in detections:
        if c not in sizes:
            raise StageError(f"camera {c!r}: no readable images")
    names = list(detections)
    ref = reference_index(names, s.reference)
    found = {c: sum(len(d) > 0 for d in detections[c]) for c in names}
    log.info("board found per camera: %s", ", ".join(f"{c} in {n} views" for c, n in found.items()))
    try:
        choice = _distortion_model(detections, spec, sizes, ref, window, s.fix_k3)
        result = calibrate_from_detections(detections, spec, sizes, reference=ref, world_view=s.world_view,
                                           fix_k3=choice.fix_k3, windows=window, refine_window=s.refine_window)
    except CalibrationError as exc:
        raise StageFailed(f"calibration failed: {exc} (board views found per camera: "
                          f"{', '.join(f'{c} {n}' for c, n in found.items())})") from None
    _refuse_unphysical(result, choice.fix_k3)
    if result.window_fit is not None and not result.window_fit.well_posed:
        raise StageFailed(f"--refine-window: {result.window_fit.message}. Nothing stored; calibrate without "
                          "--refine-window to keep the rig file's window")
    if s.out is not None:
        write_cameras(Path(s.out), result.cameras, s.units,
                      {"created_by": "vfmlab calibrate", "source": source, "rms_px": result.rms.tolist(),
                       "board": f"{s.board} {s.squares} {s.square_size_mm} mm"})
    stored = None
    if session is not None and s.store:
        params = dict(board=s.board, squares=s.squares, square_size_m=spec.square_size, marker_size_m=spec.marker_size,
                      dictionary=s.dictionary, subpix_window=s.subpix_window, reference=names[ref],
                      world_view=s.world_view, fix_k3=choice.fix_k3, distortion_choice=choice.reason,
                      heldout_rms_px=choice.heldout_rms_px, source=source,
                      window=None if window is None else window.to_dict(), refine_window=s.refine_window)
        stored = _store_board(session, result, params)
    summary = {"cameras": result.summary(), "rms_total_px": result.rms_total, "n_observations": result.n_observations,
               "n_outliers": result.n_outliers, "converged": result.converged, "views_found": found,
               "out": str(s.out) if s.out else None, "stored_as": stored,
               "fix_k3": choice.fix_k3, "distortion_choice": choice.reason, "heldout_rms_px": choice.heldout_rms_px}
    windows = window_rows(result)
    if windows:
        summary["windows"] = windows
    return CalibrationOutcome(summary, list(result.cameras), stored, result)


def _distortion_model(detections, spec, sizes, ref: int, window, fix_k3: bool | None):
    """The distortion model to calibrate with: as asked (``fix_k3`` True/False), or chosen by held-out views."""
    from reconstruction.calibration import detections_to_arrays
    from reconstruction.calibration_select import DistortionChoice, choose_distortion

    if fix_k3 is not None:
        return DistortionChoice(bool(fix_k3), "k3 fixed at 0 (--fix-k3)" if fix_k3 else "k3 free (--free-k3)")
    names, uv, obj = detections_to_arrays(detections, spec)
    choice = choose_distortion(uv, obj, [sizes[n] for n in names], names, reference=ref, windows=window,
                               resolve_flips=spec.kind in ("chessboard", "circles"))
    log.info("distortion model: %s", choice.reason)
    return choice


def _refuse_unphysical(result, fix_k3: bool) -> None:
    """StageFailed when a calibrated camera's distortion is one no lens has (nothing is stored or written)."""
    from reconstruction.calibration_select import distortion_problem

    problems = [p for p in (distortion_problem(c) for c in result.cameras) if p]
    if problems:
        hint = "calibrate with --fix-k3" if not fix_k3 else "check the board views (they should cover the image)"
        raise StageFailed(f"unphysical lens distortion: {'; '.join(problems)}. Nothing stored; {hint}")


def folder_views(images_dir: Path) -> tuple[list[str], list[str], dict[str, dict[str, Path]]]:
    """Camera names, view stems and ``{camera: {stem: path}}`` from ``DIR/<camera>/<view>.<ext>``."""
    if not images_dir.is_dir():
        raise StageError(f"--images: {images_dir} is not a folder (expected DIR/<camera>/<view>.png)")
    cams = sorted(p.name for p in images_dir.iterdir() if p.is_dir())
    if not cams:
        raise StageError(f"--images: {images_dir} has no camera sub-folders (expected DIR/<camera>/<view>.png)")
    files = {c: {p.stem: p for p in sorted((images_dir / c).iterdir()) if p.suffix.lower() in _IMAGE_SUFFIXES} for c in cams}
    stems = sorted(set().union(*[set(f) for f in files.values()]))
    if not stems:
        raise StageError(f"--images: no images ({', '.join(sorted(_IMAGE_SUFFIXES))}) under {images_dir}/<camera>/")
    return cams, stems, files


def board_spec(s: CalibrateSettings):
    """The ``reconstruction.targets.BoardSpec`` of the settings (mm -> m); StageError for a malformed one."""
    from reconstruction.targets import BoardSpec, TargetError

    try:
        cols, rows = (int(v) for v in s.squares.lower().split("x"))
    except ValueError:
        raise StageError(f"--squares must look like 8x6 (columns x rows); got {s.squares!r}") from None
    try:
        return BoardSpec(s.board, cols, rows, s.square_size_mm * 1e-3, s.marker_size_mm * 1e-3, s.dictionary,
                         s.subpix_window)
    except TargetError as exc:
        raise StageError(str(exc)) from None


def detect_in_folder(images_dir: Path, spec, progress: ProgressFactory = no_progress) -> tuple[dict, dict, str]:
    """Board detections ``{camera: [BoardDetection per view]}``, image sizes and the source, from DIR/<camera>/<view>."""
    import cv2

    from reconstruction.targets import BoardDetection, detect_board

    detections: dict = {}
    sizes: dict = {}
    cams, stems, files = folder_views(images_dir)
    with progress("detecting board", len(cams) * len(stems)) as update:
        for c in cams:
            dets = []
            for stem in stems:
                path = files[c].get(stem)
                if path is None:
                    dets.append(BoardDetection.empty())
                else:
                    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
                    if img is None:
                        raise StageError(f"cannot read image {path}")
                    sizes.setdefault(c, (img.shape[1], img.shape[0]))
                    dets.append(detect_board(img, spec))
                update()
            detections[c] = dets
    return detections, sizes, str(images_dir)


def detect_in_session(session: Path, spec, progress: ProgressFactory = no_progress) -> tuple[dict, dict, str]:
    """Board detections, image sizes and the source, from the calibration images stored in SESSION."""
    from acquisition.session import open_session
    from vfmlab.pipeline import session_board_detections

    with open_session(session) as s:
        with progress("detecting board", None) as update:
            try:
                detections, sizes = session_board_detections(s, spec, update)
            except ValueError as exc:
                raise StageError(f"{session}: {exc}; use --images DIR") from None
    return detections, sizes, f"{session} (calibration images)"


def session_window(session: Path | None, refine: bool):
    """The window the session's rig settings record (``[window]`` of the rig file), or None; ``--refine-window``
    without one is an input error. Board images from ``--images`` stored into a session are taken as seen
    through that session's window too."""
    window = None
    if session is not None:
        from acquisition.session import open_session
        from reconstruction.refraction import Window

        with open_session(session) as s:
            record = (s.rig_settings or {}).get("window")
        window = Window.from_dict(record) if record else None
    if refine and window is None:
        raise StageError("--refine-window: no window to refine (" + ("the session's rig file has no [window] table"
                         if session is not None else "give the SESSION whose rig file states it") + ")")
    return window


def window_rows(result) -> list[dict]:
    """The windows of the result, one row per plane (mm, deg), for people and --json."""
    if result.window_fit is not None:
        return result.window_fit.summary()
    wins = {}
    for c in result.cameras:
        if c.window is not None:
            wins.setdefault(repr(c.window.to_dict()), (c.window, []))[1].append(c.name)
    return [dict(cameras=names, plane_distance_mm=1e3 * w.offset, normal=[float(v) for v in w.normal], refined=False)
            for w, names in wins.values()]


def reference_index(names: list[str], reference: str | None) -> int:
    """Index of the ``--reference`` camera in ``names`` (0 when None)."""
    if reference is None:
        return 0
    if reference not in names:
        raise StageError(f"--reference must be one of {names}; got {reference!r}")
    return names.index(reference)


def _store_board(session: Path, result, params: dict) -> str:
    """Store the board calibration as a new 'calibration' result of SESSION; its name."""
    from acquisition.session import SessionError, write_result
    from reconstruction.calibration_io import cameras_to_arrays

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
    units = {"K": "px", "tvec": "m", "rvec": "rad", "rms": "px", "rms_per_view": "px", "image_size": "px",
             "board_tvecs": "m", "board_rvecs": "rad", "window_offset": "m", "window_thickness": "m",
             "window_normal": "1", "window_index": "1"}
    try:
        return write_result(session, "calibration", arrays, params, attrs, units=units)
    except SessionError as exc:
        raise StageFailed(str(exc)) from None
