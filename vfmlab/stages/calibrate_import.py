"""``vfmlab calibrate --import``: a calibration read from a file (aniposelib TOML, OpenCV YAML, MATLAB
``calibrationSession.mat``) or an OpenPTV folder (optionally refined on its calibration body and/or on its
particles), checked against the session's cameras, stored and/or converted. One reader per format; the
self-calibration is :mod:`vfmlab.stages.selfcal`.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from vfmlab.stages.calibration_files import CALIBRATION_UNITS, CalibrationOutcome, write_cameras
from vfmlab.stages.errors import StageError, StageFailed
from vfmlab.stages.feedback import Notify, ProgressFactory, log_notes, no_progress
from vfmlab.stages.settings import CalibrateSettings

__all__ = ["import_calibration", "read_calibration", "read_calibration_file", "read_matlab_file", "read_openptv_folder"]


def import_calibration(path: Path, session: Path | None, s: CalibrateSettings, *, notify: Notify = log_notes,
                       progress: ProgressFactory = no_progress) -> CalibrationOutcome:
    """Read the calibration at ``path``, optionally refine it on the particles (``s.self_calibration()``),
    store it in ``session`` (``s.store``) and/or convert it to ``s.out``."""
    from vfmlab.stages import selfcal

    sc = s.self_calibration()
    if sc is not None:
        selfcal.check_folder(path)
    cams, meta = read_calibration(path, s.import_units, s.body, notify=notify, progress=progress)
    out = None if s.out is None else Path(s.out)
    if out is not None and any(c.window is not None for c in cams):  # before a self-calibration's minute of work
        raise StageError(f"-o {out}: TOML/YAML files hold no window (refraction); store the calibration in a session instead")
    if sc is not None:
        cams, meta = selfcal.self_calibrate(path, cams, meta, sc, notify=notify, progress=progress)
    stored = None
    if session is not None and s.store:
        cams, stored = _store_imported(path, session, cams, meta, s.import_units)
    if out is not None:  # what the file keeps is also what the summary reports
        meta = {k: v for k, v in meta.items() if k not in ("units", "self_calibration", "self_calibration_settings")}
        meta["imported_from"] = str(path)
        write_cameras(out, cams, s.units, meta)
    return CalibrationOutcome(_summary(path, cams, meta, stored, out), cams, stored, None, meta)


def read_calibration(path: Path, file_units: str, body: str | None, *, notify: Notify = log_notes,
                     progress: ProgressFactory = no_progress) -> tuple[list, dict]:
    """Cameras and metadata of ``--import``: a TOML/YAML file or an OpenPTV folder (optionally refined on its body)."""
    from reconstruction.calibration_io import CalibrationFileError

    try:
        if path.is_dir():
            return read_openptv_folder(path, body, notify=notify, progress=progress)
        if body is not None:
            raise StageFailed("--body needs an OpenPTV folder for --import (its cal/camN.tif and cal/target_on_a_side.txt)")
        return read_calibration_file(path, file_units)
    except (CalibrationFileError, UnicodeDecodeError, OSError) as exc:
        raise StageError(f"--import {path}: {exc}") from None
    except (SystemError, _cv2_error()):  # OpenCV's FileStorage on a file that is no YAML/XML
        raise StageError(f"--import {path}: not a calibration file OpenCV can read (expected .toml (aniposelib), "
                         f".yaml/.yml/.xml (OpenCV), .mat (MATLAB) or an OpenPTV folder)") from None


def _cv2_error() -> type[Exception]:
    import cv2

    return cv2.error


def read_calibration_file(path: Path, file_units: str) -> tuple[list, dict]:
    """Cameras and metadata of an aniposelib ``.toml``, a MATLAB ``calibrationSession.mat`` (:func:`read_matlab_file`)
    or an OpenCV FileStorage file (any other suffix)."""
    from reconstruction.calibration_io import cameras_from_toml, cameras_from_yaml

    if path.suffix.lower() == ".mat":
        return read_matlab_file(path)
    reader = cameras_from_toml if path.suffix.lower() == ".toml" else cameras_from_yaml
    return reader(path.read_text(), units=file_units)


def read_matlab_file(path: Path) -> tuple[list, dict]:
    """The two cameras (``cam1``, ``cam2``; world = camera 1, m) of a MATLAB Stereo Camera Calibrator session
    (DuoDIC's ``calibrationSession.mat``), converted to OpenCV's conventions by ``acquisition.dic``; MATLAB's
    reprojection RMS per camera as ``rms_px``. A file that is not such a session: StageError with the reader's message."""
    from acquisition.dic import DICImportError, read_matlab_calibration_session
    from reconstruction.calibration_io import cameras_from_arrays

    try:
        calibration = read_matlab_calibration_session(path)
    except DICImportError as exc:
        raise StageError(f"--import {exc}") from None
    rms = [float(r) for r in calibration.camera_arrays["rms"]]
    return cameras_from_arrays(calibration.camera_arrays), {"units": "m", "rms_px": rms}


def read_openptv_folder(folder: Path, body: str | None, *, notify: Notify = log_notes,
                        progress: ProgressFactory = no_progress) -> tuple[list, dict]:
    """The cameras (with their window) of an OpenPTV working folder, refined on its calibration body when
    ``body`` is "fixed", "free" or "selected"."""
    from vfmlab import openptv

    cams = openptv.load_cameras(folder)
    if body is None:
        return cams, {"units": "m"}
    if body == "selected":
        return _select_on_body(folder, cams, notify, progress)
    return _refine_on_body(folder, cams, body, notify)


def _refine_on_body(folder: Path, cams: list, focal: str, notify: Notify) -> tuple[list, dict]:
    """Refine the imported cameras on the calibration body, through the window; refuse an ill-posed result."""
    from vfmlab import openptv

    media, note = _body_media(cams)
    notify(f"media assumed: {note}")
    res = openptv.calibrate_body_folder(folder, cams, media=media, **{**openptv.BODY_FIT, "fix_focal": focal == "fixed"})
    for r in res:
        notify(r.message)
    bad = [r.camera.name for r in res if not r.well_posed]
    if bad:
        raise StageError(f"--body: calibration of {bad} is ill-posed (focal length not determined by one view of this "
                         "body); use --body fixed to keep the imported focal length")
    return [r.camera for r in res], {"units": "m", "rms_px": [r.rms for r in res],
                                     "body_calibration": f"{folder}/cal (focal {focal})", "media_assumed": note,
                                     "body_rms_px": {r.camera.name: float(r.rms) for r in res}}


def _select_on_body(folder: Path, cams: list, notify: Notify, progress: ProgressFactory) -> tuple[list, dict]:
    """``--body selected``: per camera only the terms the body's dots determine over the whole image, media as
    in ptv.par (as OpenPTV's calibration was made)."""
    from vfmlab import openptv

    window = next((c.window for c in cams if c.window is not None), None)
    note = f"{openptv.describe_media(window)} (as in ptv.par)"
    notify(f"media assumed: {note}")
    with progress("body model selection (32 models per camera)", len(cams)) as update:
        sel = openptv.select_body_folder(folder, cams, progress=lambda d, t, name: update(d))
    for s in sel:
        notify(f"{s.calibration.camera.name}: model {s.chosen}, RMS {s.calibration.rms:.3f} px "
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


def _session_order(path: Path, session: Path, cams: list) -> list:
    """``cams`` in the order of the session's cameras; every session camera must be there, at its image size
    (a session without cameras, e.g. from ``import-markers`` / ``import-dic``, takes the file's cameras as they are)."""
    from acquisition.session import open_session

    with open_session(session) as s:
        wanted = s.camera_names
        sizes = {c.name: (c.width, c.height) for c in s.cameras}
    if not wanted:
        return list(cams)
    names = [c.name for c in cams]
    missing = [n for n in wanted if n not in names]
    if missing:
        raise StageError(f"--import {path}: the session's cameras {missing} are not in the file (it has {names})")
    bad = [c.name for c in cams if c.name in sizes and tuple(sizes[c.name]) != tuple(c.image_size)]
    if bad:
        raise StageError(f"--import {path}: image size differs from the session's for cameras {bad}")
    return [next(c for c in cams if c.name == n) for n in wanted]


def _store_imported(path: Path, session: Path, cams: list, meta: dict, file_units: str) -> tuple[list, str]:
    """Store the imported cameras (in the session's order) as a new "calibration" result of ``session``;
    the cameras in that order and the result's name."""
    from acquisition.session import SessionError, write_result
    from reconstruction.calibration_io import cameras_to_arrays

    names = [c.name for c in cams]  # the file's order, that of meta["rms_px"]
    cams = _session_order(path, session, cams)
    rms = meta.get("rms_px")
    rms = np.asarray(rms, float) if isinstance(rms, list) and len(rms) == len(names) else None
    arrays = cameras_to_arrays(cams, None if rms is None else [rms[names.index(c.name)] for c in cams])
    params = {"source": str(path), "imported": True, "file_units": meta.get("units", file_units)}
    attrs = {"converged": True, "n_observations": 0, "n_outliers": 0}
    for key in ("body_calibration", "body_models", "media_assumed"):
        if key in meta:
            params[key] = meta[key]
    if "self_calibration" in meta:
        params["self_calibration"] = meta["self_calibration_settings"]
        attrs["self_calibration"] = meta["self_calibration"]
    try:
        return cams, write_result(session, "calibration", arrays, params, attrs, units=CALIBRATION_UNITS)
    except SessionError as exc:
        raise StageFailed(str(exc)) from None


def _summary(path: Path, cams: list, meta: dict, stored: str | None, out: Path | None) -> dict:
    """The command's ``--json`` of an import."""
    summary = {"cameras": [c.name for c in cams], "imported_from": str(path), "stored_as": stored,
               "out": str(out) if out else None}
    if "body_rms_px" in meta:
        summary["body_rms_px"] = meta["body_rms_px"]
        summary["media_assumed"] = meta["media_assumed"]
    if "body_models" in meta:
        summary["body_models"] = meta["body_models"]
    if "self_calibration" in meta:
        summary["self_calibration"] = {**meta["self_calibration_settings"], **meta["self_calibration"]}
    return summary
