"""Correspondence of identical, unlabelled markers across several calibrated views.

Method
------
1. For every camera pair with a usable baseline, all detection pairs within ``epipolar_px`` of
   each other's epipolar line (both images) are candidate matches.
2. Each candidate pair is triangulated (mid-point of the rays); it must lie in front of both
   cameras and, when a :class:`CylinderPrior` is given, near the specimen surface and on the side
   of the tube facing both cameras (the tube is opaque).
3. The candidate point is projected into every other camera; the nearest detection within
   ``max_reprojection_px`` (and facing that camera) joins its support. Candidates with identical
   support are merged, all are triangulated with every supporting view (DLT + Gauss-Newton), and
   views whose residual exceeds the gate are dropped.
4. Global selection: candidates are ranked by (clean reprojection, number of views, reprojection
   RMS) over the whole set, "clean" meaning an RMS within 4x the typical one; the best is accepted, and every other candidate that shares a detection with it loses that
   detection, is re-triangulated from the views it keeps and re-ranked (it is dropped if fewer than
   ``min_views`` remain). Each detection is used at most once and a candidate never wins by
   being first in some camera's list.

Shapes: detections per camera ``(n_i, 2)`` px; observations ``(n_points, n_cameras)`` indices
into those arrays, -1 = not observed.
"""

from __future__ import annotations

import heapq
import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from reconstruction.cameras import Camera
from reconstruction.epipolar import _refracted_pairs, _straight_pairs, epipolar_curve_pairs
from reconstruction.triangulation import Triangulation, triangulate

