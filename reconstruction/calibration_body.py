"""Calibration of one camera from a 3-D calibration body (points with known coordinates), through its window.

The body's points are matched to detected dots by projecting them with a seed camera (e.g. an
imported or previous calibration); the dots' centres are refined on the image
(:func:`refine_dot_centres`: intensity-weighted moments above a local background); then pose,
focal length, principal point, distortion (k1, k2, optionally k3, p1, p2, the aspect ratio) and
optionally the window (its position along its normal, its tilt) are refined by least squares on the
pixel residuals, with the refraction model of :class:`~reconstruction.cameras.Camera`. Dots that do
not fit (a defect on the body, a dot assigned to the wrong point) are found with a robust loss,
dropped, and the fit is repeated on the rest (``reject_sigma``).

A body that covers only a band of the image determines the terms that act there, not those whose effect
grows towards the corners (k2, k3, the aspect ratio freed on cameras 1-2 of OpenPTV's test_cavity extrapolate
by 60-1,600 px at the corners while fitting the dots to 0.13-0.26 px): :func:`select_body_model` frees only
the combinations of terms that the dots determine over the whole image (:func:`projection_sigma_px` at
:func:`coverage_points`) and among them picks the lowest cross-validated RMS.

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

__all__ = ["BodyCalibration", "BodyModelSelection", "BODY_TERM_GROUPS", "body_models", "match_body_points",
           "refine_dot_centres", "calibrate_from_body", "select_body_model", "coverage_points", "projection_sigma_px",
           "CAMERA_PARAMETERS", "camera_parameters", "camera_with_parameters"]

log = logging.getLogger(__name__)

#: the parameters of a camera the body calibration and the volume self-calibration refine, in the order of
#: :func:`camera_parameters` (pose rvec (rad) and tvec (m), focal length fy (px), principal point (px), distortion,
#: window offset (m), aspect fx/fy, the window normal's two tilts (rad) relative to its current direction)
CAMERA_PARAMETERS = ("rx", "ry", "rz", "tx", "ty", "tz", "f", "cx", "cy", "k1", "k2", "window_offset",
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
    covariance : ndarray, shape (k, k), optional
        Covariance of the refined parameters ``free`` (their order in ``CAMERA_PARAMETERS``; tilts relative to the
        result's window normal), from the inverse normal matrix: poor when terms nearly trade off (the window
        tilt and the pose); :func:`projection_sigma_px` recomputes it stably.
    free : tuple of str
        Names of the refined parameters.
    """

    camera: Camera
    residuals: np.ndarray
    rms: float
    sigma: dict
    well_posed: bool
    message: str
    inliers: np.ndarray | None = None
    covariance: np.ndarray | None = None
    free: tuple = ()

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


def camera_with_parameters(x: np.ndarray, seed: Camera, free: np.ndarray) -> Camera:
    """``seed`` with the parameters selected by ``free`` (bool, shape (18,), order of :data:`CAMERA_PARAMETERS`)
    replaced by ``x`` (shape (free.sum(),)); the inverse of ``camera_parameters(cam)[free]``."""
    p = camera_parameters(seed)
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


def camera_parameters(cam: Camera) -> np.ndarray:
    """The parameter vector ``(18,)`` of ``cam`` in the order of :data:`CAMERA_PARAMETERS` (rad, m, px; the
    window's tilts are 0: they are relative to its current normal)."""
    off = cam.window.offset if cam.window is not None else 0.0
    d = cam.dist
    return np.array([*cam.rvec, *cam.tvec, cam.K[1, 1], cam.K[0, 2], cam.K[1, 2], d[0], d[1], off,
                     d[4], d[2], d[3], cam.K[0, 0] / cam.K[1, 1], 0.0, 0.0])


