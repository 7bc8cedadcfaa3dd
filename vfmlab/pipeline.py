"""Pipeline stages over session files: the functions the CLI commands, ``reprocess`` and the demo share.

Each stage reads what it needs from a session file, runs a stage package on the arrays and appends
one new result group (never overwriting); it returns the group's name. The registry ``STAGES`` maps
stage names to these functions so that ``vfmlab reprocess --stages reconstruct,identify`` runs
exactly the code ``vfmlab reconstruct`` / ``vfmlab identify`` run.

Errors: :class:`StageError` with one readable sentence (session path first).
"""

from __future__ import annotations

import inspect
import json
import logging
import os
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from acquisition.errors import ImplausibleInputError
from acquisition.plausibility import check_geometry, check_identifiable
from acquisition.session import SessionError, SessionWriteError, open_session, write_result
from vfmlab.parallel import fork_map
from vfmlab.results import round_floats
from vfmlab.stages.settings import IDENTIFY_DEFAULTS as _D
from vfmlab.stages.errors import StageError, StageUnavailable
from vfmlab.stages.imports import marker_outliers

log = logging.getLogger(__name__)

#: Standard deviation of a pressure reading used for the parameter uncertainty (Pa): ~0.02 mmHg,
#: a controller-grade transducer averaged over the dwell.
PRESSURE_NOISE = _D.pressure_noise
#: Standard deviation of a load-cell reading used for the parameter uncertainty (N).
FORCE_NOISE = _D.force_noise

__all__ = ["STAGES", "StageError", "StageUnavailable", "identification_arrays", "identify_session", "identify_stored",
           "load_identification_inputs", "read_identification_inputs", "reconstruct_session", "reconstruct_stored",
           "resolve_ends", "session_calibrated_cameras", "session_step_rows", "verdict_attrs"]


def load_identification_inputs(session, markers: str | None = None) -> dict[str, Any]:
    """What the identification needs from an open session, from the latest (or named) markers result.

    Returns positions (n_steps, n_markers, 3) m (NaN where not visible), pressure (n_steps,) Pa,
    force (n_steps,) N (wall force: a "total" load-cell reading is corrected by + p pi r_i^2 with
    the reference lumen radius r_i = radius - thickness, decision 0003), thickness m, rows
    (n_steps,) rows of the step table, markers_result name, notes (corrections applied) and
    uncertainty (n_steps, n_markers) m, the reconstruction's reported marker uncertainty (or None).
    """
    names = session.results("markers")
    if markers is not None and markers not in names:
        raise StageError(f"{session.path}: no markers result {markers!r}; markers results are {names}")
    if not names:
        raise StageError(f"{session.path}: no marker tracks yet; run 'vfmlab reconstruct' first "
                         "(or build the session with 'vfmlab import-markers')")
    result = session.result(markers or names[-1])
    arrays = result["arrays"]
    if "positions" not in arrays:
        raise StageError(f"{session.path}: the markers result {result['name']} has no 'positions' array")
    positions = np.asarray(arrays["positions"], dtype=float)
    if "visible" in arrays:
        positions = np.where(np.asarray(arrays["visible"], bool)[..., None], positions, np.nan)
    rows = np.asarray(arrays.get("step_index", np.arange(positions.shape[0])), int)
    if rows.size != positions.shape[0] or (rows.size and (rows.max() >= session.n_steps or rows.min() < 0)):
        raise StageError(f"{session.path}: markers result {result['name']} refers to steps {rows.tolist()} but the "
                         f"session has {session.n_steps} steps")
    specimen = session.specimen
    try:
        notes = check_identifiable(positions, source=f"{session.path}: {result['name']}")
        check_geometry(specimen.radius, specimen.thickness, specimen.length, source=f"{session.path}: specimen")
        labels = arrays.get("marker_label", arrays.get("marker_id", np.arange(positions.shape[1])))
        marker_outliers(positions, _labels(labels, positions.shape[1]), rows, radius=specimen.radius,
                        source=f"{session.path}: {result['name']}")
    except ImplausibleInputError as exc:
        raise StageError(str(exc)) from None
    steps = session.steps
    pressure = np.asarray(steps["pressure"], float)[rows]
    force = np.asarray(steps["force"], float)[rows]
    ends = {"ends": specimen.ends, "source": specimen.ends_source}
    if session.load_cell_measures == "total":
        r_i = specimen.radius - specimen.thickness
        force = force + pressure * np.pi * r_i**2
        notes.append(f"load cell measures total force: wall force = total + p*pi*r_i^2 with r_i = {r_i * 1e3:.3f} mm")
    uncertainty = np.asarray(arrays["uncertainty"], float) if "uncertainty" in arrays else None
    if uncertainty is not None and (uncertainty.shape != positions.shape[:2] or not np.isfinite(uncertainty).any()):
        uncertainty = None  # imported markers say no uncertainty (all NaN): none given
    return {"positions": positions, "pressure": pressure, "force": force, "thickness": float(specimen.thickness),
            "radius": float(specimen.radius), "length": float(specimen.length), "session_ends": ends,
            "markers_result": result["name"], "rows": rows, "notes": notes, "uncertainty": uncertainty}


