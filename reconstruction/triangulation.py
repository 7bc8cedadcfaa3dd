"""N-view triangulation: linear (DLT) initialisation, Gauss-Newton refinement, uncertainty.

Frames and shapes follow ``reconstruction/cameras.py``: world points in metres (rig frame),
pixels as OpenCV, NaN = not observed. Everything is vectorised over points.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from reconstruction.cameras import Camera, project_points
from reconstruction.refraction import refracted_directions

__all__ = ["Triangulation", "triangulate", "triangulate_linear", "triangulate_rays", "undistort_views"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Triangulation:
    """Result of :func:`triangulate`.

    Attributes
    ----------
    points : ndarray, shape (n_points, 3)
        Triangulated world points, m; NaN where fewer than two views were given.
    residuals : ndarray, shape (n_cameras, n_points, 2)
        Reprojection residuals (projected - observed), px; NaN where not observed.
    reprojection_rms : ndarray, shape (n_points,)
        RMS over the observing views of the residual norm, px.
    n_views : ndarray of int, shape (n_points,)
    covariance : ndarray, shape (n_points, 3, 3)
        ``sigma_px**2 (J^T J)^-1``, m^2.
    uncertainty : ndarray, shape (n_points,)
        ``sqrt(trace(covariance))``: RMS 3-D position uncertainty, m.
    sigma_px : float
        Pixel noise used for the covariance (given, or estimated from the residuals).
    converged : ndarray of bool, shape (n_points,)
    """

    points: np.ndarray
    residuals: np.ndarray
    reprojection_rms: np.ndarray
    n_views: np.ndarray
    covariance: np.ndarray
    uncertainty: np.ndarray
    sigma_px: float
    converged: np.ndarray


def undistort_views(pixels: np.ndarray, cameras: list[Camera]) -> np.ndarray:
    """Distorted pixels ``(n_cameras, n_points, 2)`` -> normalised undistorted coordinates, NaN kept."""
    pixels = np.asarray(pixels, dtype=float)
    out = np.full(pixels.shape, np.nan)
    for c, cam in enumerate(cameras):
        ok = np.all(np.isfinite(pixels[c]), axis=-1)
        if np.any(ok):
            out[c, ok] = cam.undistort_pixels(pixels[c, ok])
    return out


def triangulate_linear(normalised: np.ndarray, cameras: list[Camera]) -> np.ndarray:
    """Homogeneous DLT on normalised undistorted coordinates.

    Parameters
    ----------
    normalised : ndarray, shape (n_cameras, n_points, 2)
        NaN where not observed.
    cameras : list of Camera, length n_cameras

    Returns
    -------
    ndarray, shape (n_points, 3)
        NaN for points with fewer than two views.
    """
    normalised = np.asarray(normalised, dtype=float)
    n_cams, n_pts = normalised.shape[:2]
    ok = np.all(np.isfinite(normalised), axis=-1)  # (n_cams, n_pts)
    Rt = np.stack([np.hstack([c.R, c.tvec[:, None]]) for c in cameras])  # (n_cams, 3, 4)
    x = np.where(ok, normalised[..., 0], 0.0)
    y = np.where(ok, normalised[..., 1], 0.0)
    w = ok.astype(float)
    rows1 = (x[..., None] * Rt[:, None, 2, :] - Rt[:, None, 0, :]) * w[..., None]  # (n_cams, n_pts, 4)
    rows2 = (y[..., None] * Rt[:, None, 2, :] - Rt[:, None, 1, :]) * w[..., None]
    A = np.concatenate([rows1, rows2], axis=0).transpose(1, 0, 2)  # (n_pts, 2 n_cams, 4)
    # Scale the translation column so the problem is well conditioned for points near the origin.
    scale = max(float(np.median([np.linalg.norm(c.tvec) for c in cameras])), 1e-12)
    A = A * np.array([scale, scale, scale, 1.0])
    out = np.full((n_pts, 3), np.nan)
    good = ok.sum(axis=0) >= 2
    if np.any(good):
        _, _, vt = np.linalg.svd(A[good])
        h = vt[:, -1, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            out[good] = h[:, :3] / h[:, 3:4] * scale
    return out


def triangulate_rays(origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Least-squares closest point to several rays per point.

    Parameters
    ----------
    origins, directions : ndarray, shape (n_cameras, n_points, 3)
        Ray origins (m) and unit directions; NaN where not observed.

    Returns
    -------
    ndarray, shape (n_points, 3)
        NaN for points with fewer than two rays or (near) parallel rays.
    """
    ok = np.all(np.isfinite(origins), -1) & np.all(np.isfinite(directions), -1)
    d = np.where(ok[..., None], directions, 0.0)
    o = np.where(ok[..., None], origins, 0.0)
    P = ok[..., None, None] * np.eye(3) - d[..., :, None] * d[..., None, :]  # (n_cams, n_pts, 3, 3)
    A = P.sum(axis=0)
    b = np.einsum("cpij,cpj->pi", P, o)
    out = np.full(b.shape, np.nan)
    with np.errstate(invalid="ignore"):
        good = (ok.sum(axis=0) >= 2) & (np.abs(np.linalg.det(A)) > 1e-12)
    if np.any(good):
        out[good] = np.linalg.solve(A[good], b[good][..., None])[..., 0]
    return out


