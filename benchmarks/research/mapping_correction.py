"""A correction of the camera model that depends on the 3-D position, not only on the pixel.

After a volume self-calibration the cameras are still inconsistent by a few tenths of a pixel in a way that
varies over the measurement volume (``docs/validation/reconstruction.md``, "Mapping correction in 3-D"). A correction of the
detections as a function of the pixel (``temporal_matching.fit_pixel_correction``) cannot represent an error that
changes with the depth along a camera's line of sight; Wieneke's volume self-calibration (2008) corrects the
mapping per sub-volume in 3-D. Here, per camera, the reprojection residual of verified matches (projected minus
detected, px) is fitted as a map over the image plus a map of its slope along the depth (:class:`MappingCorrection`:
polynomials of the pixel, the second times the normalised depth), ridge-regularised, with a robust second fit;
the degrees are chosen by cross-validation over held-out groups (e.g. frames). (A polynomial of the world point,
curved along the lines of sight, fitted the real residuals no better and made the back-projected rays err by up
to 1.2 px: a correction linear in depth along a line of sight keeps the points that project to a pixel a line.)

:class:`CorrectedCamera` is a :class:`~reconstruction.cameras.Camera` whose projection is
``project(X) - correction(X)`` (the corrected model puts the particle where it was detected) and whose rays
undo it: for each pixel two points along its line of sight through the measurement box (at the middle of the
span +- half of it / sqrt(2)) are found by a fixed-point iteration (the correction is small and smooth) and the ray
joins them. Triangulation, the epipolar curves and the matching go through it unchanged
(``reconstruction/triangulation.py`` projects with the correction when a camera has one).

Pure functions over arrays; metres and pixels as OpenCV (``docs/decisions/0002-frames-and-shapes.md``).
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass, field

import numpy as np

from reconstruction.cameras import Camera

__all__ = ["MappingCorrection", "CorrectedCamera", "MODELS", "polynomial_basis", "correction_basis", "held_out_rms",
           "fit_mapping_correction", "corrected_cameras", "correction_at"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class MappingCorrection:
    """One camera's correction: the predicted residual (projected minus detected, px) as a map over the image plus
    a map of its slope along the depth,

        c(X) = P_d(u, v) + z P_e(u, v)

    with ``(u, v)`` the camera's (uncorrected) projection of X normalised to [-1, 1] over the image, ``z`` the world
    coordinate along ``depth_axis`` normalised to [-1, 1] over ``depth_range`` (not clipped: linear beyond it),
    ``P_d`` a polynomial of total degree ``degree``, ``P_e`` one of degree ``depth_degree`` (-1: none, a map of the
    pixel alone). Linear in depth along a line of sight, the points that project to a pixel stay (nearly) a line.

    Attributes
    ----------
    coefficients : ndarray, shape (n_terms, 2)
        Polynomial coefficients (u, v), px; the pixel map's terms first.
    image_size : tuple (W, H)
        Pixels.
    depth_axis : int
        World axis (0, 1, 2) taken as the depth.
    depth_range : tuple of float
        (lower, upper) of the depth coordinate mapped to [-1, 1], m.
    degree, depth_degree : int
    """

    coefficients: np.ndarray
    image_size: tuple
    depth_axis: int
    depth_range: tuple
    degree: int
    depth_degree: int

    def __call__(self, pixels: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Predicted residual ``(..., 2)`` px at world points ``(..., 3)`` m whose uncorrected projections are
        ``pixels`` ``(..., 2)`` (NaN gives NaN)."""
        px = np.asarray(pixels, float)
        A = correction_basis(px.reshape(-1, 2), np.asarray(points, float).reshape(-1, 3), self.image_size,
                             self.depth_axis, self.depth_range, self.degree, self.depth_degree)
        return (A @ self.coefficients).reshape(px.shape)


def polynomial_basis(z: np.ndarray, degree: int) -> np.ndarray:
    """Monomials of total degree <= ``degree`` of ``z`` ``(n, k)`` (normalised coordinates): ``(n, n_terms)``,
    ``n_terms = C(k + degree, degree)``; the constant first; ``degree`` -1 gives ``(n, 0)``."""
    z = np.asarray(z, float)
    cols = [np.prod(z[:, list(c)], axis=1) if c else np.ones(len(z))
            for d in range(degree + 1) for c in itertools.combinations_with_replacement(range(z.shape[1]), d)]
    return np.stack(cols, axis=1) if cols else np.zeros((len(z), 0))


