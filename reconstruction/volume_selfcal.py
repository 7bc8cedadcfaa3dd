"""Volume self-calibration on particle images (Wieneke 2008, "Volume self-calibration for 3D particle image
velocimetry", Exp. Fluids 45:549), through the cameras' windows.

A calibration that reprojects each camera's calibration body to a few tenths of a pixel can still be
inconsistent *across* the cameras by pixels inside the measurement volume (a shallow body, extrapolated).
At a high particle density that inconsistency makes the multi-camera matches chance coincidences. The cure
uses the particles themselves:

1. **Loose candidates** (:func:`loose_candidates`): detection pairs along the epipolar curves of every camera
   pair that crosses at a useful angle, within a loose ``epipolar_px``; each pair's mid-point is projected
   into the other cameras and the nearest detection within ``radius_px`` is added; candidates seen by
   ``min_views`` cameras are kept (three by default: on OpenPTV's test_cavity, particles seen by all four
   cameras are rare and four-view candidates mostly chance).
2. **Disparity maps** (:func:`disparity_map`): each candidate is triangulated; per camera and per
   sub-volume (a grid over ``bounds``) its disparities (projected minus detected, px) are accumulated in a
   2-D histogram. True matches pile up at one peak (the local calibration error); ghosts spread out. The
   peak (sub-pixel, Gaussian three-point fit) and its height over the mean background are the diagnosis.
3. **Consistent candidates** (:func:`consistent_candidates`): those whose disparity lies within
   ``keep_px`` of its sub-volume's peak in every camera.
4. **Bundle adjustment** (:func:`bundle_adjust`): the cameras (pose, optionally principal point, k1, k2, the
   window's position and tilt) and the candidates' 3-D points on their pixel residuals, jointly with the
   calibration body's dots (known 3-D points: they fix the gauge and the scale), with a robust loss;
   optionally (``body_sides``) the body as the cameras on its far side see it is offset along its normal by
   a refined distance (a body whose dots are seen from both faces, its file giving one: :func:`far_side`).

:func:`self_calibrate` repeats 1-4 with shrinking tolerances. Pure functions over arrays (metres, pixels as
OpenCV: ``docs/decisions/0002-frames-and-shapes.md``).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix
from scipy.spatial import cKDTree

from reconstruction.calibration_body import CAMERA_PARAMETERS, camera_parameters, camera_with_parameters
from reconstruction.cameras import Camera
from reconstruction.correspondence import epipolar_curve_pairs, observed_pixels
from reconstruction.triangulation import triangulate

__all__ = ["DisparityMap", "SelfCalibration", "loose_candidates", "disparity_map", "consistent_candidates",
           "bundle_adjust", "body_rms", "self_calibrate", "common_view_box", "body_normal", "far_side",
           "FREE_PARAMETERS"]

log = logging.getLogger(__name__)

#: parameter groups :func:`bundle_adjust` can free: names of :data:`reconstruction.calibration_body.CAMERA_PARAMETERS`
FREE_PARAMETERS = {"pose": ("rx", "ry", "rz", "tx", "ty", "tz"), "focal_length": ("f",), "principal_point": ("cx", "cy"),
                   "k1": ("k1",), "k2": ("k2",), "window_offset": ("window_offset",), "k3": ("k3",),
                   "tangential": ("p1", "p2"), "aspect": ("aspect",), "window_tilt": ("window_tilt_a", "window_tilt_b")}
#: shrinking tolerances of :func:`self_calibrate`: (epipolar_px, radius_px, keep_px) per pass
SCHEDULE = ((4.0, 3.0, 1.5), (3.0, 2.0, 1.0), (2.0, 1.5, 0.7), (1.5, 1.0, 0.5))


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


@dataclass(frozen=True)
class SelfCalibration:
    """Result of :func:`self_calibrate`.

    Attributes
    ----------
    cameras : list of Camera
        The corrected cameras.
    maps : list of DisparityMap
        The disparity maps seen by each pass (before its correction), then one after the last correction
        with the last pass's tolerances.
    n_candidates, n_used : list of int
        Candidates formed and kept (consistent with the peaks) per pass.
    particle_rms_px : list of float
        Reprojection RMS of the kept candidates after each pass's bundle adjustment, px.
    body_rms_px : ndarray, shape (n_cameras,)
        Calibration-body RMS per camera after the last pass, px.
    check_map : DisparityMap
        After the correction, with the *first* pass's tolerances: compare with ``maps[0]``. The later
        passes' maps shrink with their tolerances whatever the calibration (a candidate's disparity is
        bounded by them); this one does not.
    message : str
        How many passes ran; a pass with fewer than ``min_consistent`` candidates on the peaks stops the
        schedule there (the cameras of the passes before are returned).
    body_offset_m : float
        Offset of the body along its normal as the far-side cameras see it, m (0 when not refined).
    far_side : ndarray of bool, shape (n_cameras,), or None
        The cameras that see the body from its far side (None: one body for all).
    """

    cameras: list
    maps: list
    n_candidates: list
    n_used: list
    particle_rms_px: list
    body_rms_px: np.ndarray
    check_map: DisparityMap
    message: str = ""
    body_offset_m: float = 0.0
    far_side: np.ndarray | None = None


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


def _free_mask(free: tuple[str, ...]) -> np.ndarray:
    unknown = set(free) - set(FREE_PARAMETERS)
    if unknown:
        raise ValueError(f"free must name groups among {sorted(FREE_PARAMETERS)}; got {sorted(unknown)}")
    names = {n for g in free for n in FREE_PARAMETERS[g]}
    return np.array([n in names for n in CAMERA_PARAMETERS])


def _sparsity(seen: np.ndarray, body_seen: np.ndarray, n_par: int, far: np.ndarray | None = None) -> lil_matrix:
    """Jacobian sparsity: rows per camera (particle residuals, then body residuals), columns (camera
    parameters, then 3 per point, then the body offset of the far side when ``far`` (n_cameras,) bool is given)."""
    n_cams, n_pts = seen.shape
    n_rows = 2 * int(seen.sum() + body_seen.sum())
    n_off = 0 if far is None else 1
    S = lil_matrix((n_rows, n_cams * n_par + 3 * n_pts + n_off), dtype=np.int8)
    r = 0
    for c in range(n_cams):
        pts = np.flatnonzero(seen[c])
        m = 2 * (len(pts) + int(body_seen[c].sum()))
        S[r:r + m, c * n_par:(c + 1) * n_par] = 1
        for k in range(3):
            cols = n_cams * n_par + 3 * pts + k
            S[r + 2 * np.arange(len(pts)), cols] = 1
            S[r + 2 * np.arange(len(pts)) + 1, cols] = 1
        if n_off and far[c]:
            S[r + 2 * len(pts):r + m, -1] = 1
        r += m
    return S


def bundle_adjust(cameras: list[Camera], pixels: np.ndarray, points: np.ndarray, body: np.ndarray,
                  body_pixels: np.ndarray, *, free: tuple[str, ...] = ("pose",), f_scale_px: float = 0.5,
                  body_weight=1.0, max_nfev: int = 30, far: np.ndarray | None = None,
                  body_offset_m: float = 0.0) -> tuple[list[Camera], np.ndarray, float, float]:
    """Refine the cameras and the particles' 3-D points on their pixel residuals, jointly with the
    calibration body (step 4 of the module docstring).

    Parameters
    ----------
    cameras : list of Camera
    pixels : ndarray, shape (n_cameras, n, 2)
        Detected pixels of each particle, NaN where not seen.
    points : ndarray, shape (n, 3)
        Initial 3-D points, m.
    body : ndarray, shape (n_body, 3)
        Calibration body's points, m (they fix the gauge and the scale).
    body_pixels : ndarray, shape (n_cameras, n_body, 2)
        Their dots per camera, NaN where not seen (or rejected).
    free : tuple of str
        Parameter groups refined per camera (keys of :data:`FREE_PARAMETERS`).
    f_scale_px : float
        Soft-L1 loss scale, px: residuals beyond it count linearly.
    body_weight : float or ndarray, shape (n_cameras,)
        Weight of a body residual relative to a particle residual (one for all cameras, or per camera).
    far : ndarray of bool, shape (n_cameras,), optional
        Cameras that see the body from its far side (:func:`far_side`): for them the body's points lie
        ``body_offset_m`` further along its normal (:func:`body_normal`), an offset refined here (a body
        whose dots are seen from both faces, the file giving one face). None: one body for all.
    body_offset_m : float
        Initial offset, m.

    Returns
    -------
    cameras : list of Camera
    points : ndarray, shape (n, 3)
    particle_rms_px : float
        RMS (norm) of the particle residuals after the fit, px.
    body_offset_m : float
        The refined offset (the initial one when ``far`` is None or selects no camera), m.
    """
    pixels, points = np.asarray(pixels, float), np.asarray(points, float)
    body, body_pixels = np.asarray(body, float), np.asarray(body_pixels, float)
    n_cams = len(cameras)
    if pixels.shape != (n_cams, len(points), 2):
        raise ValueError(f"pixels must have shape (n_cameras={n_cams}, n_points={len(points)}, 2); got {pixels.shape}")
    if body_pixels.shape != (n_cams, len(body), 2):
        raise ValueError(f"body_pixels must have shape (n_cameras={n_cams}, n_body={len(body)}, 2); "
                         f"got {body_pixels.shape}")
    mask = _free_mask(tuple(free))
    n_par = int(mask.sum())
    weights = np.asarray(body_weight, float)
    weights = np.full(n_cams, float(weights)) if weights.ndim == 0 else weights
    if weights.shape != (n_cams,) or not np.all(np.isfinite(weights) & (weights >= 0)):
        raise ValueError(f"body_weight must be one weight >= 0 or one per camera ({n_cams}); got {body_weight!r}")
    seen = np.all(np.isfinite(pixels), axis=-1)
    bseen = np.all(np.isfinite(body_pixels), axis=-1)
    if np.any(bseen.sum(axis=1) < 4):
        raise ValueError(f"every camera needs >= 4 body points to fix the gauge; got {bseen.sum(axis=1).tolist()}")
    if far is not None and np.shape(far) != (n_cams,):
        raise ValueError(f"far must be one bool per camera ({n_cams}); got shape {np.shape(far)}")
    far = None if far is None or not np.any(far) else np.asarray(far, bool)
    n_x = n_cams * n_par + 3 * len(points)

    def unpack(x):
        par = x[:n_cams * n_par].reshape(n_cams, n_par)
        cams = [camera_with_parameters(par[c], cameras[c], mask) for c in range(n_cams)]
        return cams, x[n_cams * n_par:n_x].reshape(-1, 3), (x[n_x] if far is not None else body_offset_m)

    def fun(x):
        cams, X, off = unpack(x)
        bodies = _body_as_seen(body, n_cams, far, off)
        parts = []
        for c, cam in enumerate(cams):
            parts.append((cam.project(X[seen[c]]) - pixels[c, seen[c]]).ravel())
            parts.append(weights[c] * (cam.project(bodies[c][bseen[c]]) - body_pixels[c, bseen[c]]).ravel())
        return np.nan_to_num(np.concatenate(parts), nan=1e3)

    x0 = np.concatenate([np.concatenate([camera_parameters(c)[mask] for c in cameras]), points.ravel(),
                         [body_offset_m] if far is not None else []])
    sol = least_squares(fun, x0, jac_sparsity=_sparsity(seen, bseen, n_par, far), loss="soft_l1", f_scale=f_scale_px,
                        x_scale="jac", method="trf", max_nfev=max_nfev)
    cams, X, off = unpack(sol.x)
    res = np.concatenate([cams[c].project(X[seen[c]]) - pixels[c, seen[c]] for c in range(n_cams)])
    rms = float(np.sqrt(np.nanmean(np.sum(res**2, axis=1)))) if len(res) else float("nan")
    log.info("bundle adjustment: %d particles, %d evaluations, particle RMS %.3f px, body offset %.3f mm",
             len(points), sol.nfev, rms, 1e3 * off)
    return cams, X, rms, float(off)


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


def body_rms(cameras: list[Camera], body: np.ndarray, body_pixels: np.ndarray, far: np.ndarray | None = None,
             body_offset_m: float = 0.0) -> np.ndarray:
    """Calibration-body reprojection RMS (norm) per camera ``(n_cameras,)``, px; the cameras ``far`` (bool
    (n_cameras,)) see the body ``body_offset_m`` further along its normal (:func:`bundle_adjust`)."""
    out = []
    bodies = _body_as_seen(body, len(cameras), far, body_offset_m)
    for c, cam in enumerate(cameras):
        ok = np.all(np.isfinite(body_pixels[c]), axis=1)
        out.append(np.sqrt(np.mean(np.sum((cam.project(bodies[c][ok]) - body_pixels[c, ok]) ** 2, axis=1))))
    return np.array(out)


def _body_as_seen(body: np.ndarray, n_cameras: int, far: np.ndarray | None, offset_m: float) -> np.ndarray:
    """The body's points ``(n_body, 3)`` as each camera sees them, ``(n_cameras, n_body, 3)``: the cameras ``far``
    (bool (n_cameras,), None = none) see them ``offset_m`` further along :func:`body_normal`."""
    out = np.repeat(np.asarray(body, float)[None], n_cameras, axis=0)
    if far is not None:
        out[np.asarray(far, bool)] += offset_m * body_normal(body)
    return out


def body_normal(body: np.ndarray) -> np.ndarray:
    """Unit normal ``(3,)`` of the body's points ``(n, 3)``: their direction of least extent (sign: +z first,
    else +y, else +x)."""
    P = np.asarray(body, float)
    n = np.linalg.svd(P - P.mean(axis=0), full_matrices=False)[2][-1]
    k = int(np.flatnonzero(np.abs(n) > 1e-9)[-1])
    return n if n[k] > 0 else -n


def far_side(cameras: list[Camera], body: np.ndarray, body_pixels: np.ndarray | None = None) -> np.ndarray:
    """Cameras ``(n_cameras,)`` bool looking at the body from its far side (the sign of their optical axis
    along :func:`body_normal`). The near side, whose view the body's coordinates describe, is the one whose
    cameras see the most of its points in ``body_pixels`` ``(n_cameras, n_body, 2)`` (the face with every
    dot; from behind some are hidden); without ``body_pixels``, or on a tie, the first camera's side."""
    n = body_normal(body)
    side = np.array([np.sign(c.R[2] @ n) for c in cameras])
    near = side[0]
    if body_pixels is not None:
        seen = np.all(np.isfinite(np.asarray(body_pixels, float)), axis=-1).sum(axis=1)
        count = {v: int(seen[side == v].sum()) for v in np.unique(side)}
        best = max(count.values())
        near = side[0] if count[side[0]] == best else next(v for v, k in count.items() if k == best)
    return side != near