def _initial_points(pixels: np.ndarray, cameras: list[Camera]) -> np.ndarray:
    """DLT on straight rays, or the closest point of the rays in the bath when a camera has a window."""
    if all(c.window is None for c in cameras):
        return triangulate_linear(undistort_views(pixels, cameras), cameras)
    shape = pixels.shape[:2] + (3,)
    origins, directions = np.full(shape, np.nan), np.full(shape, np.nan)
    for c, cam in enumerate(cameras):
        ok = np.all(np.isfinite(pixels[c]), axis=-1)
        if np.any(ok):
            origins[c, ok], directions[c, ok] = cam.rays(pixels[c, ok])
    return triangulate_rays(origins, directions)


class _Cam:
    """Camera arrays with the rotation matrix computed once (``Camera.R`` recomputes it)."""

    __slots__ = ("R", "tvec", "K", "dist", "window", "center", "correction")

    def __init__(self, cam: Camera):
        self.R, self.tvec, self.K, self.dist = cam.R, cam.tvec, cam.K, cam.dist
        self.window = cam.window
        self.center = -self.R.T @ self.tvec
        # a mapping correction of the projection (reconstruction.mapping_correction.CorrectedCamera)
        self.correction = getattr(cam, "correction", None)


def _project_one(c: _Cam, points: np.ndarray) -> np.ndarray:
    if c.window is None:
        px = project_points(c.K, c.dist, points @ c.R.T + c.tvec)
    else:
        d, beyond = refracted_directions(c.window, c.R, c.center, points)
        px = np.where(beyond[..., None], project_points(c.K, c.dist, d), np.nan)
    return px if c.correction is None else px - c.correction(px, points)


def _project_all(points: np.ndarray, cams: list[_Cam], seen: np.ndarray | None = None) -> np.ndarray:
    """Pixels ``(n_cams, n_pts, 2)``; with ``seen`` (n_cams, n_pts) bool, only there (NaN elsewhere)."""
    if seen is None:
        return np.stack([_project_one(c, points) for c in cams])
    out = np.full((len(cams), points.shape[0], 2), np.nan)
    for c, cam in enumerate(cams):
        if np.any(seen[c]):
            out[c, seen[c]] = _project_one(cam, points[seen[c]])
    return out