def correction_basis(pixels: np.ndarray, points: np.ndarray, image_size, depth_axis: int, depth_range,
                     degree: int, depth_degree: int) -> np.ndarray:
    """Terms of :class:`MappingCorrection` at pixels ``(n, 2)`` and points ``(n, 3)``: ``(n, n_terms)``."""
    W, H = image_size
    uv = 2.0 * pixels / [max(W - 1, 1), max(H - 1, 1)] - 1.0
    lo, hi = depth_range
    z = 2.0 * (points[:, depth_axis:depth_axis + 1] - lo) / (hi - lo) - 1.0
    return np.concatenate([polynomial_basis(uv, degree), z * polynomial_basis(uv, depth_degree)], axis=1)


def _solve(A: np.ndarray, r: np.ndarray, ridge: float) -> np.ndarray:
    """Ridge least squares ``(n_terms, 2)``; the constant term is not penalised."""
    pen = ridge * len(A) * np.eye(A.shape[1])
    pen[0, 0] = 0.0
    return np.linalg.solve(A.T @ A + pen, A.T @ r)


def _robust_fit(A: np.ndarray, r: np.ndarray, ridge: float, clip_sigma: float) -> np.ndarray:
    """Fit, drop the residuals farther than ``clip_sigma`` robust sigmas from it, fit again."""
    coef = _solve(A, r, ridge)
    e = np.linalg.norm(A @ coef - r, axis=1)
    keep = e <= clip_sigma * 1.4826 * np.median(e) + 1e-12
    return _solve(A[keep], r[keep], ridge)


#: (degree, depth_degree) pairs the cross-validation chooses from: pixel maps of degree 0-3 with no depth term or a
#: depth slope of degree 0 up to the pixel map's
MODELS = tuple((d, e) for d in range(4) for e in range(-1, d + 1))


def held_out_rms(A: np.ndarray, residuals: np.ndarray, groups: np.ndarray, *, ridge: float = 1e-4,
                 clip_sigma: float = 3.0) -> float:
    """RMS (px) of ``residuals`` ``(n, 2)`` minus the fit of the terms ``A`` ``(n, n_terms)``, each group of
    ``groups`` ``(n,)`` predicted by the fit on the others; residuals over 3 robust sigmas of their median are
    left out of the score (not of the fits)."""
    base = np.linalg.norm(residuals - np.median(residuals, axis=0), axis=1)
    inlier = base <= 3.0 * 1.4826 * np.median(base) + 1e-12
    pred = np.full_like(residuals, np.nan)
    for g in np.unique(groups):
        tr = groups != g
        if tr.sum() < 2 * A.shape[1]:
            return np.inf
        pred[~tr] = A[~tr] @ _robust_fit(A[tr], residuals[tr], ridge, clip_sigma)
    return float(np.sqrt(np.mean(np.sum((residuals - pred)[inlier] ** 2, axis=1))))


