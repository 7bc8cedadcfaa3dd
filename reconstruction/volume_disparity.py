"""Volume self-calibration, steps 1-3 (Wieneke 2008): loose multi-view candidates along the epipolar curves,
disparity maps per camera and sub-volume (:class:`DisparityMap`), and the candidates consistent with them. Used by
:func:`reconstruction.volume_selfcal.self_calibrate`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter
from scipy.spatial import cKDTree

from reconstruction.cameras import Camera
from reconstruction.correspondence import observed_pixels
from reconstruction.epipolar import epipolar_curve_pairs
from reconstruction.triangulation import triangulate

__all__ = ["DisparityMap", "consistent_candidates", "disparity_map", "loose_candidates"]


@dataclass(frozen=True)
class DisparityMap:
    """Per camera and sub-volume, the peak of the candidates' disparities (projected minus detected).

    Attributes
    ----------
    peak_px : ndarray, shape (n_cameras, n_sub, 2)
        Sub-pixel position of the peak, px (NaN where a sub-volume has too few candidates).
    peak_height : ndarray, shape (n_cameras, n_sub)
        Smoothed count at the peak divided by the mean count of the histogram (1 = no peak).
    counts : ndarray of int, shape (n_cameras, n_sub)
        Candidates seen by the camera in the sub-volume.
    grid : tuple of int
        Sub-volumes per axis (x, y, z).
    bin_px : float
        Histogram bin, px.
    """

    peak_px: np.ndarray
    peak_height: np.ndarray
    counts: np.ndarray
    grid: tuple
    bin_px: float

    @property
    def max_peak_offset_px(self) -> float:
        """Largest peak distance from zero over cameras and sub-volumes, px."""
        n = np.linalg.norm(self.peak_px, axis=-1)
        return float(np.nanmax(n)) if np.any(np.isfinite(n)) else float("nan")

    @property
    def rms_peak_offset_px(self) -> float:
        """RMS of the peak distances from zero, weighted by the counts, px."""
        n2 = np.sum(self.peak_px**2, axis=-1)
        ok = np.isfinite(n2)
        return float(np.sqrt(np.sum(n2[ok] * self.counts[ok]) / max(np.sum(self.counts[ok]), 1)))


def _crossing_deg(a: Camera, b: Camera) -> float:
    ang = np.degrees(np.arccos(np.clip(a.R[2] @ b.R[2], -1.0, 1.0)))
    return float(min(ang, 180.0 - ang))


def loose_candidates(detections: list[np.ndarray], cameras: list[Camera], bounds, *, epipolar_px: float = 4.0,
                     radius_px: float = 3.0, min_views: int = 3, min_crossing_deg: float = 15.0) -> np.ndarray:
    """Candidate matches with loose tolerances (step 1 of the module docstring).

    Parameters
    ----------
    detections : list of ndarray, shape (n_i, 2)
        Distorted pixel centres per camera, px.
    cameras : list of Camera
    bounds : (ndarray (3,), ndarray (3,))
        World box of the measurement volume, m.
    epipolar_px : float
        Gate on the epipolar curve of the seeding pair, px.
    radius_px : float
        Radius around the projected mid-point in the other cameras, px.
    min_views : int
        Views a candidate needs.
    min_crossing_deg : float
        Camera pairs whose rays cross at less than this (axes nearly parallel or opposite) seed nothing.

    Returns
    -------
    ndarray of int, shape (n_candidates, n_cameras)
        Detection index per camera, -1 = not seen; unique rows.
    """
    if len(detections) != len(cameras):
        raise ValueError(f"detections must have one array per camera ({len(cameras)}); got {len(detections)}")
    if not 2 <= min_views <= len(cameras):
        raise ValueError(f"min_views must be in [2, {len(cameras)}]; got {min_views}")
    dets = [np.asarray(d, float).reshape(-1, 2) for d in detections]
    lo, hi = (np.asarray(b, float) for b in bounds)
    rays = [cam.rays(d) for cam, d in zip(cameras, dets)]
    trees = [cKDTree(d) if len(d) else None for d in dets]
    n = len(cameras)
    rows = []
    for i in range(n):
        for j in range(i + 1, n):
            if _crossing_deg(cameras[i], cameras[j]) < min_crossing_deg or not (len(dets[i]) and len(dets[j])):
                continue
            a, b, X, _ = epipolar_curve_pairs(i, j, dets, cameras, rays, epipolar_px, (lo, hi))
            inside = np.all(np.isfinite(X) & (X >= lo) & (X <= hi), axis=1)
            obs = np.full((int(inside.sum()), n), -1, np.int64)
            obs[:, i], obs[:, j] = a[inside], b[inside]
            for k in set(range(n)) - {i, j}:
                if trees[k] is None:
                    continue
                px = cameras[k].project(X[inside])
                fin = np.all(np.isfinite(px), axis=1)
                d, idx = trees[k].query(np.where(fin[:, None], px, 0.0), distance_upper_bound=radius_px)
                hit = fin & np.isfinite(d)
                obs[hit, k] = idx[hit]
            rows.append(obs[(obs >= 0).sum(axis=1) >= min_views])
    if not rows:
        return np.zeros((0, n), np.int64)
    return np.unique(np.concatenate(rows), axis=0)


def _subvolume(points: np.ndarray, bounds, grid) -> np.ndarray:
    """Flat sub-volume index ``(n,)`` of each point ``(n, 3)`` in the ``grid`` over ``bounds``; -1 outside."""
    lo, hi = (np.asarray(b, float) for b in bounds)
    g = np.asarray(grid)
    with np.errstate(invalid="ignore"):
        cell = np.floor((points - lo) / (hi - lo) * g).astype(np.int64, copy=False) if len(points) else \
            np.zeros((0, 3), np.int64)
    ok = np.all(np.isfinite(points), axis=1) & np.all((cell >= 0) & (cell < g), axis=1)
    flat = (cell[:, 0] * g[1] + cell[:, 1]) * g[2] + cell[:, 2]
    return np.where(ok, flat, -1)


def _histogram_peak(d: np.ndarray, half_width: float, bin_px: float) -> tuple[np.ndarray, float]:
    """Peak ``(2,)`` px and relative height of the smoothed 2-D histogram of disparities ``d (m, 2)``."""
    nb = int(np.ceil(2 * half_width / bin_px))
    edges = -half_width + bin_px * np.arange(nb + 1)
    h, _, _ = np.histogram2d(d[:, 0], d[:, 1], bins=(edges, edges))
    h = gaussian_filter(h, 1.0, mode="constant")
    i, j = np.unravel_index(np.argmax(h), h.shape)
    centre = 0.5 * (edges[:-1] + edges[1:])
    off = []
    for line, k in ((h[:, j], i), (h[i, :], j)):
        if 0 < k < nb - 1 and np.all(line[k - 1:k + 2] > 0):
            lm, l0, lp = np.log(line[k - 1:k + 2])
            den = lm - 2 * l0 + lp
            off.append(0.5 * (lm - lp) / den if den < 0 else 0.0)
        else:
            off.append(0.0)
    peak = np.array([centre[i] + bin_px * np.clip(off[0], -1, 1), centre[j] + bin_px * np.clip(off[1], -1, 1)])
    return peak, float(h[i, j] / max(h.mean(), 1e-12))


def disparity_map(residuals: np.ndarray, points: np.ndarray, bounds, *, grid=(2, 2, 2), half_width_px: float = 4.0,
                  bin_px: float = 0.2, min_count: int = 30) -> DisparityMap:
    """Disparity maps (step 2 of the module docstring).

    Parameters
    ----------
    residuals : ndarray, shape (n_cameras, n, 2)
        Projected minus detected pixels of the triangulated candidates, px; NaN where not seen.
    points : ndarray, shape (n, 3)
        The triangulated candidates, m.
    bounds : (ndarray (3,), ndarray (3,))
        World box, m; split into ``grid`` sub-volumes.
    half_width_px, bin_px : float
        Histogram extent (+-) and bin, px.
    min_count : int
        Fewer candidates in a sub-volume and camera give a NaN peak.
    """
    residuals = np.asarray(residuals, float)
    if residuals.ndim != 3 or residuals.shape[1:] != (len(points), 2):
        raise ValueError(f"residuals must have shape (n_cameras, n_points={len(points)}, 2); got {residuals.shape}")
    sub = _subvolume(np.asarray(points, float), bounds, grid)
    n_sub = int(np.prod(grid))
    peaks = np.full((residuals.shape[0], n_sub, 2), np.nan)
    height = np.full((residuals.shape[0], n_sub), np.nan)
    counts = np.zeros((residuals.shape[0], n_sub), np.int64)
    for c in range(residuals.shape[0]):
        seen = np.all(np.isfinite(residuals[c]), axis=1)
        for s in range(n_sub):
            d = residuals[c, seen & (sub == s)]
            counts[c, s] = len(d)
            if len(d) >= min_count:
                peaks[c, s], height[c, s] = _histogram_peak(d, half_width_px, bin_px)
    return DisparityMap(peaks, height, counts, tuple(int(g) for g in grid), float(bin_px))


def consistent_candidates(residuals: np.ndarray, points: np.ndarray, dmap: DisparityMap, bounds,
                          keep_px: float) -> np.ndarray:
    """Candidates ``(n,)`` bool whose disparity is within ``keep_px`` of its sub-volume's peak in every camera
    that sees it (step 3); candidates in sub-volumes without a peak are dropped."""
    sub = _subvolume(np.asarray(points, float), bounds, dmap.grid)
    peak = np.where(sub[None, :, None] >= 0, dmap.peak_px[:, np.maximum(sub, 0)], np.nan)  # (n_cams, n, 2)
    seen = np.all(np.isfinite(residuals), axis=-1)
    with np.errstate(invalid="ignore"):
        near = np.linalg.norm(residuals - peak, axis=-1) <= keep_px
    return (sub >= 0) & np.all(near | ~seen, axis=0)


def _candidates_all_frames(frames, cameras, bounds, epipolar_px, radius_px, min_views):
    """Pixels ``(n_cams, n, 2)`` of the loose candidates of every frame, their triangulated points ``(n, 3)``
    and residuals ``(n_cams, n, 2)``."""
    px = []
    for dets in frames:
        obs = loose_candidates(dets, cameras, bounds, epipolar_px=epipolar_px, radius_px=radius_px,
                               min_views=min_views)
        px.append(observed_pixels([np.asarray(d, float).reshape(-1, 2) for d in dets], obs))
    pixels = np.concatenate(px, axis=1)
    tri = triangulate(pixels, cameras, covariance=False)
    return pixels, tri.points, tri.residuals
