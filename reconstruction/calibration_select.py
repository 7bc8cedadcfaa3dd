"""The lens distortion model of a calibration: chosen by held-out views, an unphysical one refused.

The 6th-order radial term k3 is poorly determined by board views that stay near the image centre: free, it
trades off against k2 and lands on values like k3 = 94 that fit the views used as well as k3 = 0 does, and
extrapolate wildly towards the image corners. :func:`choose_distortion` calibrates with k3 fixed at zero and
with k3 free on most of the views, projects the board of every held-out view with each (its pose from
``cv2.solvePnP`` with the trained intrinsics) and keeps k3 free only if it predicts the held-out views
better by more than ``prefer_margin`` (the simpler model otherwise). :func:`distortion_problem` names a
distortion that no lens has over its image: a radius that folds back (``d r_d / d r <= 0``) or changes by
more than ``max_change`` within ``margin`` times the corner radius.

Pixel coordinates as OpenCV; distortion (k1, k2, p1, p2, k3) as OpenCV's; normalised radius r = |x / z| of
the undistorted ray.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import cv2
import numpy as np

from reconstruction.calibration import calibrate_cameras
from reconstruction.calibration_errors import CalibrationError
from reconstruction.calibration_init import _normalise_inputs
from reconstruction.cameras import Camera

__all__ = ["DistortionChoice", "choose_distortion", "distortion_problem"]

log = logging.getLogger(__name__)

MODELS = ("k3 fixed", "k3 free")


@dataclass(frozen=True)
class DistortionChoice:
    """The distortion model chosen: ``fix_k3``; ``heldout_rms_px`` {model: reprojection RMS (px) of the held-out
    views}; ``problems`` {model: why it is unphysical}; ``n_heldout_views``; ``reason`` (one line)."""

    fix_k3: bool
    reason: str
    heldout_rms_px: dict[str, float] = field(default_factory=dict)
    problems: dict[str, str] = field(default_factory=dict)
    n_heldout_views: int = 0


def distortion_problem(camera: Camera, *, margin: float = 1.25, max_change: float = 0.25) -> str | None:
    """None when the radial distortion of ``camera`` is one a lens can have over its image, else a one-line reason.

    Checked from the centre to ``margin`` times the normalised radius of the farthest image corner: the
    distorted radius r_d = r (1 + k1 r^2 + k2 r^4 + k3 r^6) must grow with r, and r_d / r stay within
    1 +- ``max_change``.
    """
    k1, k2, _, _, k3 = (list(np.asarray(camera.dist, float).ravel()) + [0.0] * 5)[:5]
    K = np.asarray(camera.K, float)
    w, h = camera.image_size
    corners = np.array([[0.0, 0.0], [w, 0.0], [0.0, h], [w, h]])
    r_max = float(np.max(np.hypot((corners[:, 0] - K[0, 2]) / K[0, 0], (corners[:, 1] - K[1, 2]) / K[1, 1])))
    r = np.linspace(0.0, margin * r_max, 400)
    r2 = r * r
    gain = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    slope = 1 + 3 * k1 * r2 + 5 * k2 * r2**2 + 7 * k3 * r2**3
    coefficients = f"k1 {k1:.4g}, k2 {k2:.4g}, k3 {k3:.4g}"
    if np.any(slope <= 0):
        at = r[np.argmax(slope <= 0)] / r_max
        return (f"camera {camera.name}: the radial distortion ({coefficients}) folds back at {at:.2f} x the "
                "image corner radius")
    worst = int(np.argmax(np.abs(gain - 1)))
    if abs(gain[worst] - 1) > max_change:
        return (f"camera {camera.name}: the radial distortion ({coefficients}) changes the radius by "
                f"{(gain[worst] - 1) * 100:+.0f} % at {r[worst] / r_max:.2f} x the image corner radius "
                f"(at most {max_change * 100:.0f} % expected)")
    return None


def _heldout_rms(cameras: list[Camera], uv: np.ndarray, obj: np.ndarray, views: np.ndarray, min_points: int) -> float:
    """Reprojection RMS (px) of the held-out ``views``: each camera's board pose by solvePnP, its intrinsics fixed."""
    sq, n = 0.0, 0
    for c, cam in enumerate(cameras):
        for v in views:
            ok = np.isfinite(uv[c, v]).all(-1)
            if ok.sum() < max(min_points, 6):
                continue
            found, rvec, tvec = cv2.solvePnP(obj[v][ok], uv[c, v][ok], cam.K, np.asarray(cam.dist, float))
            if not found:
                continue
            proj, _ = cv2.projectPoints(obj[v][ok], rvec, tvec, cam.K, np.asarray(cam.dist, float))
            sq += float(np.sum((proj.reshape(-1, 2) - uv[c, v][ok]) ** 2))
            n += int(ok.sum())
    return float(np.sqrt(sq / n)) if n else float("nan")