def _labels(labels, n_markers: int) -> np.ndarray:
    """Marker labels as text for messages (their indices when the stored labels do not fit)."""
    labels = np.asarray(labels)
    if labels.shape != (n_markers,):
        return np.arange(n_markers).astype(str)
    return np.array([v.decode("utf-8", "replace") if isinstance(v, bytes) else str(v) for v in labels.tolist()])


def read_identification_inputs(path: str | os.PathLike, markers: str | None = None) -> dict[str, Any]:
    """:func:`load_identification_inputs` of the session file at ``path``; a session fault is a ``StageError``."""
    try:
        with open_session(path) as session:
            return load_identification_inputs(session, markers)
    except SessionError as exc:
        raise StageError(str(exc)) from None


def resolve_ends(session_ends: dict[str, str], requested: str | None) -> tuple[str | None, str, list[str], list[str]]:
    """The end condition to identify with, where it comes from, notes and warnings.

    Parameters
    ----------
    session_ends : ``{"ends": "clamped" | "free" | "", "source": str}`` as recorded in the session.
    requested : the user's ``--ends`` or None (use the session's).

    Returns
    -------
    (ends, source, notes, warnings): ``ends`` None when neither says (the data decide,
    ``identification.identify``); ``source`` says who decided ("session (simulated specimen ...)",
    "--ends option", "the data"); a ``requested`` value against the session's record gives a warning.
    """
    recorded, where = session_ends.get("ends", ""), session_ends.get("source", "") or "session"
    if requested is not None and requested not in ("clamped", "free"):
        raise StageError(f"ends must be 'clamped', 'free' or None (the session's); got {requested!r}")
    if requested is None:
        if recorded:
            return recorded, f"session ({where})", [f"end conditions {recorded}, as the session records ({where})"], []
        return None, "the data", ["the session does not record the end conditions: the data decide between clamped "
                                  "and free (the verdict says whether they could); pass --ends clamped|free if known"], []
    if recorded and recorded != requested:
        return requested, "--ends option", [], [
            f"--ends {requested} contradicts the session, which records {recorded} ends ({where}); the result uses "
            f"{requested} as asked: check that this is what the specimen had"]
    return requested, "--ends option", [], []


def session_board_detections(session: Any, spec: Any, advance: Callable[[], None] | None = None) -> tuple[dict, dict]:
    """Board detections per camera (``reconstruction.targets.detect_board`` on every calibration view) and
    image sizes (width, height) px, from an open session; ``advance`` is called after each camera.
    A ValueError names a camera without calibration views."""
    from reconstruction import detect_board

    detections, sizes = {}, {}
    for name in session.camera_names:
        images = session.calibration_images(name)
        if len(images) == 0:
            raise ValueError(f"no calibration-board views for camera {name!r}")
        sizes[name] = (images.shape[2], images.shape[1])
        detections[name] = [detect_board(im, spec) for im in images]
        if advance is not None:
            advance()
    return detections, sizes


