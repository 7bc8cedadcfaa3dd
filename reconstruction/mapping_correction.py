"""A correction of the camera model that depends on the 3-D position, not only on the pixel.

After a volume self-calibration the cameras are still inconsistent by a few tenths of a pixel in a way that
varies over the measurement volume (``docs/reconstruction.md``, "Mapping correction in 3-D"). A correction of the
detections as a function of the pixel (``temporal_matching.fit_pixel_correction``) cannot represent an error that
changes with the depth along a camera's line of sight; Wieneke's volume self-calibration (2008) corrects the
mapping per sub-volume in 3-D. Here, per camera, the reprojection residual of verified matches (projected minus
detected, px) is fitted as a smooth function of the world point: a polynomial of total degree ``degree`` in the
world coordinates normalised to [-1, 1] over the measurement box (held constant beyond it), ridge-regularised,
with a robust second fit; the degree is chosen by cross-validation over held-out groups (e.g. frames).

:class:`CorrectedCamera` is a :class:`~reconstruction.cameras.Camera` whose projection is
``project(X) - correction(X)`` (the corrected model puts the particle where it was detected) and whose rays
undo it: for each pixel two points along its line of sight through the box (at the middle of the span +- half
of it / sqrt(2)) are found by a fixed-point iteration (the correction is small and smooth) and the ray joins
them. A correction curved along the line of sight makes the set of points that project to a pixel a curve, not
a line: the straight ray errs there by about half the correction's curvature over the box (a quadratic term of
``a`` px in the normalised depth: ``a / 2`` px), which only the seeding of candidate pairs sees; gates and
triangulation use the projection, which is exact. Triangulation, the epipolar
curves and the matching go through it unchanged (``reconstruction/triangulation.py`` projects with the correction
when a camera has one).

Pure functions over arrays; metres and pixels as OpenCV (``docs/decisions/0002-frames-and-shapes.md``).
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass, field

import numpy as np

from reconstruction.cameras import Camera

__all__ = ["MappingCorrection", "CorrectedCamera", "polynomial_basis", "fit_mapping_correction",
           "cross_validated_degree", "corrected_cameras", "correction_at"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class MappingCorrection:
    """One camera's correction: the predicted residual (projected minus detected, px) at world points.

    Attributes
    ----------
    coefficients : ndarray, shape (n_terms, 2)
        Polynomial coefficients (u, v), px.
    lower, upper : ndarray, shape (3,)
        The box the world coordinates are normalised over (m); beyond it the correction is held constant.
    degree : int
        Total degree.
    """

    coefficients: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    degree: int

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """Predicted residual ``(..., 2)`` px at world points ``(..., 3)`` m (NaN points give NaN)."""
        X = np.asarray(points, float)
        flat = X.reshape(-1, 3)
        z = np.clip(2.0 * (flat - self.lower) / (self.upper - self.lower) - 1.0, -1.0, 1.0)
        return (polynomial_basis(z, self.degree) @ self.coefficients).reshape(X.shape[:-1] + (2,))


def polynomial_basis(z: np.ndarray, degree: int) -> np.ndarray:
    """Monomials of total degree <= ``degree`` of ``z`` ``(n, k)`` (normalised coordinates): ``(n, n_terms)``,
    ``n_terms = C(k + degree, degree)``; the constant first."""
    z = np.asarray(z, float)
    cols = [np.prod(z[:, list(c)], axis=1) if c else np.ones(len(z))
            for d in range(degree + 1) for c in itertools.combinations_with_replacement(range(z.shape[1]), d)]
    return np.stack(cols, axis=1)


def _normalised(points: np.ndarray, bounds) -> np.ndarray:
    lo, hi = (np.asarray(b, float) for b in bounds)
    return np.clip(2.0 * (points - lo) / (hi - lo) - 1.0, -1.0, 1.0)


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


def cross_validated_degree(points: np.ndarray, residuals: np.ndarray, bounds, groups: np.ndarray, *,
                           degrees=(0, 1, 2, 3), ridge: float = 1e-4, clip_sigma: float = 3.0) -> tuple[int, dict]:
    """The degree whose fit predicts held-out residuals best, for one camera.

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        World points of the matches this camera sees, m.
    residuals : ndarray, shape (n, 2)
        Their residuals in this camera (projected - detected), px.
    bounds : (ndarray (3,), ndarray (3,))
        The normalisation box, m.
    groups : ndarray of int, shape (n,)
        Each group held out in turn (e.g. the frame: a particle moves little between frames, so frames are not
        independent of each other, but a smooth low-order map cannot fit single particles).
    degrees : sequence of int
    ridge, clip_sigma : float
        As :func:`fit_mapping_correction`.

    Returns
    -------
    degree : int
    rms_px : dict
        Held-out RMS of the residual left (px) per degree; robust: residuals over 3 robust sigmas of the
        degree-0 prediction are left out of the score.
    """
    z = _normalised(points, bounds)
    scores = {}
    base = np.linalg.norm(residuals - np.median(residuals, axis=0), axis=1)
    inlier = base <= 3.0 * 1.4826 * np.median(base) + 1e-12
    for d in degrees:
        A = polynomial_basis(z, d)
        pred = np.full_like(residuals, np.nan)
        for g in np.unique(groups):
            tr = groups != g
            if tr.sum() < 2 * A.shape[1]:
                break
            pred[~tr] = A[~tr] @ _robust_fit(A[tr], residuals[tr], ridge, clip_sigma)
        e = np.sum((residuals - pred)[inlier] ** 2, axis=1)
        scores[d] = float(np.sqrt(np.mean(e))) if np.all(np.isfinite(e)) else np.inf
    best = min(scores, key=lambda d: (round(scores[d], 4), d))
    return best, scores


def fit_mapping_correction(points: np.ndarray, residuals: np.ndarray, bounds, *, degree: int | None = None,
                           groups: np.ndarray | None = None, ridge: float = 1e-4, clip_sigma: float = 3.0,
                           min_points: int = 60) -> list[MappingCorrection]:
    """Per camera, the residual of verified matches as a smooth function of the world point.

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        Triangulated points of verified matches, m.
    residuals : ndarray, shape (n_cameras, n, 2)
        Their reprojection residuals (projected - detected), px; NaN where a camera does not see a match.
    bounds : (ndarray (3,), ndarray (3,))
        The measurement box, m: coordinates are normalised to [-1, 1] over it (held constant beyond).
    degree : int, optional
        Total degree; None = chosen per camera by :func:`cross_validated_degree` over ``groups`` (0-3).
    groups : ndarray of int, shape (n,), optional
        Cross-validation groups (e.g. the frame of each match); required when ``degree`` is None.
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
    if degree is None and groups is None:
        raise ValueError("fit_mapping_correction: give a degree or the cross-validation groups; got neither")
    lo, hi = (np.asarray(b, float).reshape(3) for b in bounds)
    if not np.all(hi > lo):
        raise ValueError(f"bounds must be (lower, upper) with upper > lower (m); got {lo}, {hi}")
    out = []
    for c in range(residuals.shape[0]):
        ok = np.all(np.isfinite(residuals[c]), axis=1) & np.all(np.isfinite(points), axis=1)
        d = degree
        if d is None:
            d, scores = (0, {})
            if ok.sum() >= min_points:
                d, scores = cross_validated_degree(points[ok], residuals[c, ok], (lo, hi), np.asarray(groups)[ok],
                                                   ridge=ridge, clip_sigma=clip_sigma)
            log.info("mapping correction, camera %d: degree %d (held-out RMS %s px)", c, d, scores)
        A = polynomial_basis(_normalised(points[ok], (lo, hi)), d)
        coef = np.zeros((A.shape[1], 2))
        if ok.sum() >= max(min_points, 2 * A.shape[1]):
            coef = _robust_fit(A, residuals[c, ok], ridge, clip_sigma)
        else:
            log.warning("fit_mapping_correction: camera %d sees %d matches (< %d): no correction",
                        c, ok.sum(), min_points)
        out.append(MappingCorrection(coef, lo, hi, int(d)))
    return out