def self_calibrate(frames: list[list[np.ndarray]], cameras: list[Camera], bounds, body: np.ndarray,
                   body_pixels: np.ndarray, *, schedule=SCHEDULE, grid=(2, 2, 2), free: tuple[str, ...] = ("pose",),
                   min_views: int = 3, bin_px: float = 0.2, f_scale_px: float = 0.5,
                   body_weight=1.0, min_consistent: int = 20, body_sides: bool = False,
                   progress: Callable[[int, int, str], None] | None = None) -> SelfCalibration:
    """Volume self-calibration (module docstring): passes of loose candidates, disparity maps, consistent
    candidates and a bundle adjustment with the body, with the tolerances of ``schedule``.

    Parameters
    ----------
    frames : list of list of ndarray, shape (n_i, 2)
        Per frame, the particle detections of every camera (distorted px).
    cameras : list of Camera
        The calibration to correct (e.g. from the calibration body).
    bounds : (ndarray (3,), ndarray (3,))
        World box of the measurement volume, m.
    body, body_pixels : ndarray, shapes (n_body, 3) and (n_cameras, n_body, 2)
        Calibration body's points (m) and their dots in each camera (px, NaN = unseen).
    schedule : sequence of (epipolar_px, radius_px, keep_px)
        Candidate tolerances (:func:`loose_candidates`) and the distance to the disparity peak a kept
        candidate may have, per pass.
    grid : tuple of int
        Sub-volumes per axis of the disparity maps.
    free : tuple of str
        Camera parameter groups refined (:data:`FREE_PARAMETERS`).
    min_views : int
        Views a candidate needs.
    body_weight : float or ndarray, shape (n_cameras,)
        Weight of a body residual relative to a particle residual (:func:`bundle_adjust`).
    min_consistent : int
        Fewer candidates on the disparity peaks stop the schedule (see ``SelfCalibration.message``).
    body_sides : bool
        When cameras look at the body from both sides (:func:`far_side`), the body as the far side sees it
        is offset along its normal by a refined distance (``SelfCalibration.body_offset_m``; test_cavity:
        see docs/validation/reconstruction.md). False: one body for all cameras.
    progress : callable (done, total, what) -> None, optional
        Called after each step (a pass, the two closing disparity maps): ``total`` = len(schedule) + 2.
    """
    if not len(schedule):
        raise ValueError("schedule must hold at least one (epipolar_px, radius_px, keep_px) pass; got none")
    cams = list(cameras)
    maps, n_cand, n_used, rms = [], [], [], []
    message = f"{len(schedule)} passes"
    total = len(schedule) + 2
    far = far_side(cams, body, body_pixels) if body_sides else None
    far = far if far is not None and np.any(far) else None
    offset = 0.0
    tick = progress if progress is not None else (lambda done, total, what: None)
    for epi, rad, keep in schedule:
        pixels, X, res = _candidates_all_frames(frames, cams, bounds, epi, rad, min_views)
        dmap = disparity_map(res, X, bounds, grid=grid, half_width_px=max(epi, rad) + 1.0, bin_px=bin_px)
        ok = consistent_candidates(res, X, dmap, bounds, keep)
        log.info("self-calibration pass (%.1f, %.1f, %.1f px): %d candidates, %d consistent, peaks %.2f px RMS "
                 "(max %.2f), height %.1f x background", epi, rad, keep, len(X), ok.sum(), dmap.rms_peak_offset_px,
                 dmap.max_peak_offset_px, np.nanmedian(dmap.peak_height))
        maps.append(dmap)
        n_cand.append(int(len(X)))
        n_used.append(int(ok.sum()))
        if ok.sum() < min_consistent:
            message = (f"stopped before pass {len(rms) + 1} of {len(schedule)}: only {int(ok.sum())} of {len(X)} "
                       f"candidates agree with the disparity peaks at tolerances {(epi, rad, keep)} px")
            log.warning("self_calibrate: %s", message)
            break
        cams, _, r, offset = bundle_adjust(cams, pixels[:, ok], X[ok], body, body_pixels, free=free,
                                           f_scale_px=f_scale_px, body_weight=body_weight, far=far,
                                           body_offset_m=offset)
        rms.append(r)
        tick(len(rms), total, f"pass {len(rms)}: particle RMS {r:.2f} px")
    epi, rad, _ = schedule[len(rms) - 1] if rms else schedule[0]
    _, X, res = _candidates_all_frames(frames, cams, bounds, epi, rad, min_views)
    maps.append(disparity_map(res, X, bounds, grid=grid, half_width_px=max(epi, rad) + 1.0, bin_px=bin_px))
    tick(total - 1, total, "disparity after the last pass")
    epi, rad, _ = schedule[0]
    _, X, res = _candidates_all_frames(frames, cams, bounds, epi, rad, min_views)
    check = disparity_map(res, X, bounds, grid=grid, half_width_px=max(epi, rad) + 1.0, bin_px=bin_px)
    tick(total, total, "disparity check at the first pass's tolerances")
    return SelfCalibration(cams, maps, n_cand, n_used, rms, body_rms(cams, body, body_pixels, far, offset), check,
                           message, offset, far)


