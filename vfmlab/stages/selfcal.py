"""``vfmlab calibrate --import FOLDER --self-calibrate FRAMES``: refine imported OpenPTV cameras on the
particles of some frames (volume self-calibration, :func:`vfmlab.openptv.self_calibrate_folder`).

Settings in mm as on the command line; what is kept is in SI and px, the unit in every key.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vfmlab.stages.errors import StageError, StageFailed
from vfmlab.stages.feedback import Notify, ProgressFactory, log_notes, no_progress
from vfmlab.stages.settings import SelfCalibrationSettings

__all__ = ["check_folder", "parse_frames", "parse_volume", "self_calibrate"]


def parse_frames(text: str) -> list[int]:
    """``10000-10004`` or ``10000,10002`` (or both mixed) -> frame numbers."""
    frames: list[int] = []
    try:
        for part in text.split(","):
            lo, _, hi = part.strip().partition("-")
            frames += list(range(int(lo), int(hi) + 1)) if hi else [int(lo)]
    except ValueError:
        raise StageError(f"--self-calibrate must list frame numbers like 10000-10004 or 10000,10002; got {text!r}") from None
    if not frames:
        raise StageError(f"--self-calibrate must name at least one frame; got {text!r}")
    return sorted(set(frames))


def parse_volume(text: str | None):
    """``XMIN,XMAX,YMIN,YMAX,ZMIN,ZMAX`` in mm -> ``(lo, hi)`` in m, or None."""
    if text is None:
        return None
    try:
        v = np.array([float(x) for x in text.split(",")]) * 1e-3
    except ValueError:
        v = np.zeros(0)
    if v.shape != (6,) or not np.all(np.isfinite(v)) or np.any(v[1::2] <= v[0::2]):
        raise StageError(f"--volume-mm must be XMIN,XMAX,YMIN,YMAX,ZMIN,ZMAX in mm with each min < max; got {text!r}")
    return v[0::2], v[1::2]


def check_folder(path: Path) -> None:
    """A StageError unless ``path`` is an OpenPTV working folder."""
    from vfmlab import openptv

    if not openptv.is_openptv_folder(path):
        raise StageError(f"--self-calibrate needs an OpenPTV folder for --import (its particle images, cal/camN.tif "
                         f"and cal/target_on_a_side.txt); got {path}")


def self_calibrate(folder: Path, cams: list, meta: dict, s: SelfCalibrationSettings, *, notify: Notify = log_notes,
                   progress: ProgressFactory = no_progress) -> tuple[list, dict]:
    """Refine ``cams`` on the particles of ``s.frames``; the cameras and ``meta`` with ``self_calibration``
    (figures, SI/px keys) and ``self_calibration_settings``."""
    from vfmlab import openptv

    numbers, bounds = parse_frames(s.frames), parse_volume(s.volume)
    if not s.body_weight > 0:
        raise StageError(f"--body-weight must be > 0 (the body's dots fix the gauge); got {s.body_weight}")
    no_window = [c.name for c in cams if c.window is None]
    if no_window:
        raise StageError(f"--self-calibrate: cameras {no_window} of --import {folder} have no window (ptv.par's media "
                         "are all air?); the self-calibration refines the window's tilt through glass and water")
    with progress("self-calibration", None) as update:
        try:
            sc, bounds, pts, px, dets = openptv.self_calibrate_folder(
                folder, cams, numbers, images=s.images, body_weight=s.body_weight, bounds=bounds,
                progress=lambda done, total, what: update(done, total, f"self-calibration: {what}"),
                body_sides=s.body_sides)
        except FileNotFoundError as exc:
            raise StageError(f"--self-calibrate {s.frames} (--particle-images {s.images}): {exc}") from None
        except ValueError as exc:
            raise StageError(f"--self-calibrate {s.frames}: {exc}") from None
    if not sc.particle_rms_px:
        raise StageFailed(f"--self-calibrate: {sc.message}; nothing stored (more frames, or a calibration closer to "
                          "consistent, e.g. --body)")
    out = _selfcal_meta(sc, cams, numbers, s, bounds, pts, px, dets)
    if not out["self_calibration"]["disparity_improved"]:
        notify("warning: --self-calibrate made the cameras less consistent (disparity peaks "
               f"{sc.maps[0].rms_peak_offset_px:.3f} -> {sc.check_map.rms_peak_offset_px:.3f} px RMS at the first "
               "pass's tolerances); a calibration whose distortion extrapolates (e.g. --body fixed) is a poor seed")
    return sc.cameras, {**meta, **out}


def _selfcal_meta(sc, before: list, frames, s: SelfCalibrationSettings, bounds, pts, px, dets) -> dict:
    """What the session and --json keep of a self-calibration (SI and px, the unit in every key)."""
    from reconstruction.volume_selfcal import body_rms
    from vfmlab import openptv

    names = [c.name for c in before]
    settings = {"frames": frames, "particle_images": s.images, "body_weight": s.body_weight,
                "refined": list(openptv.SELFCAL_SETTINGS["free"]),
                "schedule_px": [list(t) for t in openptv.SELFCAL_SETTINGS["schedule"]], "body_sides": s.body_sides,
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
