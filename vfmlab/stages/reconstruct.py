"""The reconstruct stage: detect, match, triangulate and track the markers of a session (a "markers" result).

The work is :func:`vfmlab.pipeline.reconstruct_stored`; this module chooses the cameras (``calibration``: a
file or an OpenPTV folder, else the session's latest calibration) and builds the command's summary.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vfmlab.stages.errors import StageError, StageFailed
from vfmlab.stages.feedback import Notify, log_notes
from vfmlab.stages.settings import ReconstructSettings, settings_with

__all__ = ["ReconstructOutcome", "blind_cameras", "load_calibration_file", "reconstruct", "resolve_cameras", "session_cameras"]


def load_calibration_file(path: Path, units: str | None = None) -> list:
    """Cameras from an aniposelib ``.toml`` or OpenCV ``.yaml``/``.yml`` calibration file, or an OpenPTV
    working folder (``parameters/ptv.par`` + ``cal/*.ori``/``.addpar``: cameras with their window)."""
    from reconstruction.calibration_io import CalibrationFileError, cameras_from_toml, cameras_from_yaml
    from vfmlab import openptv

    path = Path(path)
    if path.is_dir():
        try:
            return openptv.load_cameras(path)
        except (CalibrationFileError, OSError) as exc:
            raise (StageError if isinstance(exc, CalibrationFileError) else StageFailed)(f"--calibration {path}: {exc}") from None
    suffix = path.suffix.lower()
    if suffix not in (".toml", ".yaml", ".yml"):
        raise StageError(f"--calibration must be a .toml (aniposelib) or .yaml/.yml (OpenCV) file or an OpenPTV folder; "
                         f"got {path.name!r}")
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise StageError(f"--calibration: cannot read {path} ({exc.strerror})") from None
    try:
        cams, _ = (cameras_from_toml if suffix == ".toml" else cameras_from_yaml)(text, units=units)
    except (CalibrationFileError, ValueError) as exc:
        raise StageError(f"--calibration {path}: {exc}") from None
    return cams


def session_cameras(session, calibration: Path | None, units: str | None, warn: Notify = log_notes) -> tuple[list, str]:
    """Calibrated cameras (ordered as the session's cameras) and a description of their source:
    the ``--calibration`` file if given, else the session's latest calibration result."""
    from vfmlab.pipeline import session_calibrated_cameras

    if calibration is None:
        try:
            return session_calibrated_cameras(session)
        except StageError as exc:
            raise StageError(f"{exc} (or pass --calibration FILE)") from None
    cams, source = load_calibration_file(calibration, units), str(calibration)
    by_name = {c.name: c for c in cams}
    names = session.camera_names
    missing = [n for n in names if n not in by_name]
    used = [by_name[n] for n in names if n in by_name]
    if len(used) < 2:
        raise StageError(
            f"the calibration ({source}) covers cameras {sorted(by_name)} but the session has {names}: "
            "at least two session cameras must be calibrated"
        )
    if missing:
        warn(f"no calibration for camera(s) {', '.join(missing)}; they are ignored.")
    return used, source


@dataclass(frozen=True)
class ReconstructOutcome:
    """A reconstruction: ``stored`` (the "markers" result's name, None with ``store=False``), ``result`` (the
    ``reconstruct_series`` result: positions (n_steps, n_markers, 3) m, visible, uncertainty, diagnostics),
    ``rows`` (n_steps,) step-table rows, camera ``names`` and the calibration ``source``."""

    stored: str | None
    result: Any
    rows: Any
    names: list[str]
    source: str
    session: str

    def to_dict(self) -> dict[str, Any]:
        """What ``vfmlab reconstruct --json`` prints."""
        import numpy as np

        res, d = self.result, self.result.diagnostics
        return {
            "session": self.session, "n_steps": int(self.rows.size), "n_markers": int(res.visible.shape[1]),
            "tracked_per_step": d["tracked"], "lost_per_step": d["lost"], "detected_per_camera": d["detected"].sum(0),
            "rejects": dict(zip(d["reject_reasons"].tolist(), d["rejects"].sum(axis=(0, 1)).tolist())),
            "reprojection_rms_median_px": d["reprojection_rms_median"], "median_uncertainty_m":
                float(np.nanmedian(res.uncertainty)) if res.visible.any() else None,
            "swaps_detected": int(d["swaps"].sum()), "calibration": self.source, "stored_as": self.stored,
        }


def resolve_cameras(session_path: str | os.PathLike, s: ReconstructSettings, warn: Notify = log_notes) -> tuple[list, str]:
    """The cameras :func:`reconstruct` uses and their source (:func:`session_cameras` on the open session)."""
    from acquisition.session import open_session

    with open_session(session_path) as session:
        return session_cameras(session, None if s.calibration is None else Path(s.calibration), s.calibration_units,
                               warn)


def reconstruct(session_path: str | os.PathLike, settings: ReconstructSettings | None = None, *,
                progress: Callable[[int, int, str], None] | None = None, warn: Notify = log_notes,
                cameras: tuple[list, str] | None = None, invoked_by: str = "python",
                **overrides: Any) -> ReconstructOutcome:
    """Reconstruct the 3-D marker positions of every step of the session and track their identities
    (``vfmlab reconstruct``; defaults: :class:`ReconstructSettings`). ``progress(step, n_steps, stage)``;
    ``cameras``: (cameras, source) of :func:`resolve_cameras` when already resolved."""
    from vfmlab.pipeline import reconstruct_stored

    s = settings_with(ReconstructSettings, settings, overrides)
    cams, source = resolve_cameras(session_path, s, warn) if cameras is None else cameras
    stored, res, rows, names, source = reconstruct_stored(
        session_path, cameras=cams, calibration_source=source, marker_diameter_mm=s.marker_diameter_mm,
        normals=s.normals, epipolar_px=s.epipolar_px, max_reprojection_px=s.max_reprojection_px,
        include_superseded=s.include_superseded, frame=s.frame, flip_axis=s.flip_axis, store=s.store,
        progress=progress, invoked_by=invoked_by)
    for line in blind_cameras(cams, res):
        warn(line)
    return ReconstructOutcome(stored, res, rows, names, source, str(session_path))


def blind_cameras(cameras: list, result) -> list[str]:
    """One warning per camera that projects fewer than half of the reference markers reconstructed from all
    cameras into its image: its calibration does not describe where it looks, and it contributed (almost)
    nothing. A camera is never dropped silently."""
    import numpy as np

    from reconstruction import fraction_in_view

    centres = np.asarray(result.centres)[0] if np.asarray(result.centres).size else np.empty((0, 3))
    inverse = np.linalg.inv(np.asarray(result.world_to_rig, float))  # returned frame -> calibration world
    world = centres @ inverse[:3, :3].T + inverse[:3, 3]
    out = []
    for cam in cameras:
        seen = fraction_in_view(cam, world)
        if seen < 0.5:
            out.append(f"camera {cam.name!r} sees only {seen:.0%} of the {int(np.isfinite(world).all(1).sum())} "
                       "reconstructed reference markers in its image: its calibration does not match where it "
                       "looks, so its images added (almost) nothing; check that camera's calibration")
    return out