def correction_at(corrections: list[MappingCorrection], points: np.ndarray) -> np.ndarray:
    """Predicted residuals ``(n_cameras, n, 2)`` px at world points ``(n, 3)`` m."""
    return np.stack([c(points) for c in corrections])


@dataclass(frozen=True)
class CorrectedCamera(Camera):
    """A camera whose projection subtracts a :class:`MappingCorrection` (see the module docstring).

    ``project(X) = Camera.project(X) - correction(X)``; ``rays(u)`` are the lines through two points along the
    line of sight through the correction's box that project to ``u``.
    """

    correction: MappingCorrection | None = field(default=None, compare=False)
    iterations: int = 4

    def project(self, points: np.ndarray) -> np.ndarray:
        base = Camera.project(self, points)
        if self.correction is None:
            return base
        return base - self.correction(points)

    def base_camera(self) -> Camera:
        """The camera without the correction."""
        return Camera(self.name, self.K, self.dist, self.rvec, self.tvec, self.image_size, self.meta, self.window)

    def rays(self, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World-frame rays ``(n, 3)`` origins (m) and unit directions of pixels ``(n, 2)``, the correction undone."""
        pixels = np.asarray(pixels, float).reshape(-1, 2)
        o, d = Camera.rays(self, pixels)
        if self.correction is None or len(pixels) == 0:
            return o, d
        t0, t1 = _box_span(o, d, self.correction.lower, self.correction.upper)
        # nodes at the middle of the span +- half of it / sqrt(2): the chord of a correction curved along the line
        # of sight (e.g. quadratic in depth) then errs by half as much as through the span's ends
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
            target = pixels + self.correction(X)
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


def corrected_cameras(cameras: list[Camera], corrections: list[MappingCorrection]) -> list[CorrectedCamera]:
    """The cameras with their corrections (a :class:`CorrectedCamera` already corrected is replaced, not stacked)."""
    if len(cameras) != len(corrections):
        raise ValueError(f"corrections must have one entry per camera ({len(cameras)}); got {len(corrections)}")
    out = []
    for cam, corr in zip(cameras, corrections):
        base = cam.base_camera() if isinstance(cam, CorrectedCamera) else cam
        out.append(CorrectedCamera(base.name, base.K, base.dist, base.rvec, base.tvec, base.image_size, base.meta,
                                   base.window, correction=corr))
    return out