def fit_mapping_correction(cameras: list[Camera], points: np.ndarray, residuals: np.ndarray, bounds, *,
                           model: tuple[int, int] | None = None, groups: np.ndarray | None = None,
                           ridge: float = 1e-4, clip_sigma: float = 3.0,
                           min_points: int = 60) -> list[MappingCorrection]:
    """Per camera, the residual of verified matches as a pixel map plus a depth slope (:class:`MappingCorrection`).

    Parameters
    ----------
    cameras : list of Camera
        The cameras the residuals were computed with (a :class:`CorrectedCamera`'s correction is ignored: fit its
        residuals with the base camera's).
    points : ndarray, shape (n, 3)
        Triangulated points of verified matches, m.
    residuals : ndarray, shape (n_cameras, n, 2)
        Their reprojection residuals (projected - detected), px; NaN where a camera does not see a match.
    bounds : (ndarray (3,), ndarray (3,))
        The measurement box, m: its extent along each camera's depth axis (the world axis closest to the camera's
        optical axis) is mapped to [-1, 1].
    model : (int, int), optional
        (degree, depth_degree) of :class:`MappingCorrection`; None = chosen per camera among :data:`MODELS` by the
        held-out RMS over ``groups`` (:func:`held_out_rms`; a simpler model within 0.001 px preferred).
    groups : ndarray of int, shape (n,), optional
        Cross-validation groups (e.g. the frame of each match); required when ``model`` is None.
    ridge : float
        Ridge weight per match on the non-constant coefficients (normalised coordinates, px^2).
    clip_sigma : float
        Residuals farther than this many robust sigmas from a first fit are left out of the second.
    min_points : int
        A camera seeing fewer matches gets no correction (zeros).

    Returns
    -------
    list of MappingCorrection, one per camera
    """
    points = np.asarray(points, float)
    residuals = np.asarray(residuals, float)
    if points.ndim != 2 or points.shape[1] != 3 or residuals.ndim != 3 or residuals.shape[1:] != (len(points), 2):
        raise ValueError(f"points must be (n, 3) and residuals (n_cameras, n, 2); "
                         f"got {points.shape}, {residuals.shape}")
    if len(cameras) != residuals.shape[0]:
        raise ValueError(f"residuals must have one row per camera ({len(cameras)}); got {residuals.shape[0]}")
    if model is None and groups is None:
        raise ValueError("fit_mapping_correction: give a model or the cross-validation groups; got neither")
    lo, hi = (np.asarray(b, float).reshape(3) for b in bounds)
    if not np.all(hi > lo):
        raise ValueError(f"bounds must be (lower, upper) with upper > lower (m); got {lo}, {hi}")
    return [_fit_one(cam, points, residuals[c], (lo, hi), model, groups, ridge, clip_sigma, min_points)
            for c, cam in enumerate(cameras)]


def _fit_one(cam, points, residuals, bounds, model, groups, ridge, clip_sigma, min_points) -> MappingCorrection:
    """:func:`fit_mapping_correction` for one camera (``residuals`` ``(n, 2)``)."""
    base = cam.base_camera() if isinstance(cam, CorrectedCamera) else cam
    axis = int(np.argmax(np.abs(base.R[2])))
    depth = (float(bounds[0][axis]), float(bounds[1][axis]))
    ok = np.all(np.isfinite(residuals), axis=1) & np.all(np.isfinite(points), axis=1)
    px = base.project(points[ok])
    ok[ok] = np.all(np.isfinite(px), axis=1)
    px = base.project(points[ok])

    def terms(m):
        return correction_basis(px, points[ok], base.image_size, axis, depth, *m)

    chosen = model or (0, -1)
    if model is None and ok.sum() >= min_points:
        scores = {m: held_out_rms(terms(m), residuals[ok], np.asarray(groups)[ok], ridge=ridge, clip_sigma=clip_sigma)
                  for m in MODELS}
        best = min(scores.values())
        chosen = min((m for m in MODELS if scores[m] <= best + 1e-3), key=lambda m: terms(m).shape[1])
        log.info("mapping correction, %s: model %s (held-out RMS %.3f px; pixel map alone, degree 3: %.3f px)",
                 base.name, chosen, scores[chosen], scores[(3, -1)])
    A = terms(chosen)
    coef = np.zeros((A.shape[1], 2))
    if ok.sum() >= max(min_points, 2 * A.shape[1]):
        coef = _robust_fit(A, residuals[ok], ridge, clip_sigma)
    else:
        log.warning("fit_mapping_correction: %s sees %d matches (< %d): no correction", base.name, ok.sum(), min_points)
    return MappingCorrection(coef, base.image_size, axis, depth, int(chosen[0]), int(chosen[1]))


def correction_at(cameras: list, points: np.ndarray) -> np.ndarray:
    """Corrections ``(n_cameras, n, 2)`` px of :class:`CorrectedCamera` s at world points ``(n, 3)`` m (zeros for a
    camera without one)."""
    out = []
    for cam in cameras:
        corr = getattr(cam, "correction", None)
        out.append(np.zeros((len(points), 2)) if corr is None else corr(Camera.project(cam, points), points))
    return np.stack(out)