def triangulate(
    pixels: np.ndarray,
    cameras: list[Camera],
    *,
    sigma_px: float | None = None,
    max_iterations: int = 20,
    tolerance: float = 1e-13,
    covariance: bool = True,
) -> Triangulation:
    """Triangulate points seen in several cameras: DLT, then Gauss-Newton on the pixel residuals.

    Parameters
    ----------
    pixels : ndarray, shape (n_cameras, n_points, 2)
        Observed distorted pixels; NaN where a camera does not see a point.
    cameras : list of Camera, length n_cameras
    sigma_px : float, optional
        Pixel noise (px, per coordinate) for the covariance. Default: estimated from the pooled
        residuals (``sum r^2 / (2 n_obs - 3 n_points)``) when there is redundancy, else 0.02 px.
    max_iterations : int
    tolerance : float
        Stop when every update is below this, m.
    covariance : bool
        Compute ``covariance`` and ``uncertainty`` (False: NaN, faster; for candidate screening).

    Returns
    -------
    Triangulation
    """
    pixels = np.asarray(pixels, dtype=float)
    if pixels.ndim != 3 or pixels.shape[-1] != 2 or pixels.shape[0] != len(cameras):
        raise ValueError(
            f"pixels must have shape (n_cameras={len(cameras)}, n_points, 2); got {pixels.shape}"
        )
    n_cams, n_pts = pixels.shape[:2]
    ok = np.all(np.isfinite(pixels), axis=-1)
    n_views = ok.sum(axis=0)
    X = _initial_points(pixels, cameras)
    cams = [_Cam(c) for c in cameras]
    active = np.all(np.isfinite(X), axis=1)
    converged = _gauss_newton(X, pixels, ok, active, cams, max_iterations, tolerance)
    proj = _project_all(X, cams, ok)
    res = np.where(ok[..., None], proj - pixels, np.nan)  # NaN where unobserved
    with np.errstate(invalid="ignore"):
        sq = np.nansum(res**2, axis=(0, 2))
        rms = np.where(n_views > 0, np.sqrt(sq / np.maximum(n_views, 1)), np.nan)
    rms = np.where(active, rms, np.nan)
    dof = int(2 * n_views[active].sum() - 3 * active.sum())
    if sigma_px is None:
        sigma_px = float(np.sqrt(sq[active].sum() / dof)) if dof > 0 else 0.02
        if not np.isfinite(sigma_px) or sigma_px <= 0:
            sigma_px = 0.02
    if covariance:
        cov = _covariance(X, cams, ok, active, sigma_px, proj)
    else:
        cov = np.full((n_pts, 3, 3), np.nan)
    unc = np.sqrt(np.trace(cov, axis1=1, axis2=2))
    return Triangulation(
        points=X,
        residuals=res,
        reprojection_rms=rms,
        n_views=n_views,
        covariance=cov,
        uncertainty=unc,
        sigma_px=float(sigma_px),
        converged=converged | ~active,
    )


def _gauss_newton(X, pixels, ok, active, cams, max_iterations, tolerance) -> np.ndarray:
    """Refine the points ``X (n_pts, 3)`` in place on the pixel residuals; returns the (n_pts,) bool
    converged flags (update below ``tolerance``, m). Converged points leave the batch."""
    converged = np.zeros(X.shape[0], dtype=bool)
    obs = np.where(ok[..., None], pixels, 0.0)
    for _ in range(max_iterations):
        idx = np.flatnonzero(active & ~converged)
        if idx.size == 0:
            break
        Xa = X[idx]
        proj = _project_all(Xa, cams, ok[:, idx])
        r = np.where(ok[:, idx, None], proj - obs[:, idx], 0.0)  # (n_cams, m, 2)
        Ja = np.where(ok[:, idx, None, None], _jacobian(Xa, cams, base=proj, seen=ok[:, idx]), 0.0)  # (n_cams, m, 2, 3)
        JtJ = np.einsum("cmki,cmkj->mij", Ja, Ja)
        Jtr = np.einsum("cmki,cmk->mi", Ja, r)
        try:
            step = np.linalg.solve(JtJ, -Jtr[..., None])[..., 0]
        except np.linalg.LinAlgError:  # a degenerate (e.g. coincident-ray) point in the batch
            step = -(np.linalg.pinv(JtJ) @ Jtr[..., None])[..., 0]
        bad = ~np.all(np.isfinite(step), axis=1)
        step[bad] = 0.0
        X[idx] = Xa + step
        converged[idx] = np.linalg.norm(step, axis=1) < tolerance
    return converged


def _covariance(X, cams, ok, active, sigma_px, proj) -> np.ndarray:
    """``sigma_px^2 (J^T J)^-1`` per point ``(n_pts, 3, 3)``, NaN where not determined; ``proj``: the
    projections of ``X`` (n_cams, n_pts, 2)."""
    Xa = np.where(active[:, None], X, 0.0)
    Jf = np.where(ok[..., None, None] & active[None, :, None, None], _jacobian(Xa, cams, base=proj, seen=ok & active), 0.0)
    JtJ = np.einsum("cmki,cmkj->mij", Jf, Jf)
    JtJ = np.where(np.isfinite(JtJ), JtJ, 0.0)  # a refracted point that left a window's bath side
    cov = np.full((X.shape[0], 3, 3), np.nan)
    inv_ok = active & (np.abs(np.linalg.det(JtJ)) > 0)
    if np.any(inv_ok):
        cov[inv_ok] = sigma_px**2 * np.linalg.inv(JtJ[inv_ok])
    return cov


