"""Calibration of one camera from a 3-D calibration body (points with known coordinates), through its window.

The body's points are matched to detected dots by projecting them with a seed camera (e.g. an
imported or previous calibration), then pose, focal length, principal point, radial distortion
and optionally the window's position along its normal are refined by least squares on the pixel
residuals, with the refraction model of :class:`~reconstruction.cameras.Camera`.

An ill-posed problem (a thin body seen once: focal length and distance trade off) is never
returned silently: the result carries the parameter uncertainties and ``well_posed = False`` with
the reason when the focal length is not determined to ``max_focal_rel_sigma``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial import cKDTree

from reconstruction.cameras import Camera

__all__ = ["BodyCalibration", "match_body_points", "calibrate_from_body"]

log = logging.getLogger(__name__)

_NAMES = ("rx", "ry", "rz", "tx", "ty", "tz", "f", "cx", "cy", "k1", "k2", "window_offset")


@dataclass(frozen=True)
class BodyCalibration:
    """Result of :func:`calibrate_from_body`.

    Attributes
    ----------
    camera : Camera
    residuals : ndarray, shape (n_points, 2)
        Projected minus observed, px.
    rms : float
        Reprojection RMS (norm), px.
    sigma : dict
        1-sigma of every refined parameter (units: rad, m, px, dimensionless, m).
    well_posed : bool
    message : str
    """

    camera: Camera
    residuals: np.ndarray
    rms: float
    sigma: dict
    well_posed: bool
    message: str


def match_body_points(detections: np.ndarray, seed: Camera, body: np.ndarray, *, gate_px: float = 6.0) -> np.ndarray:
    """Pixels ``(n_body, 2)`` of the body's points: the detection nearest each seed projection
    within ``gate_px``, used once (mutual nearest); NaN where none."""
    det = np.asarray(detections, float).reshape(-1, 2)
    out = np.full((len(body), 2), np.nan)
    pp = seed.project(body)
    fin = np.all(np.isfinite(pp), axis=1)
    if not len(det) or not np.any(fin):
        return out
    dist, j = cKDTree(det).query(np.where(fin[:, None], pp, -1e9))
    back = cKDTree(np.where(fin[:, None], pp, -1e9)).query(det)[1]
    ok = fin & (dist <= gate_px) & (back[np.minimum(j, len(det) - 1)] == np.arange(len(body)))
    out[ok] = det[j[ok]]
    return out


def _camera_from(x: np.ndarray, seed: Camera, free: np.ndarray) -> Camera:
    p = _params(seed)
    p[free] = x
    K = seed.K.copy()
    aspect = seed.K[0, 0] / seed.K[1, 1]
    K[0, 0], K[1, 1], K[0, 2], K[1, 2] = p[6] * aspect, p[6], p[7], p[8]
    dist = seed.dist.copy()
    dist[0], dist[1] = p[9], p[10]
    win = seed.window.with_offset(p[11]) if seed.window is not None else None
    return replace(seed, K=K, dist=dist, rvec=p[0:3], tvec=p[3:6], window=win)


def _params(cam: Camera) -> np.ndarray:
    off = cam.window.offset if cam.window is not None else 0.0
    return np.array([*cam.rvec, *cam.tvec, cam.K[1, 1], cam.K[0, 2], cam.K[1, 2], cam.dist[0], cam.dist[1], off])


def calibrate_from_body(
    pixels: np.ndarray,
    body: np.ndarray,
    seed: Camera,
    *,
    refine_window: bool = False,
    refine_k2: bool = False,
    fix_focal: bool = False,
    max_focal_rel_sigma: float = 0.01,
    sigma_px: float | None = None,
) -> BodyCalibration:
    """Refine ``seed`` on the body's points ``body`` (m, ``(n, 3)``) observed at ``pixels`` (``(n, 2)``, NaN = unseen).

    Parameters
    ----------
    refine_window : bool
        Also refine the window's position along its normal (needs a window on ``seed``).
    refine_k2 : bool
        Refine k2 besides k1.
    fix_focal : bool
        Keep the seed's focal length (the remedy when one view of the body cannot fix it).
    max_focal_rel_sigma : float
        The calibration is flagged ill-posed when the focal length's 1-sigma exceeds this fraction.
    sigma_px : float, optional
        Pixel noise for the uncertainties; default the residual RMS per coordinate.
    """
    pixels = np.asarray(pixels, float)
    body = np.asarray(body, float)
    if pixels.shape != (len(body), 2):
        raise ValueError(f"pixels must have shape (n_body={len(body)}, 2); got {pixels.shape}")
    ok = np.all(np.isfinite(pixels), axis=1)
    free = np.ones(len(_NAMES), bool)
    free[10] = refine_k2
    free[6] = not fix_focal
    free[11] = refine_window and seed.window is not None
    if ok.sum() * 2 <= free.sum() + 2:
        raise ValueError(f"calibrate_from_body: {int(ok.sum())} matched points cannot fix {int(free.sum())} parameters")

    def residual(x):
        r = _camera_from(x, seed, free).project(body[ok]) - pixels[ok]
        return np.nan_to_num(r, nan=1e3).ravel()

    sol = least_squares(residual, _params(seed)[free], x_scale="jac", method="lm")
    cam = _camera_from(sol.x, seed, free)
    res = np.full(pixels.shape, np.nan)
    res[ok] = cam.project(body[ok]) - pixels[ok]
    rms = float(np.sqrt(np.nanmean(np.sum(res**2, axis=1))))
    return _assess(cam, sol, free, res, rms, ok, sigma_px, max_focal_rel_sigma)


def _assess(cam, sol, free, res, rms, ok, sigma_px, max_rel) -> BodyCalibration:
    """Parameter uncertainties from the Jacobian; flag an undetermined focal length."""
    dof = max(2 * int(ok.sum()) - int(free.sum()), 1)
    s = sigma_px if sigma_px is not None else float(np.sqrt(np.sum(sol.fun**2) / dof))
    JtJ = sol.jac.T @ sol.jac
    try:
        cov = s**2 * np.linalg.inv(JtJ)
        sig = np.sqrt(np.maximum(np.diag(cov), 0))
    except np.linalg.LinAlgError:
        sig = np.full(int(free.sum()), np.inf)
    sigma = dict(zip(np.array(_NAMES)[free].tolist(), sig.tolist()))
    f = cam.K[1, 1]
    rel = sigma.get("f", 0.0) / f
    well = bool(np.isfinite(rel) and rel <= max_rel and sol.success)
    msg = (f"{cam.name}: {int(ok.sum())} points, RMS {rms:.3f} px, focal {f:.1f} px +- {100 * rel:.2g} %" + ("" if "f" in sigma else " (fixed)")
           + ("" if well else f": ILL-POSED (focal length not determined to {100 * max_rel:g} %; "
                               "use a deeper body, more views or a fixed focal length)"))
    (log.info if well else log.warning)(msg)
    return BodyCalibration(cam, res, rms, sigma, well, msg)