def _free_mask(seed: Camera, *, fix_focal, refine_k2, refine_k3, refine_tangential, refine_aspect, refine_window,
               refine_window_tilt) -> np.ndarray:
    free = np.zeros(len(CAMERA_PARAMETERS), bool)
    free[[0, 1, 2, 3, 4, 5, 7, 8, 9]] = True
    has_window = seed.window is not None
    for i, on in ((6, not fix_focal), (10, refine_k2), (11, refine_window and has_window), (12, refine_k3),
                  (13, refine_tangential), (14, refine_tangential), (15, refine_aspect),
                  (16, refine_window_tilt and has_window), (17, refine_window_tilt and has_window)):
        free[i] = on
    return free


def _terms_mask(seed: Camera, terms) -> np.ndarray:
    """Free-parameter mask of the pose plus ``terms`` (names of :data:`CAMERA_PARAMETERS`; ``window_tilt`` = both tilts)."""
    names = {"window_tilt_a", "window_tilt_b"} if "window_tilt" in terms else set()
    names |= set(terms) - {"window_tilt", "pose"}
    unknown = names - set(CAMERA_PARAMETERS)
    if unknown:
        raise ValueError(f"terms must be names of {CAMERA_PARAMETERS + ('window_tilt',)}; got unknown {sorted(unknown)}")
    if seed.window is None:
        names -= {"window_tilt_a", "window_tilt_b", "window_offset"}
    free = np.array([n in names for n in CAMERA_PARAMETERS])
    free[:6] = True
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
    terms: tuple[str, ...] | None = None,
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
    terms : tuple of str, optional
        Instead of the flags above: exactly the parameters refined besides the pose, by name (``"f"``,
        ``"cx"``, ``"cy"``, ``"k1"``, ``"k2"``, ``"k3"``, ``"p1"``, ``"p2"``, ``"aspect"``, ``"window_offset"``,
        ``"window_tilt"``); the others keep the seed's values (:func:`body_models`).
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
    if terms is not None:
        free = _terms_mask(seed, terms)
    if seen.sum() * 2 <= free.sum() + 2:
        raise ValueError(f"calibrate_from_body: {int(seen.sum())} matched points cannot fix {int(free.sum())} parameters")
    ok = seen
    x0 = camera_parameters(seed)[free]
    if reject_sigma is not None:
        robust = _fit(pixels, body, seed, free, ok, x0, loss="soft_l1")
        ok = _inliers(_residuals(camera_with_parameters(robust.x, seed, free), body, pixels), seen, reject_sigma)
        x0 = robust.x
        if ok.sum() * 2 <= free.sum() + 2:
            ok, x0 = seen, camera_parameters(seed)[free]
    sol = _fit(pixels, body, seed, free, ok, x0)
    cam = camera_with_parameters(sol.x, seed, free)
    res = _residuals(cam, body, pixels)
    rms = float(np.sqrt(np.nanmean(np.sum(res[ok] ** 2, axis=1))))
    return _assess(cam, sol, free, res, rms, ok, sigma_px, max_focal_rel_sigma)


def _fit(pixels, body, seed, free, ok, x0, loss="linear"):
    def residual(x):
        r = camera_with_parameters(x, seed, free).project(body[ok]) - pixels[ok]
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
        cov = None
        sig = np.full(int(free.sum()), np.inf)
    names = tuple(np.array(CAMERA_PARAMETERS)[free].tolist())
    sigma = dict(zip(names, sig.tolist()))
    f = cam.K[1, 1]
    rel = sigma.get("f", 0.0) / f
    well = bool(np.isfinite(rel) and rel <= max_rel and sol.success)
    n_rej = int(np.all(np.isfinite(res), axis=1).sum() - ok.sum())
    msg = (f"{cam.name}: {int(ok.sum())} points ({n_rej} rejected), RMS {rms:.3f} px, focal {f:.1f} px +- {100 * rel:.2g} %"
           + ("" if "f" in sigma else " (fixed)")
           + ("" if well else f": ILL-POSED (focal length not determined to {100 * max_rel:g} %; "
                               "use a deeper body, more views or a fixed focal length)"))
    (log.info if well else log.warning)(msg)
    return BodyCalibration(cam, res, rms, sigma, well, msg, ok.copy(), cov, names)