@dataclass(frozen=True)
class CorrectedCamera(Camera):
    """A camera whose projection subtracts a :class:`MappingCorrection` (see the module docstring).

    ``project(X) = Camera.project(X) - correction(Camera.project(X), X)``; ``rays(u)`` are the lines through two
    points along the line of sight through ``box`` (the measurement box: (lower (3,), upper (3,)), m; required with a
    correction) that project to ``u``.
    """

    correction: MappingCorrection | None = field(default=None, compare=False)
    #: the measurement box (lower, upper), m: where the rays are made to pass through the corrected points
    box: tuple | None = field(default=None, compare=False)
    iterations: int = 4

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.correction is not None and self.box is None:
            raise ValueError(f"CorrectedCamera {self.name!r}: a correction needs the measurement box (box=(lower, "
                             f"upper), m) its rays are fitted over; got box=None")

    def project(self, points: np.ndarray) -> np.ndarray:
        base = Camera.project(self, points)
        if self.correction is None:
            return base
        return base - self.correction(base, points)

    def base_camera(self) -> Camera:
        """The camera without the correction."""
        return Camera(self.name, self.K, self.dist, self.rvec, self.tvec, self.image_size, self.meta, self.window)

    def rays(self, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World-frame rays ``(n, 3)`` origins (m) and unit directions of pixels ``(n, 2)``, the correction undone."""
        pixels = np.asarray(pixels, float).reshape(-1, 2)
        o, d = Camera.rays(self, pixels)
        if self.correction is None or len(pixels) == 0:
            return o, d
        t0, t1 = _box_span(o, d, *self.box)
        # nodes at the middle of the span +- half of it / sqrt(2): were the correction curved along the line of sight
        # (it is linear in depth, up to its own small effect on the pixel), the chord would err least
        mid, half = 0.5 * (t0 + t1), 0.5 * (t1 - t0) / np.sqrt(2.0)
        t_near = np.maximum(mid - half, 1e-6)
        ends = [self._point_at(pixels, t) for t in (t_near, mid + half)]
        direction = ends[1] - ends[0]
        length = np.linalg.norm(direction, axis=1, keepdims=True)
        good = np.all(np.isfinite(direction), axis=1) & (length[:, 0] > 0)
        direction = np.where(good[:, None], direction / np.where(length > 0, length, 1.0), d)
        origin = np.where(good[:, None], ends[0] - t_near[:, None] * direction, o)
        return origin, direction

    def _point_at(self, pixels: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Points ``(n, 3)`` at ray parameter ``t`` (m from the bath side of the window) whose corrected
        projection is ``pixels`` (fixed point: the uncorrected ray of ``pixels + correction``)."""
        target = pixels.copy()
        for _ in range(self.iterations):
            o, d = Camera.rays(self, target)
            X = o + t[:, None] * d
            target = pixels + self.correction(target, X)
        o, d = Camera.rays(self, target)
        return o + t[:, None] * d


def _box_span(origins: np.ndarray, directions: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """Ray parameters (each (n,)) where rays enter and leave the box; rays missing it get the span of the
    box's centre depth +- half its diagonal (any two points on the line of sight will do there)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (lo - origins) / directions, (hi - origins) / directions
    t0 = np.nanmax(np.minimum(ta, tb), axis=1)
    t1 = np.nanmin(np.maximum(ta, tb), axis=1)
    centre = np.sum(((lo + hi) / 2 - origins) * directions, axis=1)
    half = 0.5 * np.linalg.norm(hi - lo)
    miss = ~(t1 > t0) | ~np.isfinite(t0) | ~np.isfinite(t1)
    t0 = np.where(miss, centre - half, t0)
    t1 = np.where(miss, centre + half, t1)
    return np.maximum(t0, 1e-6), np.maximum(t1, 2e-6)


def corrected_cameras(cameras: list[Camera], corrections: list[MappingCorrection], bounds) -> list[CorrectedCamera]:
    """The cameras with their corrections (a :class:`CorrectedCamera` already corrected is replaced, not stacked);
    ``bounds`` (lower (3,), upper (3,), m): the measurement box the rays are fitted over."""
    if len(cameras) != len(corrections):
        raise ValueError(f"corrections must have one entry per camera ({len(cameras)}); got {len(corrections)}")
    out = []
    for cam, corr in zip(cameras, corrections):
        base = cam.base_camera() if isinstance(cam, CorrectedCamera) else cam
        out.append(CorrectedCamera(base.name, base.K, base.dist, base.rvec, base.tvec, base.image_size, base.meta,
                                   base.window, correction=corr,
                                   box=None if bounds is None else tuple(np.asarray(b, float).reshape(3)
                                                                         for b in bounds)))
    return out