def identify_stored(path: str | os.PathLike, *, model: str = _D.model, wall: str | None = _D.wall,
                    ends: str | None = _D.ends, optimizer: str = _D.optimizer,
                    smoothing: str | tuple[int, int] | None = _D.smoothing, markers: str | None = None,
                    uncertainty: str = _D.uncertainty, check: bool = True, weighting: str = _D.weighting,
                    invoked_by: str = "pipeline",
                    progress: Callable[[int, int, str], None] | None = None) -> tuple[str, Any, dict[str, Any]]:
    """Identify ``model`` from the session's marker tracks with the VFM and store an "identification" result.

    Parameters
    ----------
    path : session file.
    model : "fung" | "delfino" | "hgo" | "neohookean".
    wall : "membrane" | "thick", or None (default): thick unless the data say membrane.
    ends : "clamped" | "free", or None (default) for what the session records (decided by the data
        when it records nothing). A value against the session's record is used, with a warning in
        the result's flags. The defaults are ``identification.DEFAULTS``: the library's.
    optimizer : "lsq" | "nelder-mead".
    smoothing : (axial Legendre degree, circumferential harmonics) to smooth the measured
        displacements first, "auto" (the basis chosen from the data; none when the markers look
        exact), or None. The standard errors and 95 % intervals come from a parametric bootstrap
        (``identification.uncertainty``) with the sensor noise of ``PRESSURE_NOISE``/``FORCE_NOISE``.
    markers : markers result to use (default: the latest).
    uncertainty : "auto" (default: "gls" for the efficient weighting, "bootstrap" for the others), "gls" (the
        efficient fit's own generalised least-squares covariance, no re-identification), "bootstrap" (~16
        re-identifications of re-simulated measurements) or "gauss-newton" (fast, too small on noisy data).
    weighting : "efficient" (default: generalised least squares over the full covariance of the virtual-work
        gaps, issue 24, docs/validation/efficiency.md), "paper" (the paper's cost) or "noise" (each gap weighted
        by the inverse of its noise as re-simulated i.i.d. marker noise predicts). The weightings need smoothed
        data and ``optimizer="lsq"`` (else the paper's cost).
    check : judge the result (``identification.verdict``: end conditions, wall form and law
        against the data's own evidence, in noise units): ``verdict`` and the reasons are stored.
    invoked_by : recorded in the result's attributes (e.g. "identify", "reprocess").

    Returns
    -------
    (group name e.g. "identification_003", the identification result object, the inputs used
    as returned by :func:`load_identification_inputs`).
    """
    try:
        from identification import IdentificationError, identify
        from identification.mesh import describe_dropped
    except ImportError as exc:  # pragma: no cover - the identification package ships with vfmlab
        raise StageUnavailable(f"the identification package is not available: {exc}") from None
    if smoothing is not None and smoothing != "auto":
        try:
            smoothing = tuple(int(v) for v in smoothing)
        except (TypeError, ValueError):
            smoothing = ()
        if len(smoothing) != 2 or min(smoothing) < 0:
            raise StageError(f"smoothing must be 'auto' or two non-negative integers (axial, harmonics); "
                             f"got {smoothing!r}")
    if weighting not in ("efficient", "noise", "paper"):
        raise StageError(f"weighting must be 'efficient', 'noise' or 'paper'; got {weighting!r}")
    weighting = weighting if optimizer == "lsq" else "paper"  # Nelder-Mead: the paper's method, for comparison
    data = read_identification_inputs(path, markers)
    ends, ends_source, ends_notes, warnings = resolve_ends(data["session_ends"], ends)
    if progress is not None:
        progress(0, 1, f"fitting {model}")
    force_notes = list(data["notes"])
    data["notes"] = force_notes + ends_notes
    if not check and (ends is None or wall is None):
        raise StageError(f"{path}: check=False needs the ends and the wall given; got ends={ends!r}, wall={wall!r}")
    try:
        result = identify(data["positions"], data["pressure"], data["force"], thickness=data["thickness"],
                          model=model, wall=wall, ends=ends, optimizer=optimizer, smoothing=smoothing,
                          uncertainty=uncertainty, weighting=weighting, judged=check, uncertainty_options={
                              "marker_sigma": data["uncertainty"], "pressure_noise": PRESSURE_NOISE,
                              "force_noise": FORCE_NOISE,
                              # the re-identifications on both cores: the same results, ~half the time idle
                              "map_replicates": fork_map, "progress": progress} if uncertainty != "gauss-newton" else None)
    except (IdentificationError, ValueError) as exc:
        raise StageError(f"{path}: cannot identify {model}: {exc}") from None
    result = replace(result, flags=tuple(warnings) + tuple(result.flags))
    if result.data is not None:
        data["notes"].append(describe_dropped(result.data.mesh.dropped))
    wall = result.wall if result.data is None else result.data.wall
    ends = ends if result.data is None else result.data.ends
    if ends_source == "the data":
        ends_source = "the data" if result.verdict == "trusted" or not any(
            "ends" in r and "cannot tell" in r for r in result.verdict_reasons) else "the data could not tell"
    settings = {"model": model, "wall": wall, "ends": ends, "ends_source": ends_source, "optimizer": optimizer,
                "smoothing": smoothing, "markers_result": data["markers_result"],
                # what was used: exact-looking (unsmoothed) data keep the paper's cost
                "weighting": weighting if result.smoothing is not None else "paper",
                "thickness_m": round_floats(data["thickness"]),
                "force_correction": force_notes}
    arrays, _, attrs = identification_arrays(result, data["rows"])
    attrs.update({"model": model, "wall": wall, "invoked_by": invoked_by, "notes": data["notes"]})
    data["settings"] = settings
    try:
        group = write_result(path, "identification", arrays, settings, attrs=attrs,
                             units={"ivw": "J", "evw": "J", "residuals": "1"})
    except SessionWriteError:  # a failed write (disk full, locked): exit 1, not bad input
        raise
    except SessionError as exc:
        raise StageError(str(exc)) from None
    return group, result, data