def _jacobian(points: np.ndarray, cameras: list, base: np.ndarray | None = None,
              seen: np.ndarray | None = None) -> np.ndarray:
    """d(pixel)/d(X) for every camera and point, shape (n_cams, n_pts, 2, 3): analytic chain rule, or
    finite differences through a window (``base``: the projections ``(n_cams, n_pts, 2)`` of ``points``
    if already known, which makes them one-sided). With ``seen`` (n_cams, n_pts) bool, only there
    (NaN elsewhere)."""
    cams = [c if isinstance(c, _Cam) else _Cam(c) for c in cameras]
    out = np.full((len(cams), points.shape[0], 2, 3), np.nan)
    for c, cam in enumerate(cams):
        sel = slice(None) if seen is None else seen[c]
        if seen is not None and not np.any(sel):
            continue
        out[c, sel] = _camera_jacobian(cam, points[sel], None if base is None else base[c][sel])
    return out


def _refracted_jacobian(cam: _Cam, points: np.ndarray, base: np.ndarray | None = None, step: float = 1e-6) -> np.ndarray:
    """Finite differences (step in m) through the window, all perturbed points in one batch: the refracted
    projection is smooth. Central differences, or forward ones from ``base`` (n_pts, 2) when given (the
    relative error, ~1e-6, does not move the Gauss-Newton solution, only its path)."""
    n = points.shape[0]
    signs = (1.0,) if base is not None else (1.0, -1.0)
    shifted = np.concatenate([points + sg * step * np.eye(3)[i] for sg in signs for i in range(3)])
    proj = _project_one(cam, shifted).reshape(len(signs), 3, n, 2)
    diff = (proj[0] - base) / step if base is not None else (proj[0] - proj[1]) / (2 * step)  # (3, n, 2)
    return diff.transpose(1, 2, 0)


def _camera_jacobian(cam: _Cam, points: np.ndarray, base: np.ndarray | None = None) -> np.ndarray:
    if cam.window is not None or cam.correction is not None:
        return _refracted_jacobian(cam, points, base)
    R = cam.R
    Xc = points @ R.T + cam.tvec
    z = Xc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        x = Xc[:, 0] / z
        y = Xc[:, 1] / z
    k1, k2, p1, p2, k3 = cam.dist
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dradial = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r2 * r2  # d radial / d r2
    # xd = x*radial + 2 p1 x y + p2 (r2 + 2 x^2); yd = y*radial + p1 (r2 + 2 y^2) + 2 p2 x y
    dxd_dx = radial + x * dradial * 2 * x + 2 * p1 * y + p2 * (2 * x + 4 * x)
    dxd_dy = x * dradial * 2 * y + 2 * p1 * x + p2 * 2 * y
    dyd_dx = y * dradial * 2 * x + p1 * 2 * x + 2 * p2 * y
    dyd_dy = radial + y * dradial * 2 * y + p1 * (2 * y + 4 * y) + 2 * p2 * x
    K = cam.K
    du_dx = K[0, 0] * dxd_dx + K[0, 1] * dyd_dx
    du_dy = K[0, 0] * dxd_dy + K[0, 1] * dyd_dy
    dv_dx = K[1, 1] * dyd_dx
    dv_dy = K[1, 1] * dyd_dy
    # x = Xc0/z, y = Xc1/z: d(x,y)/dXc
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_z = 1.0 / z
    dn = np.zeros((points.shape[0], 2, 3))
    dn[:, 0, 0] = inv_z
    dn[:, 0, 2] = -x * inv_z
    dn[:, 1, 1] = inv_z
    dn[:, 1, 2] = -y * inv_z
    A = np.stack([np.stack([du_dx, du_dy], -1), np.stack([dv_dx, dv_dy], -1)], -2)  # (n, 2, 2)
    return A @ dn @ R