#: groups of terms :func:`select_body_model` tries (every combination, besides the pose); the others keep the seed's
BODY_TERM_GROUPS = {
    "window_tilt": ("window_tilt",),
    "principal_point": ("cx", "cy"),
    "k1": ("k1",),
    "k2,p1,p2": ("k2", "p1", "p2"),
    "k3,aspect": ("k3", "aspect"),
}


def body_models(groups: dict | None = None, *, max_groups: int | None = None) -> dict:
    """Candidate models: every combination of ``groups`` (default :data:`BODY_TERM_GROUPS`; up to ``max_groups``
    of them), named ``"pose"`` or ``"pose+g1+g2"``, simplest first; values are the ``terms`` of
    :func:`calibrate_from_body`."""
    from itertools import combinations

    groups = dict(BODY_TERM_GROUPS if groups is None else groups)
    out = {}
    for k in range(0, min(len(groups), max_groups if max_groups is not None else len(groups)) + 1):
        for combo in combinations(groups, k):
            out["+".join(("pose", *combo))] = tuple(t for g in combo for t in groups[g])
    return out


def coverage_points(camera: Camera, body: np.ndarray, *, grid: int = 5) -> np.ndarray:
    """World points ``(grid**2, 3)`` (m) seen on a ``grid x grid`` lattice of pixels spanning the whole image
    (corners included) at the median depth (camera z) of ``body``: where a calibration is used beyond the
    band of the image the body's dots cover."""
    W, H = camera.image_size
    u, v = np.meshgrid(np.linspace(0, W - 1, grid), np.linspace(0, H - 1, grid))
    o, d = camera.rays(np.stack([u.ravel(), v.ravel()], axis=1))
    z = np.median(camera.to_camera(body)[:, 2])
    zo, zd = camera.to_camera(o)[:, 2], (d @ camera.R.T)[:, 2]
    return o + ((z - zo) / zd)[:, None] * d


def projection_sigma_px(result: BodyCalibration, body: np.ndarray, points: np.ndarray) -> np.ndarray:
    """1-sigma (px, norm of the 2-D standard deviations) ``(n,)`` of the projections of ``points`` ``(n, 3)``
    implied by the fit of ``result`` on its inlier dots at ``body`` (``(n_body, 3)``, m): how well the body
    determines the calibration at those points.

    The Jacobians at the dots and at ``points`` come from the same central differences, and the normal
    matrix is inverted through the SVD of the column-scaled Jacobian (the window tilt and the pose nearly
    trade off: a plain inverse of the normal matrix loses the cancellation)."""
    free = np.array([n in result.free for n in CAMERA_PARAMETERS])
    dots = np.asarray(body, float)[result.inliers]
    Jb = _projection_jacobian(result.camera, free, dots).reshape(-1, int(free.sum()))
    Jp = _projection_jacobian(result.camera, free, np.asarray(points, float))  # (n, 2, k)
    dof = max(Jb.shape[0] - Jb.shape[1], 1)
    s2 = float(np.nansum(result.residuals[result.inliers] ** 2)) / dof
    D = np.linalg.norm(Jb, axis=0)
    D = np.where(D > 0, D, 1.0)
    _, S, Vt = np.linalg.svd(Jb / D, full_matrices=False)
    keep = S > S[0] * 1e-12
    A = np.einsum("nik,jk->nij", Jp / D, Vt[keep] / S[keep, None])  # (n, 2, r)
    return np.sqrt(s2 * np.sum(A**2, axis=(1, 2)))


def _projection_jacobian(camera: Camera, free: np.ndarray, points: np.ndarray) -> np.ndarray:
    """d project(points) / d parameters ``(n, 2, k)`` around ``camera`` (central differences)."""
    x0 = camera_parameters(camera)[free]
    steps = 1e-6 * np.maximum(np.abs(x0), 1e-2)
    return np.stack([(camera_with_parameters(x0 + h * e, camera, free).project(points)
                      - camera_with_parameters(x0 - h * e, camera, free).project(points)) / (2 * h)
                     for h, e in zip(steps, np.eye(len(x0)))], axis=-1)


