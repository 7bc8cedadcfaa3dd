"""Calibration of one camera from a 3-D calibration body (points with known coordinates), through its window.

The body's points are matched to detected dots by projecting them with a seed camera (e.g. an
imported or previous calibration); the dots' centres are refined on the image
(:func:`refine_dot_centres`: intensity-weighted moments above a local background); then pose,
focal length, principal point, distortion (k1, k2, optionally k3, p1, p2, the aspect ratio) and
optionally the window (its position along its normal, its tilt) are refined by least squares on the
pixel residuals, with the refraction model of :class:`~reconstruction.cameras.Camera`. Dots that do
not fit (a defect on the body, a dot assigned to the wrong point) are found with a robust loss,
dropped, and the fit is repeated on the rest (``reject_sigma``).

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
from reconstruction.refraction import Window

__all__ = ["BodyCalibration", "match_body_points", "refine_dot_centres", "calibrate_from_body"]

log = logging.getLogger(__name__)

_NAMES = ("rx", "ry", "rz", "tx", "ty", "tz", "f", "cx", "cy", "k1", "k2", "window_offset",
          "k3", "p1", "p2", "aspect", "window_tilt_a", "window_tilt_b")


@dataclass(frozen=True)
class BodyCalibration:
    """Result of :func:`calibrate_from_body`.

    Attributes
    ----------
    camera : Camera
    residuals : ndarray, shape (n_points, 2)
        Projected minus observed, px (NaN = unseen); also for the rejected points.
    rms : float
        Reprojection RMS (norm) of the points kept, px.
    sigma : dict
        1-sigma of every refined parameter (units: rad, m, px, dimensionless, m, rad).
    well_posed : bool
    message : str
    inliers : ndarray of bool, shape (n_points,)
        Points the final fit used (seen and not rejected).
    """

    camera: Camera
    residuals: np.ndarray
    rms: float
    sigma: dict
    well_posed: bool
    message: str
    inliers: np.ndarray | None = None

    @property
    def n_rejected(self) -> int:
        """Seen points dropped as outliers."""
        seen = np.all(np.isfinite(self.residuals), axis=1)
        return int(seen.sum() - (self.inliers.sum() if self.inliers is not None else seen.sum()))


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


def refine_dot_centres(image: np.ndarray, pixels: np.ndarray, *, radius_px: float = 6.0, iterations: int = 3,
                       polarity: str = "bright") -> np.ndarray:
    """Sub-pixel centres of calibration dots near ``pixels``: intensity-weighted first moments of the
    disc of ``radius_px`` around each centre, above the local background (a plane fitted to the ring
    from ``radius_px + 1`` to ``radius_px + 3``), iterated ``iterations`` times.

    A whole-dot moment over a local background is unbiased by the detection threshold (a threshold
    centroid cuts the dim side of an obliquely seen dot off) and by the background's slope.

    Parameters
    ----------
    image : ndarray, shape (H, W)
    pixels : ndarray, shape (n, 2)
        Approximate centres (OpenCV px, NaN = none).
    radius_px : float
        Dot radius to integrate, px (somewhat above the dot's radius; not so large as to reach the next dot).
    polarity : {"bright", "dark"}

    Returns
    -------
    ndarray, shape (n, 2)
        NaN where the input is NaN, the disc leaves the image or holds nothing above background.
    """
    img = np.asarray(image, float)
    if img.ndim != 2:
        raise ValueError(f"image must be a 2-D grey-level array (H, W); got shape {img.shape}")
    if polarity not in ("bright", "dark"):
        raise ValueError(f"polarity must be 'bright' or 'dark'; got {polarity!r}")
    if not radius_px >= 1:
        raise ValueError(f"radius_px must be >= 1 px; got {radius_px}")
    img = img if polarity == "bright" else -img
    xy = np.asarray(pixels, float).reshape(-1, 2).copy()
    R = int(np.ceil(radius_px)) + 3
    oy, ox = np.mgrid[-R : R + 1, -R : R + 1]
    H, W = img.shape
    for _ in range(int(iterations)):
        ok = np.all(np.isfinite(xy), axis=1)
        c = np.where(ok[:, None], np.rint(xy), 0).astype(int)
        inside = ok & (c[:, 0] >= R) & (c[:, 1] >= R) & (c[:, 0] < W - R) & (c[:, 1] < H - R)
        X = c[:, 0, None, None] + ox  # (n, 2R+1, 2R+1)
        Y = c[:, 1, None, None] + oy
        patch = img[np.clip(Y, 0, H - 1), np.clip(X, 0, W - 1)]
        d = np.hypot(X - np.nan_to_num(xy[:, 0, None, None]), Y - np.nan_to_num(xy[:, 1, None, None]))
        ring = ((d > radius_px + 1) & (d <= radius_px + 3)).astype(float)
        w = np.clip(patch - _ring_plane(patch, ring, ox, oy), 0, None) * (d <= radius_px)
        sw = w.sum(axis=(1, 2))
        good = inside & (sw > 0)
        safe = np.where(sw > 0, sw, 1.0)
        new = np.stack([(w * X).sum(axis=(1, 2)) / safe, (w * Y).sum(axis=(1, 2)) / safe], axis=1)
        xy = np.where(good[:, None], new, np.nan)
    return xy


def _ring_plane(patch: np.ndarray, ring: np.ndarray, ox: np.ndarray, oy: np.ndarray) -> np.ndarray:
    """The local background under each patch ``(n, h, w)``: the plane fitted to its ``ring`` pixels (least squares)."""
    A = np.stack([np.ones_like(ox, dtype=float), ox, oy], axis=-1)  # (h, w, 3)
    AtA = np.einsum("nhw,hwi,hwj->nij", ring, A, A) + 1e-9 * np.eye(3)
    coef = np.linalg.solve(AtA, np.einsum("nhw,hwi,nhw->ni", ring, A, patch)[..., None])[..., 0]
    return np.einsum("hwi,ni->nhw", A, coef)


def _tilt_basis(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to ``normal``: the axes of the window's tilt parameters."""
    a = np.cross(normal, [0.0, 0.0, 1.0])
    if np.linalg.norm(a) < 1e-6:
        a = np.cross(normal, [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    return a, np.cross(normal, a)


def _camera_from(x: np.ndarray, seed: Camera, free: np.ndarray) -> Camera:
    p = _params(seed)
    p[free] = x
    K = seed.K.copy()
    K[0, 0], K[1, 1], K[0, 2], K[1, 2] = p[6] * p[15], p[6], p[7], p[8]
    dist = seed.dist.copy()
    dist[0], dist[1], dist[2], dist[3], dist[4] = p[9], p[10], p[13], p[14], p[12]
    win = seed.window
    if win is not None:
        a, b = _tilt_basis(win.normal)
        win = Window(win.normal + p[16] * a + p[17] * b, p[11], win.thicknesses, win.indices, win.n_bath, win.n_air)
    return replace(seed, K=K, dist=dist, rvec=p[0:3], tvec=p[3:6], window=win)


def _params(cam: Camera) -> np.ndarray:
    off = cam.window.offset if cam.window is not None else 0.0
    d = cam.dist
    return np.array([*cam.rvec, *cam.tvec, cam.K[1, 1], cam.K[0, 2], cam.K[1, 2], d[0], d[1], off,
                     d[4], d[2], d[3], cam.K[0, 0] / cam.K[1, 1], 0.0, 0.0])


def _free_mask(seed: Camera, *, fix_focal, refine_k2, refine_k3, refine_tangential, refine_aspect, refine_window,
               refine_window_tilt) -> np.ndarray:
    free = np.zeros(len(_NAMES), bool)
    free[[0, 1, 2, 3, 4, 5, 7, 8, 9]] = True
    has_window = seed.window is not None
    for i, on in ((6, not fix_focal), (10, refine_k2), (11, refine_window and has_window), (12, refine_k3),
                  (13, refine_tangential), (14, refine_tangential), (15, refine_aspect),
                  (16, refine_window_tilt and has_window), (17, refine_window_tilt and has_window)):
        free[i] = on
    return free


def calibrate_from_body(
    pixels: np.ndarray,
    body: np.ndarray,
    seed: Camera,
    *,
    refine_window: bool = False,
    refine_window_tilt: bool = False,
    refine_k2: bool = False,
    refine_k3: bool = False,
    refine_tangential: bool = False,
    refine_aspect: bool = False,
    fix_focal: bool = False,
    reject_sigma: float | None = 3.0,
    max_focal_rel_sigma: float = 0.01,
    sigma_px: float | None = None,
) -> BodyCalibration:
    """Refine ``seed`` on the body's points ``body`` (m, ``(n, 3)``) observed at ``pixels`` (``(n, 2)``, NaN = unseen).

    Parameters
    ----------
    refine_window : bool
        Also refine the window's position along its normal (needs a window on ``seed``). On one view
        of a shallow body it trades off with the camera's distance: prefer it fixed.
    refine_window_tilt : bool
        Also refine the direction of the window's normal (two small angles, rad).
    refine_k2, refine_k3 : bool
        Refine k2 (k3) besides k1.
    refine_tangential : bool
        Refine the tangential distortion p1, p2.
    refine_aspect : bool
        Refine fx / fy.
    fix_focal : bool
        Keep the seed's focal length (the remedy when one view of the body cannot fix it).
    reject_sigma : float or None
        Outliers: a first fit with a robust (soft L1) loss, then the points whose residual exceeds
        ``reject_sigma`` robust sigmas (1.4826 MAD of the residual norms / 1.1774) are dropped and the
        fit is repeated on the rest. None keeps every point (plain least squares).
    max_focal_rel_sigma : float
        The calibration is flagged ill-posed when the focal length's 1-sigma exceeds this fraction.
    sigma_px : float, optional
        Pixel noise for the uncertainties; default the residual RMS per coordinate.
    """
    pixels = np.asarray(pixels, float)
    body = np.asarray(body, float)
    if pixels.shape != (len(body), 2):
        raise ValueError(f"pixels must have shape (n_body={len(body)}, 2); got {pixels.shape}")
    if reject_sigma is not None and not reject_sigma > 0:
        raise ValueError(f"reject_sigma must be > 0 (robust sigmas) or None; got {reject_sigma}")
    seen = np.all(np.isfinite(pixels), axis=1)
    free = _free_mask(seed, fix_focal=fix_focal, refine_k2=refine_k2, refine_k3=refine_k3,
                      refine_tangential=refine_tangential, refine_aspect=refine_aspect, refine_window=refine_window,
                      refine_window_tilt=refine_window_tilt)
    if seen.sum() * 2 <= free.sum() + 2:
        raise ValueError(f"calibrate_from_body: {int(seen.sum())} matched points cannot fix {int(free.sum())} parameters")
    ok = seen
    x0 = _params(seed)[free]
    if reject_sigma is not None:
        robust = _fit(pixels, body, seed, free, ok, x0, loss="soft_l1")
        ok = _inliers(_residuals(_camera_from(robust.x, seed, free), body, pixels), seen, reject_sigma)
        x0 = robust.x
        if ok.sum() * 2 <= free.sum() + 2:
            ok, x0 = seen, _params(seed)[free]
    sol = _fit(pixels, body, seed, free, ok, x0)
    cam = _camera_from(sol.x, seed, free)
    res = _residuals(cam, body, pixels)
    rms = float(np.sqrt(np.nanmean(np.sum(res[ok] ** 2, axis=1))))
    return _assess(cam, sol, free, res, rms, ok, sigma_px, max_focal_rel_sigma)


def _fit(pixels, body, seed, free, ok, x0, loss="linear"):
    def residual(x):
        r = _camera_from(x, seed, free).project(body[ok]) - pixels[ok]
        return np.nan_to_num(r, nan=1e3).ravel()

    if loss == "linear":
        return least_squares(residual, x0, x_scale="jac", method="lm")
    return least_squares(residual, x0, x_scale="jac", loss=loss, f_scale=0.5)


def _residuals(cam: Camera, body: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    seen = np.all(np.isfinite(pixels), axis=1)
    res = np.full(pixels.shape, np.nan)
    res[seen] = cam.project(body[seen]) - pixels[seen]
    return res


def _inliers(res: np.ndarray, seen: np.ndarray, k: float) -> np.ndarray:
    """Seen points within ``k`` robust sigmas of the residual norms."""
    n = np.linalg.norm(res, axis=1)
    fin = seen & np.isfinite(n)
    s = 1.4826 * np.median(n[fin]) / 1.1774 if fin.any() else np.inf
    return fin & (n <= k * s)


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
    n_rej = int(np.all(np.isfinite(res), axis=1).sum() - ok.sum())
    msg = (f"{cam.name}: {int(ok.sum())} points ({n_rej} rejected), RMS {rms:.3f} px, focal {f:.1f} px +- {100 * rel:.2g} %"
           + ("" if "f" in sigma else " (fixed)")
           + ("" if well else f": ILL-POSED (focal length not determined to {100 * max_rel:g} %; "
                               "use a deeper body, more views or a fixed focal length)"))
    (log.info if well else log.warning)(msg)
    return BodyCalibration(cam, res, rms, sigma, well, msg, ok.copy())
