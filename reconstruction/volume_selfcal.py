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
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix

from reconstruction.calibration_body import CAMERA_PARAMETERS, camera_parameters, camera_with_parameters
from reconstruction.cameras import Camera
from reconstruction.volume_disparity import (
    DisparityMap,
    _candidates_all_frames,
    consistent_candidates,
    disparity_map,
    loose_candidates,
)

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