def identification_arrays(result: Any, rows: np.ndarray, checks: Any = None) -> tuple[dict, dict, dict]:
    """The arrays, settings (empty: the caller's) and attributes of an "identification" result
    for an identification result object and the step-table rows (n_steps,) it was given, plus
    what the setting checks (``identification.checks``) measured when given."""
    names = list(result.parameters)
    rows = np.asarray(rows)
    arrays = {
        "parameters": np.array([result.parameters[n] for n in names]),
        "stderr": np.array([result.stderr[n] for n in names]),
        "parameter_names": np.array(names, dtype=object).astype(str),
        "correlation": result.correlation,
        "ivw": result.ivw,
        "evw": result.evw,
        "residuals": result.residuals,
        "step_index": rows if getattr(result, "steps", None) is None else rows[list(result.steps)],
    }
    if getattr(result, "uncertainty", None) is not None:
        arrays["interval_low"] = np.array([result.uncertainty.interval[n][0] for n in names])
        arrays["interval_high"] = np.array([result.uncertainty.interval[n][1] for n in names])
        arrays["bootstrap_bias"] = np.array([result.uncertainty.bias[n] for n in names])
    attrs = {"cost": result.cost, "converged": result.converged, "flags": list(result.flags),
             "message": result.message, "n_evaluations": result.n_evaluations,
             "field_names": list(result.field_names), "smoothing_used": json.dumps(data_smoothing(result)),
             "uncertainty": _uncertainty_said(getattr(result, "uncertainty", None))}
    if checks is not None:
        attrs.update({"check_taper": list(checks.taper), "check_gap": checks.gap,
                      "check_gap_other_ends": checks.gap_other_ends, "check_gap_other_wall": checks.gap_other_wall})
    attrs.update(verdict_attrs(result))
    return arrays, {}, attrs


def _uncertainty_said(unc: Any) -> str:
    """The stored ``uncertainty`` attribute: how the intervals were made."""
    if unc is None:
        return "gauss-newton"
    if getattr(unc, "method", "bootstrap") == "gls":
        return "generalised least-squares covariance, 95 % intervals"
    return "parametric bootstrap, 95 % intervals"


def verdict_attrs(result: Any) -> dict[str, Any]:
    """The verdict of a judged result as stored attributes (the storage contract: ``verdict``,
    ``verdict_reasons``, ``parameter_verdicts``, ``parameter_reasons`` as JSON text, and the settings
    judged, ``hypotheses``); empty for a result that was not judged."""
    if getattr(result, "verdict", None) is None:
        return {}
    return {"verdict": result.verdict, "verdict_reasons": json.dumps(list(result.verdict_reasons)),
            "parameter_verdicts": json.dumps(dict(result.parameter_verdicts)),
            "parameter_reasons": json.dumps(dict(result.parameter_reasons)),
            "hypotheses": json.dumps([{**h, "parameters": {k: float(v) for k, v in h["parameters"].items()}}
                                      for h in result.hypotheses])}