@dataclass(frozen=True)
class BodyModelSelection:
    """Result of :func:`select_body_model`.

    Attributes
    ----------
    chosen : str
        Name of the model chosen (key of the ``models`` given).
    calibration : BodyCalibration
        The chosen model's fit.
    table : dict
        Per model: ``rms_px`` (fit), ``cv_rms_px`` (dots left out, predicted), ``image_sigma_px`` (largest
        1-sigma of the projection over the whole image at the body's depth), ``admissible``.
    """

    chosen: str
    calibration: BodyCalibration
    table: dict


def select_body_model(pixels: np.ndarray, body: np.ndarray, seed: Camera, *, models: dict | None = None,
                      max_image_sigma_px: float = 1.0, folds: int = 5, tie_px: float = 0.005,
                      reject_sigma: float = 3.0, seed_rng: int = 0) -> BodyModelSelection:
    """Calibrate ``seed`` on the body with each of ``models`` (default :func:`body_models`: every combination of
    :data:`BODY_TERM_GROUPS`; terms not freed keep the seed's values) and choose the one the dots determine.

    A model is admissible when the body determines its projection over the whole image
    (:func:`coverage_points`, :func:`projection_sigma_px`) to ``max_image_sigma_px`` (1 sigma): terms whose
    effect outside the band of the dots is unconstrained are not freed. Among the admissible models the one
    with the lowest ``folds``-fold cross-validated RMS (dots left out, predicted by the fit on the others)
    is chosen; a simpler one within ``tie_px`` of it is preferred. Outliers are found once, with the richest
    model (``reject_sigma``), and left out of every fit. When no model is admissible the simplest is chosen.
    """
    models = dict(models or body_models())
    pixels = np.asarray(pixels, float)
    body = np.asarray(body, float)
    richest = calibrate_from_body(pixels, body, seed, terms=max(models.values(), key=len), reject_sigma=reject_sigma)
    px = np.where(richest.inliers[:, None], pixels, np.nan)
    idx = np.flatnonzero(richest.inliers)
    np.random.default_rng(seed_rng).shuffle(idx)
    table, fits = {}, {}
    for name, terms in models.items():
        fit = calibrate_from_body(px, body, seed, terms=terms, reject_sigma=None)
        sigma_img = float(np.max(projection_sigma_px(fit, body, coverage_points(fit.camera, body))))
        table[name] = {"rms_px": fit.rms, "cv_rms_px": _cv_rms(px, body, seed, terms, np.array_split(idx, folds)),
                       "image_sigma_px": sigma_img, "admissible": bool(sigma_img <= max_image_sigma_px)}
        fits[name] = fit
    ok = [n for n in models if table[n]["admissible"]] or [next(iter(models))]
    best = min(table[n]["cv_rms_px"] for n in ok)
    chosen = next(n for n in ok if table[n]["cv_rms_px"] <= best + tie_px)
    log.info("%s: body model %s (%s)", seed.name, chosen, ", ".join(
        f"{n}: cv {t['cv_rms_px']:.3f} px, image sigma {t['image_sigma_px']:.2f} px" for n, t in table.items()))
    return BodyModelSelection(chosen, fits[chosen], table)


def _cv_rms(px: np.ndarray, body: np.ndarray, seed: Camera, terms, folds: list) -> float:
    """RMS (px) of the dots of each fold predicted by the fit on the other folds."""
    err = []
    for f in folds:
        train = px.copy()
        train[f] = np.nan
        try:
            cam = calibrate_from_body(train, body, seed, terms=terms, reject_sigma=None).camera
        except ValueError:  # too few dots left to fix this model's parameters
            return float("inf")
        err.append(np.sum((cam.project(body[f]) - px[f]) ** 2, axis=1))
    return float(np.sqrt(np.mean(np.concatenate(err))))