__all__ = ["CylinderPrior", "Correspondence", "match_views", "observed_pixels", "epipolar_curve_pairs"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CylinderPrior:
    """Where markers can be: near a cylinder around the specimen axis, on its camera-facing side.

    Attributes
    ----------
    radius : float
        Approximate radius of the marker centres (outer wall radius + marker radius), m.
    tolerance : float
        Accepted ``|r - radius|``, m.
    half_length : float
        Accepted ``|z - axis_point_z|`` along the axis, m (inf = unbounded).
    axis_point : ndarray, shape (3,)
        A point on the axis, m (world frame).
    axis_direction : ndarray, shape (3,)
        Unit axis direction (default +z).
    min_facing : float
        Minimum cosine between the outward radial direction and the direction to a camera for the
        marker to count as visible in it. A sphere standing one radius off the wall is still
        visible a little beyond the limb (such views are biased; the pipeline keeps them only
        when a marker has no two better views, and rejects the points they spoil).
    """

    radius: float
    tolerance: float
    half_length: float = np.inf
    axis_point: np.ndarray = field(default_factory=lambda: np.zeros(3))
    axis_direction: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    min_facing: float = -0.15

    def __post_init__(self) -> None:
        if not (self.radius > 0 and self.tolerance > 0):
            raise ValueError(
                f"CylinderPrior: radius and tolerance must be > 0 m; got {self.radius}, {self.tolerance}"
            )
        a = np.asarray(self.axis_direction, dtype=float)
        object.__setattr__(self, "axis_direction", a / np.linalg.norm(a))
        object.__setattr__(self, "axis_point", np.asarray(self.axis_point, dtype=float).reshape(3))

    def radial(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(radius (n,), axial coordinate (n,), outward unit radial direction (n, 3)) of points (n, 3)."""
        v = np.asarray(points, dtype=float) - self.axis_point
        z = v @ self.axis_direction
        rv = v - z[:, None] * self.axis_direction
        r = np.linalg.norm(rv, axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            n = rv / r[:, None]
        return r, z, n

    def admissible(self, points: np.ndarray) -> np.ndarray:
        """(n,) bool: the point is within the radial and axial tolerance."""
        r, z, _ = self.radial(points)
        return (np.abs(r - self.radius) <= self.tolerance) & (np.abs(z) <= self.half_length)

    def facing(self, points: np.ndarray, camera: Camera) -> np.ndarray:
        """(n,) bool: the outward normal at the point faces ``camera``."""
        _, _, n = self.radial(points)
        v = camera.center - points
        v = v / np.linalg.norm(v, axis=1, keepdims=True)
        return np.sum(n * v, axis=1) > self.min_facing


@dataclass(frozen=True)
class Correspondence:
    """Result of :func:`match_views`.

    Attributes
    ----------
    observations : ndarray of int, shape (n_points, n_cameras)
        Detection index per camera, -1 where unobserved.
    triangulation : Triangulation
        For the accepted points (``triangulation.points`` shape (n_points, 3), m).
    unmatched : list of ndarray of int
        Per camera, indices of detections not used by any point.
    n_candidates : int
        Distinct candidate points considered.
    """

    observations: np.ndarray
    triangulation: Triangulation
    unmatched: list[np.ndarray]
    n_candidates: int

    @property
    def points(self) -> np.ndarray:
        return self.triangulation.points


def observed_pixels(detections: list[np.ndarray], observations: np.ndarray) -> np.ndarray:
    """Gather pixels ``(n_cameras, n_points, 2)`` (NaN where -1) from per-camera detections."""
    n_pts, n_cams = observations.shape
    out = np.full((n_cams, n_pts, 2), np.nan)
    for c in range(n_cams):
        sel = observations[:, c] >= 0
        if np.any(sel):
            out[c, sel] = np.asarray(detections[c], dtype=float)[observations[sel, c]]
    return out


def _seed_candidates(dets, cameras, epipolar_px, prior, min_angle, max_angle, bounds) -> list:
    """Steps 1-2 of :func:`match_views`: candidate pairs and their mid-points, per camera pair."""
    n_cams = len(cameras)
    refracted = any(c.window is not None for c in cameras)
    norm = [cam.undistort_pixels(d) if len(d) else np.zeros((0, 2)) for cam, d in zip(cameras, dets)]
    rays = [cam.rays(d) if len(d) else (np.zeros((0, 3)), np.zeros((0, 3))) for cam, d in zip(cameras, dets)]
    axes = np.stack([c.R[2] for c in cameras])
    seeds = []
    for i in range(n_cams):
        for j in range(i + 1, n_cams):
            if len(dets[i]) == 0 or len(dets[j]) == 0:
                continue
            ang = np.degrees(np.arccos(np.clip(axes[i] @ axes[j], -1, 1)))
            if min(ang, 180.0 - ang if max_angle > 90.0 else ang) < min_angle or ang > max_angle:
                continue
            if refracted and bounds is not None:
                a, b, X, ok = epipolar_curve_pairs(i, j, dets, cameras, rays, epipolar_px, bounds)
            elif refracted:
                a, b, X, ok = _refracted_pairs(i, j, dets, cameras, rays, epipolar_px)
            else:
                a, b, X, ok = _straight_pairs(i, j, dets, cameras, norm, rays, epipolar_px)
            ok = ok & np.all(np.isfinite(X), axis=1)
            if bounds is not None:
                ok &= np.all((X >= np.asarray(bounds[0])) & (X <= np.asarray(bounds[1])), axis=1)
            if prior is not None:
                ok &= prior.admissible(X) & prior.facing(X, cameras[i]) & prior.facing(X, cameras[j])
            if np.any(ok):
                obs = np.full((int(ok.sum()), n_cams), -1, dtype=np.int64)
                obs[:, i] = a[ok]
                obs[:, j] = b[ok]
                seeds.append((X[ok], obs))
    return seeds


def match_views(
    detections: list[np.ndarray],
    cameras: list[Camera],
    *,
    epipolar_px: float = 2.0,
    max_reprojection_px: float = 1.5,
    prior: CylinderPrior | None = None,
    min_views: int = 2,
    min_pair_angle_deg: float = 8.0,
    max_pair_angle_deg: float = 150.0,
    sigma_px: float | None = None,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
) -> Correspondence:
    """Find which detections in different cameras are the same marker, and triangulate them.

    Parameters
    ----------
    detections : list of ndarray, shape (n_i, 2)
        Distorted pixel centres per camera (same order as ``cameras``).
    cameras : list of Camera
    epipolar_px : float
        Gate on the distance to the epipolar line for candidate pairs, px.
    max_reprojection_px : float
        Gate on the reprojection residual of every supporting view, px.
    prior : CylinderPrior, optional
        Specimen geometry used to discard ghost candidates.
    min_views : int
        Minimum number of views of an accepted point (>= 2).
    min_pair_angle_deg, max_pair_angle_deg : float
        Camera pairs whose optical axes differ by less or more than these are not used to seed
        candidates (nearly parallel or nearly opposite rays do not fix the depth; opposite
        cameras cannot both see a marker on an opaque tube anyway). With ``max_pair_angle_deg``
        above 90 (a transparent volume seen from both sides), an opposite pair also needs its rays
        to cross at ``min_pair_angle_deg`` or more (``180 - angle``).
    sigma_px : float, optional
        Pixel noise for the triangulation covariance (default estimated).
    bounds : (ndarray (3,), ndarray (3,)), optional
        World box (m) the points lie in (e.g. a particle measurement volume); candidates outside are
        dropped. Useful without a prior; with windows it also bounds the search along the epipolar
        curves (sampled rays, KD-tree), which is much faster than testing every pair.

    Cameras with a window (``Camera.window``) are matched along their epipolar *curves*: the rays
    in the bath are intersected, and the distance of each detection to the projection of the
    other camera's ray is measured at the closest approach of the two rays.

    Returns
    -------
    Correspondence
    """
    dets = _checked_detections(detections, cameras, min_views)
    seeds = _seed_candidates(dets, cameras, epipolar_px, prior, min_pair_angle_deg, max_pair_angle_deg, bounds)
    if not seeds:
        return _empty_correspondence(dets, cameras, 0)
    X = np.concatenate([s[0] for s in seeds])
    obs = np.concatenate([s[1] for s in seeds])
    obs = _support_from_other_cameras(X, obs, dets, cameras, 2.0 * max_reprojection_px, prior)
    obs = np.unique(obs, axis=0)
    obs = obs[(obs >= 0).sum(axis=1) >= min_views]
    tri, obs = _triangulate_gated(obs, dets, cameras, max_reprojection_px, min_views, prior, sigma_px)
    n_cand = obs.shape[0]
    chosen = _select(obs, tri, dets, cameras, max_reprojection_px, min_views, prior, sigma_px)
    if not chosen:
        return _empty_correspondence(dets, cameras, n_cand)
    final_obs = np.stack(chosen)
    final = triangulate(observed_pixels(dets, final_obs), cameras, sigma_px=sigma_px)
    # deterministic order: by axial then angular position
    order = np.lexsort((np.arctan2(final.points[:, 1], final.points[:, 0]), np.round(final.points[:, 2], 6)))
    return Correspondence(final_obs[order], _take(final, order), _unmatched(dets, final_obs[order]), n_cand)


def _checked_detections(detections, cameras, min_views) -> list[np.ndarray]:
    """Detections as float ``(n_i, 2)`` arrays, after checking the arguments of :func:`match_views`."""
    n_cams = len(cameras)
    if len(detections) != n_cams:
        raise ValueError(f"detections must have one array per camera ({n_cams}); got {len(detections)}")
    if min_views < 2:
        raise ValueError(f"min_views must be >= 2; got {min_views}")
    return [np.asarray(d, dtype=float).reshape(-1, 2) for d in detections]


def _empty_correspondence(dets, cameras, n_cand: int) -> Correspondence:
    n_cams = len(cameras)
    empty_tri = triangulate(np.zeros((n_cams, 0, 2)), cameras)
    return Correspondence(np.zeros((0, n_cams), np.int64), empty_tri, [np.arange(len(d)) for d in dets], n_cand)


def _unmatched(dets, final_obs) -> list[np.ndarray]:
    """Per camera, indices of the detections no accepted point uses."""
    out = []
    for c, d in enumerate(dets):
        used = np.zeros(len(d), bool)
        used[final_obs[final_obs[:, c] >= 0, c]] = True
        out.append(np.flatnonzero(~used))
    return out


def _support_from_other_cameras(X, obs, dets, cameras, radius_px, prior) -> np.ndarray:
    """Step 3 of :func:`match_views`: each candidate point ``X (n, 3)`` takes the nearest detection
    within ``radius_px`` of its projection in every camera it is not seeded from (and faces)."""
    obs = obs.copy()
    for c, cam in enumerate(cameras):
        free = obs[:, c] < 0
        if len(dets[c]) == 0 or not np.any(free):
            continue
        px = cam.project(X[free])
        fin = np.all(np.isfinite(px), axis=1)
        dist, idx = cKDTree(dets[c]).query(np.where(fin[:, None], px, 0.0), distance_upper_bound=radius_px)
        hit = fin & np.isfinite(dist)
        if prior is not None:
            hit &= prior.facing(X[free], cam)
        col = obs[free, c]
        col[hit] = idx[hit]
        obs[free, c] = col
    return obs


def _take(tri: Triangulation, idx) -> Triangulation:
    return Triangulation(
        points=tri.points[idx],
        residuals=tri.residuals[:, idx],
        reprojection_rms=tri.reprojection_rms[idx],
        n_views=tri.n_views[idx],
        covariance=tri.covariance[idx],
        uncertainty=tri.uncertainty[idx],
        sigma_px=tri.sigma_px,
        converged=tri.converged[idx],
    )


def _triangulate_gated(obs, dets, cameras, gate, min_views, prior, sigma_px, passes=2, with_mask=False):
    """Triangulate candidates, dropping views beyond ``gate`` px; keep those with >= min_views.

    Returns ``(triangulation, obs)`` of the kept candidates, and with ``with_mask`` also the
    ``(n,) bool`` mask of the input rows kept."""
    for _ in range(passes):
        tri = _screen(obs, dets, cameras, sigma_px)
        err = np.linalg.norm(tri.residuals, axis=-1).T  # (n, n_cams)
        bad = (obs >= 0) & ~(err <= gate)
        if not np.any(bad):
            break
        # drop only the worst view of each offending candidate, then re-solve
        worst = np.argmax(np.where(obs >= 0, np.nan_to_num(err, nan=np.inf), -1.0), axis=1)
        rows = np.flatnonzero(bad.any(axis=1))
        obs = obs.copy()
        obs[rows, worst[rows]] = -1
    tri = _screen(obs, dets, cameras, sigma_px)
    err = np.linalg.norm(tri.residuals, axis=-1).T
    keep = ((obs >= 0).sum(axis=1) >= min_views) & np.all((obs < 0) | (err <= gate), axis=1)
    keep &= np.all(np.isfinite(tri.points), axis=1)
    if prior is not None:
        keep &= prior.admissible(np.nan_to_num(tri.points))
    if with_mask:
        return _take(tri, np.flatnonzero(keep)), obs[keep], keep
    return _take(tri, np.flatnonzero(keep)), obs[keep]


def _select(obs, tri, dets, cameras, gate, min_views, prior, sigma_px) -> list[np.ndarray]:
    """Best-first selection over the whole candidate set; losers of a conflict are re-scored.

    A loser keeps the views nobody took and is re-triangulated from them; these re-triangulations
    are computed in one batch beforehand for every way a candidate can lose its shared detections
    (:func:`_rescored_table`), and only the rare deeper cases one at a time.
    """
    used = [np.zeros(len(d), bool) for d in dets]
    # candidates whose reprojection RMS is far above the typical one are ranked after all others,
    # whatever their number of views (a ghost that picked up a chance third view must not beat a
    # clean two-view marker)
    typical = float(np.median(tri.reprojection_rms)) if obs.shape[0] else 0.0
    weak_above = max(4.0 * typical, 0.03 * gate)

    def key(nv, rms):
        return (int(rms > weak_above), -nv, rms)

    table = _rescored_table(obs, dets, cameras, gate, min_views, prior, sigma_px)
    heap = [(*key(int((obs[k] >= 0).sum()), float(tri.reprojection_rms[k])), k, tuple(obs[k])) for k in range(obs.shape[0])]
    heapq.heapify(heap)
    chosen: list[np.ndarray] = []
    seen: set[tuple] = set()
    while heap:
        *_, k, obs_key = heapq.heappop(heap)
        o = np.array(obs_key)
        views = np.flatnonzero(o >= 0)
        taken = np.array([used[c][o[c]] for c in views], dtype=bool)
        if not np.any(taken):
            chosen.append(o)
            for c in views:
                used[c][o[c]] = True
            continue
        o2 = o.copy()
        o2[views[taken]] = -1
        if (o2 >= 0).sum() < min_views:
            continue
        key2 = tuple(o2)
        if key2 in seen:
            continue
        seen.add(key2)
        if key2 not in table:
            table.update(_rescored_table(o2[None], dets, cameras, gate, min_views, prior, sigma_px, subsets=False))
        if table[key2] is not None:
            ob2, rms2 = table[key2]
            heapq.heappush(heap, (*key(int((np.array(ob2) >= 0).sum()), rms2), k, ob2))
    return chosen


def _rescored_table(obs, dets, cameras, gate, min_views, prior, sigma_px, subsets: bool = True) -> dict:
    """``{views kept: (views after gating, reprojection RMS) or None}`` for candidates ``obs (n, n_cams)``
    stripped of any combination of their shared detections (``subsets``), or for ``obs`` itself."""
    rows = _losing_subsets(obs, min_views) if subsets else obs
    if rows.shape[0] == 0:
        return {}
    tri, gated, keep = _triangulate_gated(rows, dets, cameras, gate, min_views, prior, sigma_px, with_mask=True)
    table = dict.fromkeys(map(tuple, rows))
    kept = np.flatnonzero(keep)
    for r, g, rms in zip(rows[kept], gated, tri.reprojection_rms):
        table[tuple(r)] = (tuple(g), float(rms))
    return table


def _losing_subsets(obs, min_views) -> np.ndarray:
    """Distinct rows ``obs`` with a non-empty subset of their shared detections removed (>= min_views left)."""
    n, n_cams = obs.shape
    shared = np.zeros(obs.shape, bool)
    for c in range(n_cams):
        sel = obs[:, c] >= 0
        counts = np.bincount(obs[sel, c])
        shared[sel, c] = counts[obs[sel, c]] > 1
    out = []
    for mask in range(1, 2**n_cams):
        drop = np.array([(mask >> c) & 1 for c in range(n_cams)], bool)
        rows = np.flatnonzero(np.all(shared[:, drop], axis=1))
        if rows.size == 0:
            continue
        sub = obs[rows].copy()
        sub[:, drop] = -1
        out.append(sub[(sub >= 0).sum(axis=1) >= min_views])
    return np.unique(np.concatenate(out), axis=0) if out else np.zeros((0, n_cams), np.int64)


def _screen(obs, dets, cameras, sigma_px) -> Triangulation:
    """Triangulation of candidates ``obs (n, n_cams)`` for gating and ranking: no covariance, converged to
    0.1 nm (the accepted points are triangulated in full at the end)."""
    return triangulate(observed_pixels(dets, obs), cameras, sigma_px=sigma_px, tolerance=1e-10, covariance=False)