def data_smoothing(result) -> list | None:
    """The smoothing degrees a result was identified with (three [nz, nt] pairs), or None."""
    used = getattr(result, "smoothing", None)
    return None if used is None else [list(map(int, d)) for d in used]


def identify_session(path: str | os.PathLike, **options: Any) -> str:
    """:func:`identify_stored`, returning only the new result group's name (the ``STAGES`` signature)."""
    return identify_stored(path, **options)[0]


# reprocess checks settings against a stage's keyword parameters: show identify_stored's
identify_session.__signature__ = inspect.signature(identify_stored).replace(return_annotation=str)


def session_step_rows(session, include_superseded: bool = False) -> np.ndarray:
    """Rows of the step table that are test steps: imaged preconditioning (block < 0, decision
    0006) is left out, and so are retaken rows unless ``include_superseded``."""
    steps = session.steps
    keep = steps["block"] >= 0
    if not include_superseded:
        keep &= steps["active"]
    return np.flatnonzero(keep)


def session_calibrated_cameras(session) -> tuple[list, str]:
    """The session's cameras from its latest "calibration" result, and a description of the source."""
    from reconstruction import CalibrationFileError, cameras_from_arrays

    calib = session.latest("calibration")
    if calib is None:
        raise StageError(f"{session.path}: no calibration; run 'vfmlab calibrate {session.path}' first")
    try:
        by_name = {c.name: c for c in cameras_from_arrays(calib["arrays"])}
    except CalibrationFileError as exc:
        raise StageError(f"{session.path}: stored calibration {calib['name']} is unusable ({exc})") from None
    cams = [by_name[n] for n in session.camera_names if n in by_name]
    if len(cams) < 2:
        raise StageError(f"{session.path}: calibration {calib['name']} covers cameras {sorted(by_name)} but the "
                         f"session has {session.camera_names}: at least two session cameras must be calibrated")
    return cams, f"session result {calib['name']}"


def check_camera_images(session, cameras: list) -> None:
    """Every calibrated camera has step images in the session, of the size it was calibrated at."""
    frames = session.image_cameras
    missing = [c.name for c in cameras if c.name not in frames]
    if missing:
        raise StageError(f"{session.path}: calibrated camera(s) {missing} have no images in the session "
                         f"(cameras with images: {sorted(frames)}); calibrate the cameras that took the images")
    for cam in cameras:
        size = getattr(cam, "image_size", None)
        if size is not None and tuple(int(v) for v in size) != frames[cam.name][::-1]:
            height, width = frames[cam.name]
            raise StageError(f"{session.path}: camera {cam.name!r} was calibrated at {int(size[0])}x{int(size[1])} px "
                             f"but its images are {width}x{height} px; calibrate at the images' size")