def _held_out(usable: np.ndarray, seen: np.ndarray, every: int) -> np.ndarray:
    """Views to hold out: every ``every``-th of ``seen``, skipping a view that would take from some camera more
    than 1 in ``every`` of the views it sees (``usable`` (n_cams, n_views) bool)."""
    budget = usable.sum(1) // every
    taken = np.zeros_like(budget)
    held: list[int] = []
    for k, v in enumerate(seen):
        if (k + 1) % every and len(held) >= (k + 1) // every:
            continue  # not this view's turn, and on schedule
        cams = usable[:, v]
        if np.all(taken[cams] < budget[cams]):
            held.append(v)
            taken[cams] += 1
    return np.asarray(held, int)


def choose_distortion(image_points: np.ndarray, object_points: np.ndarray, image_sizes: list[tuple[int, int]],
                      camera_names: list[str] | None = None, *, holdout_every: int = 4, prefer_margin: float = 0.02,
                      min_views: int = 8, **calibrate_kwargs) -> DistortionChoice:
    """Fix k3 or free it, by held-out views (module docstring).

    image_points (n_cams, n_views, n_points, 2) px, NaN where unseen; object_points (n_points, 3) or
    (n_views, n_points, 3); every ``holdout_every``-th view seen by some camera is held out (at least
    ``min_views`` such views needed, else k3 is fixed). ``calibrate_kwargs`` go to
    :func:`~reconstruction.calibration.calibrate_cameras` (not ``fix_k3``, ``world_view``). Behind a window
    (``windows``) k3 is fixed: the held-out projection here is through straight rays.
    """
    if calibrate_kwargs.get("windows") is not None:
        return DistortionChoice(True, "k3 fixed at 0: the cameras look through a window (held-out views are "
                                      "checked through straight rays only)")
    calibrate_kwargs.pop("world_view", None)
    calibrate_kwargs.pop("fix_k3", None)
    uv, obj = _normalise_inputs(image_points, object_points)
    min_points = int(calibrate_kwargs.get("min_points", 6))
    seen = np.flatnonzero((np.isfinite(uv).all(-1).sum(-1) >= min_points).any(0))
    if len(seen) < min_views:
        return DistortionChoice(True, f"k3 fixed at 0: {len(seen)} board views are too few to test a free k3 on "
                                      f"held-out views (>= {min_views})")
    held = _held_out(np.isfinite(uv).all(-1).sum(-1) >= min_points, seen, holdout_every)
    if len(held) == 0:
        return DistortionChoice(True, "k3 fixed at 0: no board view can be held out without leaving a camera "
                                      "too few views")
    train = np.setdiff1d(np.arange(uv.shape[1]), held)
    rms, problems = {}, {}
    for model, fix in zip(MODELS, (True, False)):
        try:
            result = calibrate_cameras(uv[:, train], obj[train], image_sizes, camera_names, fix_k3=fix,
                                       **calibrate_kwargs)
        except CalibrationError as exc:
            return DistortionChoice(True, f"k3 fixed at 0: the views left after holding out {len(held)} cannot "
                                          f"calibrate the cameras ({exc})")
        rms[model] = _heldout_rms(result.cameras, uv, obj, held, min_points)
        found = [p for p in (distortion_problem(c) for c in result.cameras) if p]
        if found:
            problems[model] = "; ".join(found)
    log.info("held-out reprojection RMS over %d views: %s", len(held),
             ", ".join(f"{m} {v:.4f} px" for m, v in rms.items()))
    better = rms["k3 free"] < (1 - prefer_margin) * rms["k3 fixed"]
    text = f"held-out RMS over {len(held)} views: k3 fixed {rms['k3 fixed']:.4f} px, k3 free {rms['k3 free']:.4f} px"
    if "k3 free" in problems:
        return DistortionChoice(True, f"k3 fixed at 0: free, it is unphysical ({problems['k3 free']}); {text}",
                                rms, problems, len(held))
    if better:
        return DistortionChoice(False, f"k3 free: it predicts held-out views better by more than "
                                       f"{prefer_margin * 100:.0f} % ({text})", rms, problems, len(held))
    return DistortionChoice(True, f"k3 fixed at 0: a free k3 does not predict held-out views better by more than "
                                  f"{prefer_margin * 100:.0f} % ({text})", rms, problems, len(held))