def common_view_box(cameras: list[Camera], depth_range, *, min_views: int = 3, axis: int = 2,
                    step: float = 2e-3) -> tuple[np.ndarray, np.ndarray]:
    """World box of the points inside the images of at least ``min_views`` cameras between two planes.

    The cameras' image borders are cast (through their windows) onto the planes ``axis = depth_range[0]``
    and ``depth_range[1]``; a lattice of ``step`` over the box of those footprints is kept where
    ``min_views`` cameras see it. A default measurement volume for :func:`self_calibrate` when only the
    depth range is known (e.g. OpenPTV's ``criteria.par``).

    Parameters
    ----------
    cameras : list of Camera
    depth_range : (float, float)
        Range along ``axis``, m.
    min_views : int
    axis : int
        World axis of the depth (0, 1 or 2).
    step : float
        Lattice spacing, m.

    Returns
    -------
    (ndarray (3,), ndarray (3,))
        Lower and upper corners, m.
    """
    z0, z1 = sorted(float(v) for v in depth_range)
    if not z1 > z0:
        raise ValueError(f"depth_range must span a non-empty range, m; got {tuple(depth_range)}")
    if not 1 <= min_views <= len(cameras):
        raise ValueError(f"min_views must be in [1, {len(cameras)}]; got {min_views}")
    feet = []
    for cam in cameras:
        W, H = cam.image_size
        u = np.linspace(0.0, 1.0, 9)
        border = np.concatenate([np.c_[u * (W - 1), np.zeros(9)], np.c_[u * (W - 1), np.full(9, H - 1.0)],
                                 np.c_[np.zeros(9), u * (H - 1)], np.c_[np.full(9, W - 1.0), u * (H - 1)]])
        o, d = cam.rays(border)
        for z in (z0, z1):
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (z - o[:, axis]) / d[:, axis]
            feet.append((o + t[:, None] * d)[np.isfinite(t) & (t > 0)])
    feet = np.concatenate(feet)
    lo, hi = feet.min(axis=0), feet.max(axis=0)
    lo[axis], hi[axis] = z0, z1
    axes = [np.arange(lo[k], hi[k] + 0.5 * step, step) for k in range(3)]
    X = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    views = np.zeros(len(X), np.int64)
    for cam in cameras:
        px = cam.project(X)
        W, H = cam.image_size
        with np.errstate(invalid="ignore"):
            views += np.all(np.isfinite(px), axis=1) & (px[:, 0] >= 0) & (px[:, 0] <= W - 1) & (px[:, 1] >= 0) & \
                (px[:, 1] <= H - 1)
    seen = X[views >= min_views]
    if not len(seen):
        raise ValueError(f"no point between the planes {axis=} = {z0:.4g}..{z1:.4g} m is seen by {min_views} cameras")
    return seen.min(axis=0), seen.max(axis=0)