def reconstruct_stored(path: str | os.PathLike, *, cameras: list | None = None, calibration_source: str = "",
                       marker_diameter_mm: float | None = None, normals: str = "local", epipolar_px: float = 2.0,
                       max_reprojection_px: float = 1.5, include_superseded: bool = False, frame: str = "specimen",
                       flip_axis: bool = False, store: bool = True,
                       progress: Callable[[int, int, str], None] | None = None,
                       invoked_by: str = "pipeline") -> tuple[str | None, Any, np.ndarray, list[str], str]:
    """Reconstruct and track the 3-D markers of a session from its images; store a "markers" result.

    Parameters
    ----------
    cameras : calibrated cameras to use (default: the session's latest calibration), with
        ``calibration_source`` describing where they came from.
    marker_diameter_mm : default: the rig settings' ``marker_diameter_mm``, else 0.4 mm.
    progress : ``progress(step, n_steps, stage)`` callback of ``reconstruct_series``.
    store : False to compute without writing a result.

    Returns
    -------
    (result name or None, the ``reconstruct_series`` result, step-table rows used (n_steps,),
    camera names, calibration source).
    """
    try:
        from reconstruction import ReconstructionSettings, reconstruct_series
    except ImportError as exc:  # pragma: no cover - the reconstruction package ships with vfmlab
        raise StageUnavailable(f"the reconstruction package is not available: {exc}") from None
    try:
        session = open_session(path)
    except SessionError as exc:
        raise StageError(str(exc)) from None
    with session as s:
        if cameras is None:
            cameras, calibration_source = session_calibrated_cameras(s)
        check_camera_images(s, cameras)
        rows = session_step_rows(s, include_superseded)
        if rows.size == 0:
            raise StageError(f"{path}: no steps to reconstruct")
        if marker_diameter_mm is None:
            marker_diameter_mm = float((s.rig_settings or {}).get("marker_diameter_mm", 0.4))
        if not marker_diameter_mm > 0:
            raise StageError(f"marker diameter must be positive (mm); got {marker_diameter_mm}")
        polarity = str((s.rig_settings or {}).get("marker_polarity", "dark"))  # import-images --polarity
        try:
            settings = ReconstructionSettings(marker_diameter=marker_diameter_mm * 1e-3,
                                              specimen_radius=s.specimen.radius, normals=normals,
                                              epipolar_px=epipolar_px, max_reprojection_px=max_reprojection_px,
                                              detection={"polarity": polarity})
        except ValueError as exc:
            raise StageError(f"{path}: {exc}") from None
        names = [c.name for c in cameras]
        try:
            res = reconstruct_series(lambda k: {n: s.image(n, int(rows[k])) for n in names}, cameras, settings,
                                     n_steps=int(rows.size), progress=progress, frame=frame,
                                     axis_sign=-1 if flip_axis else 1)
        except ValueError as exc:
            raise StageError(f"{path}: reconstruction failed: {exc}") from None
    if not store:
        return None, res, rows, names, calibration_source
    d = res.diagnostics
    arrays = {"positions": res.positions, "visible": res.visible, "uncertainty": res.uncertainty,
              "marker_id": res.marker_id, "step_index": rows.astype(np.int64), "centres": res.centres,
              "n_views": res.n_views, "reprojection_rms": res.reprojection_rms, "world_to_rig": res.world_to_rig,
              "camera_names": np.array(names, dtype=object), "detected": d["detected"], "rejects": d["rejects"],
              "reject_reasons": np.array(d["reject_reasons"], dtype=object)}
    params = {"marker_diameter_mm": marker_diameter_mm, "marker_polarity": polarity, "calibration": calibration_source,
              "frame": frame,
              "flip_axis": flip_axis, "normals": normals, "epipolar_px": epipolar_px,
              "max_reprojection_px": max_reprojection_px, "include_superseded": include_superseded}
    attrs = {"tracked_per_step": np.asarray(d["tracked"]).tolist(), "lost_per_step": np.asarray(d["lost"]).tolist(),
             "swaps_detected": int(np.sum(d["swaps"])), "sigma_px": np.asarray(d["sigma_px"]).tolist(),
             "invoked_by": invoked_by}
    try:
        name = write_result(path, "markers", arrays, params, attrs,
                            units={"positions": "m", "centres": "m", "uncertainty": "m", "reprojection_rms": "px",
                                   "world_to_rig": "m"})
    except SessionWriteError:  # a failed write (disk full, locked): exit 1, not bad input
        raise
    except SessionError as exc:
        raise StageError(str(exc)) from None
    return name, res, rows, names, calibration_source


def reconstruct_session(path: str | os.PathLike, *, marker_diameter_mm: float | None = None, normals: str = "local",
                        epipolar_px: float = 2.0, max_reprojection_px: float = 1.5, include_superseded: bool = False,
                        frame: str = "specimen", flip_axis: bool = False, invoked_by: str = "pipeline") -> str:
    """:func:`reconstruct_stored` with the session's own calibration; returns the new result's name."""
    return reconstruct_stored(path, marker_diameter_mm=marker_diameter_mm, normals=normals, epipolar_px=epipolar_px,
                              max_reprojection_px=max_reprojection_px, include_superseded=include_superseded,
                              frame=frame, flip_axis=flip_axis, invoked_by=invoked_by)[0]


#: Stage name -> function(path, **settings) -> result group name.
STAGES: dict[str, Callable[..., str]] = {
    "reconstruct": reconstruct_session,
    "identify": identify_session,
}

#: Order in which stages run when several are requested.
STAGE_ORDER = ("reconstruct", "identify")
