"""Multi-camera particle matching over time: a true match persists, a chance one does not.

At a high particle density a single frame cannot tell a true three-camera match from a chance coincidence
along the epipolar curves (``docs/validation/reconstruction.md``, "Real data"). Consecutive frames of the same particles
can: a true match is a 3-D point whose track continues smoothly through the neighbouring frames (small
displacement, consistent in every camera). A chance match is made of detections of unrelated particles; when
they move coherently (a smooth flow, small steps) it persists too, but its reprojection residuals change as
they move apart, whereas a true match's residual is the local calibration error, constant over a small step.
A chance match of particles that do not move persists unchanged: static chains prove nothing.

:func:`temporal_match` works on per-frame candidates with loose gates:

1. **Candidates** (:func:`frame_candidates`): per frame, detection tuples seen by >= ``min_views``
   cameras along the epipolar curves through the windows (``volume_selfcal.loose_candidates``),
   triangulated; those whose largest reprojection residual exceeds ``max_residual_px`` are dropped.
2. **Links** (:func:`link_frames`): candidates of consecutive frames whose 3-D points are within
   ``max_step_m``.
3. **Smooth triplets** (:func:`smooth_triplets`): chains ``a -> b -> c`` over three consecutive frames
   whose second difference ``|X_c - 2 X_b + X_a|`` (the acceleration times dt^2) is at most
   ``max_accel_m``, that move by at least ``min_motion_m`` and whose residual changes by at most
   ``max_residual_change_px`` from frame to frame in every camera. A candidate in at least one such triplet
   is *supported*; its score is the number of triplets it belongs to (a track through 5 frames gives its
   middle candidate 3; :func:`persistence_support`).
4. **Selection** (:func:`select_per_frame`): per frame, supported candidates in order of score, then
   views, then reprojection RMS; each detection is used once.
5. **Recovery** (:func:`recover_from_tracks`): the selected points are chained over the
   frames; where a chain has no point in a neighbouring frame, its position there is predicted (constant
   velocity), projected into every camera and the nearest unused detection within ``recover_radius_px``
   taken; >= ``min_views`` views within ``max_residual_px`` of their triangulation and within ``max_accel_m``
   of the prediction are added. The chain vouches for the match, so the single-frame ambiguity no longer matters.

:func:`match_over_time` runs it once with loose gates, fits a smooth per-camera map of the residuals of those
matches over the image (:func:`fit_pixel_correction`: the calibration error the camera model leaves), moves the
detections by it (:func:`apply_pixel_correction`) and matches again with the final gates.

Pure functions over arrays; metres and pixels as OpenCV (``docs/decisions/0002-frames-and-shapes.md``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from reconstruction.cameras import Camera
from reconstruction.correspondence import observed_pixels
from reconstruction.triangulation import triangulate
from reconstruction.volume_selfcal import loose_candidates

__all__ = ["FrameCandidates", "TemporalMatch", "frame_candidates", "link_frames", "smooth_triplets",
           "persistence_support", "select_greedy", "select_per_frame",
           "recover_from_tracks", "temporal_match", "fit_pixel_correction",
           "apply_pixel_correction", "match_over_time"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FrameCandidates:
    """Candidate matches of one frame.

    Attributes
    ----------
    observations : ndarray of int, shape (n, n_cameras)
        Detection index per camera, -1 = not seen.
    points : ndarray, shape (n, 3)
        Triangulated points, m.
    rms : ndarray, shape (n,)
        Reprojection RMS over the observing cameras (norm of the residual), px.
    residuals : ndarray, shape (n_cameras, n, 2)
        Reprojection residuals (projected - detected), px; NaN where not seen.
    """

    observations: np.ndarray
    points: np.ndarray
    rms: np.ndarray
    residuals: np.ndarray


@dataclass(frozen=True)
class TemporalMatch:
    """Result of :func:`temporal_match`.

    Attributes
    ----------
    observations : list of ndarray of int, shape (m_t, n_cameras)
        Per frame, the accepted matches: detection index per camera, -1 = not seen.
    points : list of ndarray, shape (m_t, 3)
        Their triangulated points, m.
    rms : list of ndarray, shape (m_t,)
        Their reprojection RMS, px.
    support : list of ndarray of int, shape (m_t,)
        Smooth triplets each belongs to (0 for a match added by the recovery).
    n_candidates, n_supported, n_recovered : list of int
        Per frame: candidates, candidates in a smooth triplet, matches added by the recovery.
    """

    observations: list
    points: list
    rms: list
    support: list
    n_candidates: list
    n_supported: list
    n_recovered: list


def _checked_frames(frames, cameras) -> list[list[np.ndarray]]:
    if len(frames) < 3:
        raise ValueError(f"frames must hold at least 3 consecutive frames (a smooth triplet); got {len(frames)}")
    out = []
    for t, dets in enumerate(frames):
        if len(dets) != len(cameras):
            raise ValueError(f"frames[{t}] must have one detection array per camera ({len(cameras)}); got {len(dets)}")
        out.append([np.asarray(d, float).reshape(-1, 2) for d in dets])
    return out


def frame_candidates(detections: list[np.ndarray], cameras: list[Camera], bounds, *, epipolar_px: float = 2.0,
                     radius_px: float = 1.5, max_residual_px: float = 1.5, min_views: int = 3) -> FrameCandidates:
    """Step 1: loose candidates of one frame, triangulated, with their largest residual within ``max_residual_px``.

    Parameters
    ----------
    detections : list of ndarray, shape (n_i, 2)
        Distorted pixel centres per camera, px.
    cameras : list of Camera
    bounds : (ndarray (3,), ndarray (3,))
        World box of the measurement volume, m.
    epipolar_px, radius_px : float
        Gates of :func:`reconstruction.volume_selfcal.loose_candidates`, px.
    max_residual_px : float
        Largest reprojection residual (norm) a candidate may have in any camera, px.
    min_views : int
    """
    obs = loose_candidates(detections, cameras, bounds, epipolar_px=epipolar_px, radius_px=radius_px,
                           min_views=min_views)
    if len(obs) == 0:
        return FrameCandidates(obs, np.zeros((0, 3)), np.zeros(0), np.zeros((len(cameras), 0, 2)))
    tri = triangulate(observed_pixels(detections, obs), cameras, covariance=False)
    worst = np.nanmax(np.linalg.norm(tri.residuals, axis=-1), axis=0)
    lo, hi = (np.asarray(b, float) for b in bounds)
    ok = (worst <= max_residual_px) & np.all((tri.points >= lo) & (tri.points <= hi), axis=1)
    return FrameCandidates(obs[ok], tri.points[ok], tri.reprojection_rms[ok], tri.residuals[:, ok])


def link_frames(points_a: np.ndarray, points_b: np.ndarray, max_step_m: float) -> np.ndarray:
    """Step 2: pairs of points of two consecutive frames within ``max_step_m`` (m).

    ``points_a`` ``(n_a, 3)``, ``points_b`` ``(n_b, 3)`` -> ndarray of int ``(n_links, 2)``: (index in a, index in b).
    """
    if len(points_a) == 0 or len(points_b) == 0:
        return np.zeros((0, 2), np.int64)
    m = cKDTree(points_a).sparse_distance_matrix(cKDTree(points_b), max_step_m, output_type="ndarray")
    return np.stack([m["i"], m["j"]], axis=1).astype(np.int64)


def smooth_triplets(points: list[np.ndarray], links: list[np.ndarray], max_accel_m: float,
                    residuals: list[np.ndarray] | None = None, max_residual_change_px: float = np.inf,
                    min_motion_m: float = 0.0) -> np.ndarray:
    """Step 3: chains over three consecutive frames with a small second difference.

    Parameters
    ----------
    points : list of ndarray, shape (n_t, 3)
        Candidate points per frame, m.
    links : list of ndarray of int, shape (l_t, 2)
        ``links[t]``: pairs (index in frame t, index in frame t + 1), from :func:`link_frames`.
    max_accel_m : float
        Largest ``|X_c - 2 X_b + X_a|``, m.
    residuals : list of ndarray, shape (n_cameras, n_t, 2), optional
        Reprojection residuals of the candidates, px (NaN where a camera does not see one). With them, in
        every camera that sees all three, the residual may change by at most ``max_residual_change_px``
        from one frame to the next: a true match's residual is the local calibration error (constant
        over a small displacement) plus detection noise; a chance match's changes as the unrelated
        particles it is made of move apart.
    max_residual_change_px : float
    min_motion_m : float
        Smallest ``|X_c - X_a|``, m: a chance match made of particles that do not move persists as well
        as a true one, so a static chain proves nothing (0 = accept static chains).

    Returns
    -------
    ndarray of int, shape (n_triplets, 4)
        (middle frame t, index in t - 1, index in t, index in t + 1).
    """
    out = [np.zeros((0, 4), np.int64)]
    for t in range(1, len(points) - 1):
        before, after = links[t - 1], links[t]
        if len(before) == 0 or len(after) == 0:
            continue
        order = np.argsort(after[:, 0], kind="stable")
        keys = after[order, 0]
        lo = np.searchsorted(keys, before[:, 1], side="left")
        hi = np.searchsorted(keys, before[:, 1], side="right")
        n = hi - lo
        rep = np.repeat(np.arange(len(before)), n)
        pos = np.repeat(lo - np.cumsum(n) + n, n) + np.arange(n.sum())
        a, b, c = before[rep, 0], before[rep, 1], after[order[pos], 1]
        acc = np.linalg.norm(points[t + 1][c] - 2.0 * points[t][b] + points[t - 1][a], axis=1)
        ok = (acc <= max_accel_m) & (np.linalg.norm(points[t + 1][c] - points[t - 1][a], axis=1) >= min_motion_m)
        if residuals is not None:
            with np.errstate(invalid="ignore"):
                r0, r1, r2 = residuals[t - 1][:, a], residuals[t][:, b], residuals[t + 1][:, c]
                change = np.maximum(np.linalg.norm(r1 - r0, axis=-1), np.linalg.norm(r2 - r1, axis=-1))
            ok &= ~np.any(change > max_residual_change_px, axis=0)  # NaN (camera not in all three) passes
        out.append(np.stack([np.full(int(ok.sum()), t), a[ok], b[ok], c[ok]], axis=1))
    return np.concatenate(out)


def persistence_support(candidates: list[FrameCandidates], *, max_step_m: float, max_accel_m: float,
                        max_residual_change_px: float = np.inf, min_motion_m: float = 0.0) -> list[np.ndarray]:
    """Steps 2-3: per frame, the number of smooth triplets each candidate belongs to, ``(n_t,)`` of int.

    ``candidates``: per consecutive frame, its FrameCandidates (points m, residuals px); the other arguments
    as :func:`link_frames` and :func:`smooth_triplets` (m, px)."""
    links = [link_frames(a.points, b.points, max_step_m) for a, b in zip(candidates[:-1], candidates[1:])]
    trip = smooth_triplets([c.points for c in candidates], links, max_accel_m, [c.residuals for c in candidates],
                           max_residual_change_px, min_motion_m)
    offsets = np.concatenate([[0], np.cumsum([len(c.points) for c in candidates])]).astype(np.int64)
    flat = np.zeros(offsets[-1], np.int64)
    for k, off in ((1, -1), (2, 0), (3, 1)):  # the triplet's frames t - 1, t, t + 1
        np.add.at(flat, offsets[trip[:, 0] + off] + trip[:, k], 1)
    return np.split(flat, offsets[1:-1])


def select_greedy(observations: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Indices of the candidates kept, taken in ``order``: one is kept when none of its detections is taken yet
    (each detection used once). ``observations`` ``(n, n_cameras)`` detection ids (-1: none), ``order`` ``(k,)``
    candidate indices -> ndarray of int ``(m,)``, in order."""
    obs = np.asarray(observations, np.int64)
    used = np.zeros((obs.shape[1], max(int(obs.max(initial=-1)) + 1, 1)), bool)
    cams = np.arange(obs.shape[1])
    keep = []
    for i in order:  # sequential by nature: whether a candidate stands depends on those taken before it
        seen = obs[i] >= 0
        if used[cams[seen], obs[i, seen]].any():
            continue
        used[cams[seen], obs[i, seen]] = True
        keep.append(i)
    return np.asarray(keep, np.int64)


def select_per_frame(cands: FrameCandidates, support: np.ndarray, *, min_support: int = 1) -> np.ndarray:
    """Step 4: indices of the candidates kept in one frame, each detection used once.

    Candidates with ``support >= min_support`` in order of support (descending), views (descending),
    reprojection RMS (ascending), then :func:`select_greedy`. ``support``: ``(n,)`` from
    :func:`persistence_support`. Returns ndarray of int ``(m,)``.
    """
    views = (cands.observations >= 0).sum(axis=1)
    idx = np.flatnonzero(support >= min_support)
    return select_greedy(cands.observations, idx[np.lexsort((cands.rms[idx], -views[idx], -support[idx]))])


def _nearest_link(points_a: np.ndarray, points_b: np.ndarray, max_step_m: float) -> np.ndarray:
    """Index in ``points_b`` ``(n_b, 3)`` of the nearest point within ``max_step_m`` of each of ``points_a``
    ``(n_a, 3)``, -1 where none: ``(n_a,)``."""
    out = np.full(len(points_a), -1, np.int64)
    if len(points_a) == 0 or len(points_b) == 0:
        return out
    d, j = cKDTree(points_b).query(points_a, distance_upper_bound=max_step_m)
    hit = np.isfinite(d)
    out[hit] = j[hit]
    return out


def _predictions(points: list[np.ndarray], s: int, max_step_m: float, same_m: float) -> np.ndarray:
    """Constant-velocity predictions ``(k, 3)`` into frame ``s`` of the chains of the neighbouring frames that
    have no point in ``s``: from ``s - 1`` (velocity from ``s - 2``) and from ``s + 1`` (from ``s + 2``);
    predictions within ``same_m`` of an earlier one are dropped (the same gap seen from both sides)."""
    preds = [np.zeros((0, 3))]
    for src, far in ((s - 1, s - 2), (s + 1, s + 2)):
        if not (0 <= src < len(points) and 0 <= far < len(points)):
            continue
        Xs = points[src]
        lone = _nearest_link(Xs, points[s], max_step_m) < 0
        back = _nearest_link(Xs, points[far], max_step_m)
        ok = lone & (back >= 0)
        preds.append(2.0 * Xs[ok] - points[far][back[ok]])
    P = np.concatenate(preds)
    if len(P) > 1:
        pairs = cKDTree(P).query_pairs(same_m, output_type="ndarray")
        P = np.delete(P, np.unique(pairs[:, 1]), axis=0) if len(pairs) else P
    return P


def _claim(P: np.ndarray, dets: list[np.ndarray], obs: np.ndarray, cameras: list[Camera],
           radius_px: float) -> np.ndarray:
    """Per prediction ``P`` ``(k, 3)`` and camera, the nearest detection within ``radius_px`` not in ``obs``
    ``(m, n_cameras)`` and not claimed by a nearer prediction: ``(k, n_cameras)``, -1 = none."""
    out = np.full((len(P), len(cameras)), -1, np.int64)
    for c, cam in enumerate(cameras):
        free = np.setdiff1d(np.arange(len(dets[c])), obs[:, c])
        if free.size == 0 or len(P) == 0:
            continue
        px = cam.project(P)
        fin = np.all(np.isfinite(px), axis=1)
        d, j = cKDTree(dets[c][free]).query(np.where(fin[:, None], px, -1e9), distance_upper_bound=radius_px)
        hit = np.flatnonzero(fin & np.isfinite(d))
        order = hit[np.argsort(d[hit], kind="stable")]
        _, first = np.unique(j[order], return_index=True)
        win = order[first]
        out[win, c] = free[j[win]]
    return out


def recover_from_tracks(frames: list[list[np.ndarray]], cameras: list[Camera], observations: list[np.ndarray],
                        points: list[np.ndarray], *, max_step_m: float, max_accel_m: float,
                        recover_radius_px: float = 1.5, max_residual_px: float = 1.5, min_views: int = 3,
                        passes: int = 2) -> tuple[list, list, list[int]]:
    """Step 5: matches added where a chain of accepted points predicts one (module docstring).

    Parameters
    ----------
    frames : list of list of ndarray, shape (n_i, 2)
        Per frame, the detections of every camera, px.
    cameras : list of Camera
    observations, points : list of ndarray, shapes (m_t, n_cameras) and (m_t, 3)
        Accepted matches per frame (detection indices, -1 = not seen) and their points, m.
    max_step_m, max_accel_m : float
        Link distance between frames and largest distance of a recovered point from its prediction, m.
    recover_radius_px : float
        Search radius around the predicted pixel in each camera, px.
    max_residual_px : float
        Largest reprojection residual of a recovered match in any camera, px.
    min_views : int
    passes : int
        Sweeps over the frames (a recovered point predicts the next gap).

    Returns
    -------
    observations, points : lists as given, with the recovered matches appended
    n_recovered : list of int
        Matches added per frame.
    """
    obs, pts = list(observations), list(points)
    n_rec = [0] * len(frames)
    for _ in range(passes):
        for s in range(len(frames)):
            P = _predictions(pts, s, max_step_m, max_accel_m)
            new = _claim(P, frames[s], obs[s], cameras, recover_radius_px)
            ok = (new >= 0).sum(axis=1) >= min_views
            if not np.any(ok):
                continue
            tri = triangulate(observed_pixels(frames[s], new[ok]), cameras, covariance=False)
            worst = np.nanmax(np.linalg.norm(tri.residuals, axis=-1), axis=0)
            good = (worst <= max_residual_px) & (np.linalg.norm(tri.points - P[ok], axis=1) <= max_accel_m)
            obs[s] = np.concatenate([obs[s], new[ok][good]])
            pts[s] = np.concatenate([pts[s], tri.points[good]])
            n_rec[s] += int(good.sum())
    return obs, pts, n_rec


def temporal_match(frames: list[list[np.ndarray]], cameras: list[Camera], bounds, *, max_step_m: float,
                   max_accel_m: float, epipolar_px: float = 2.0, radius_px: float = 1.5,
                   max_residual_px: float = 1.5, min_views: int = 3, min_support: int = 1,
                   max_residual_change_px: float = np.inf, min_motion_m: float = 0.0, recover: bool = True,
                   recover_radius_px: float | None = None) -> TemporalMatch:
    """Matches seen by >= ``min_views`` cameras that persist over consecutive frames (module docstring).

    Parameters
    ----------
    frames : list of list of ndarray, shape (n_i, 2)
        Consecutive frames (>= 3), each the detections of every camera (distorted px, OpenCV convention).
    cameras : list of Camera
        Calibrated cameras (with their windows), consistent across the cameras to a fraction of
        ``max_residual_px`` (e.g. after ``volume_selfcal.self_calibrate``).
    bounds : (ndarray (3,), ndarray (3,))
        World box of the measurement volume, m.
    max_step_m : float
        Largest displacement of a particle between consecutive frames, m.
    max_accel_m : float
        Largest second difference of a track over three frames (acceleration x dt^2 plus the position
        noise of three points), m.
    epipolar_px, radius_px, max_residual_px : float
        Candidate gates (:func:`frame_candidates`), px.
    min_views : int
        Cameras a match needs (3: the must-hold of issue 14).
    min_support : int
        Smooth triplets a candidate must belong to.
    max_residual_change_px : float
        Largest change of a camera's residual between consecutive frames of a triplet, px (see
        :func:`smooth_triplets`).
    min_motion_m : float
        Smallest displacement over a triplet, m: static chains prove nothing.
    recover : bool
        Run :func:`recover_from_tracks` (search radius ``recover_radius_px``, default ``radius_px``).
    """
    frames = _checked_frames(frames, cameras)
    if max_step_m <= 0 or max_accel_m <= 0:
        raise ValueError(f"max_step_m and max_accel_m must be > 0 m; got {max_step_m}, {max_accel_m}")
    cands = [frame_candidates(d, cameras, bounds, epipolar_px=epipolar_px, radius_px=radius_px,
                              max_residual_px=max_residual_px, min_views=min_views) for d in frames]
    sup = persistence_support(cands, max_step_m=max_step_m, max_accel_m=max_accel_m,
                              max_residual_change_px=max_residual_change_px, min_motion_m=min_motion_m)
    keep = [select_per_frame(c, s, min_support=min_support) for c, s in zip(cands, sup)]
    obs = [c.observations[k] for c, k in zip(cands, keep)]
    pts = [c.points[k] for c, k in zip(cands, keep)]
    n_rec = [0] * len(frames)
    if recover:
        obs, pts, n_rec = recover_from_tracks(frames, cameras, obs, pts, max_step_m=max_step_m,
                                              max_accel_m=max_accel_m, max_residual_px=max_residual_px,
                                              recover_radius_px=recover_radius_px or radius_px, min_views=min_views)
    tris = [triangulate(observed_pixels(d, o), cameras, covariance=False) for d, o in zip(frames, obs)]
    support = [np.concatenate([s[k], np.zeros(len(o) - len(k), np.int64)]) for s, k, o in zip(sup, keep, obs)]
    log.info("temporal matching: candidates %s, supported %s, kept %s, recovered %s",
             [len(c.points) for c in cands], [int((s > 0).sum()) for s in sup], [len(k) for k in keep], n_rec)
    return TemporalMatch(obs, [t.points for t in tris], [t.reprojection_rms for t in tris], support,
                         [len(c.points) for c in cands], [int((s >= min_support).sum()) for s in sup], n_rec)


def _poly_basis(pixels: np.ndarray, image_size, degree: int) -> np.ndarray:
    """Monomials of total degree <= ``degree`` of the pixels ``(n, 2)`` scaled to [-1, 1] over ``image_size``
    (W, H): ``(n, n_terms)``."""
    W, H = image_size
    u = 2.0 * pixels[:, 0] / max(W - 1, 1) - 1.0
    v = 2.0 * pixels[:, 1] / max(H - 1, 1) - 1.0
    return np.stack([u**i * v**j for i in range(degree + 1) for j in range(degree + 1 - i)], axis=1)


def fit_pixel_correction(pixels: np.ndarray, residuals: np.ndarray, image_sizes, *, degree: int = 3,
                         min_points: int = 30, clip_sigma: float = 3.0) -> np.ndarray:
    """Per camera, a smooth map of the reprojection residual over the image (a non-parametric correction of
    the camera model: the part of the calibration error that is a function of the pixel).

    Parameters
    ----------
    pixels, residuals : ndarray, shape (n_cameras, n, 2)
        Detected pixels of verified matches and their residuals (projected - detected), px; NaN = not seen.
    image_sizes : sequence of (W, H)
        Per camera, px.
    degree : int
        Total degree of the bivariate polynomial.
    min_points : int
        A camera with fewer matches gets no correction (zeros).
    clip_sigma : float
        Residuals farther than this many robust sigmas from the first fit are left out of the second.

    Returns
    -------
    ndarray, shape (n_cameras, n_terms, 2)
        Coefficients for :func:`apply_pixel_correction`.
    """
    n_terms = (degree + 1) * (degree + 2) // 2
    out = np.zeros((pixels.shape[0], n_terms, 2))
    for c in range(pixels.shape[0]):
        ok = np.all(np.isfinite(pixels[c]) & np.isfinite(residuals[c]), axis=1)
        if ok.sum() < max(min_points, n_terms):
            log.warning("fit_pixel_correction: camera %d has %d matches (< %d): no correction", c, ok.sum(), min_points)
            continue
        A, r = _poly_basis(pixels[c, ok], image_sizes[c], degree), residuals[c, ok]
        coef = np.linalg.lstsq(A, r, rcond=None)[0]
        e = np.linalg.norm(A @ coef - r, axis=1)
        keep = e <= clip_sigma * 1.4826 * np.median(e) + 1e-12
        out[c] = np.linalg.lstsq(A[keep], r[keep], rcond=None)[0]
    return out


def apply_pixel_correction(detections: list[np.ndarray], coefficients: np.ndarray, image_sizes) -> list[np.ndarray]:
    """Detections ``(n_i, 2)`` per camera moved by the residual map of :func:`fit_pixel_correction` (the
    detection plus the predicted residual: where the camera model puts the particle)."""
    deg = int(round((np.sqrt(8 * coefficients.shape[1] + 1) - 3) / 2))
    return [np.asarray(d, float).reshape(-1, 2) + (_poly_basis(np.asarray(d, float).reshape(-1, 2), s, deg) @ k
                                                   if len(d) else 0.0)
            for d, k, s in zip(detections, coefficients, image_sizes)]


def match_over_time(frames: list[list[np.ndarray]], cameras: list[Camera], bounds, *, max_step_m: float,
                    max_accel_m: float, loose_gates=(3.0, 2.5, 2.5), gates=(2.0, 1.5, 1.5), degree: int = 3,
                    **options) -> tuple[TemporalMatch, list[list[np.ndarray]], np.ndarray]:
    """Temporal matching with loose gates, a pixel correction fit on its matches, temporal matching again.

    1. :func:`temporal_match` with ``loose_gates`` (epipolar_px, radius_px, max_residual_px): matches whose
       calibration error is larger than the final gates, kept only when they persist (chance ones do not);
    2. :func:`fit_pixel_correction` on their residuals (each camera's residual as a smooth function of the
       pixel, total ``degree``), :func:`apply_pixel_correction` to every frame's detections;
    3. :func:`temporal_match` on the corrected detections with ``gates``.

    Parameters
    ----------
    frames : list of list of ndarray, shape (n_i, 2)
        Consecutive frames of detections per camera, px.
    cameras, bounds, max_step_m, max_accel_m
        As :func:`temporal_match`.
    loose_gates, gates : tuple of 3 float
        (epipolar_px, radius_px, max_residual_px) of steps 1 and 3, px.
    degree : int
        Degree of the pixel correction (0 = no correction: step 3 only, on the detections as given).
    **options
        Further keywords of :func:`temporal_match` (``max_residual_change_px``, ``min_motion_m`` ...).

    Returns
    -------
    match : TemporalMatch
        Of step 3; its observations index the detections as given (the correction moves them, in order).
    corrected : list of list of ndarray
        The corrected detections (the pixels the reported reprojection RMS refers to).
    coefficients : ndarray, shape (n_cameras, n_terms, 2)
        The correction (:func:`fit_pixel_correction`).
    """
    frames = _checked_frames(frames, cameras)
    sizes = [c.image_size for c in cameras]
    n_terms = (degree + 1) * (degree + 2) // 2
    coef = np.zeros((len(cameras), n_terms, 2))
    corrected = frames
    if degree > 0:
        first = temporal_match(frames, cameras, bounds, max_step_m=max_step_m, max_accel_m=max_accel_m,
                               epipolar_px=loose_gates[0], radius_px=loose_gates[1], max_residual_px=loose_gates[2],
                               **options)
        px = np.concatenate([observed_pixels(f, o) for f, o in zip(frames, first.observations)], axis=1)
        res = triangulate(px, cameras, covariance=False).residuals
        coef = fit_pixel_correction(px, res, sizes, degree=degree)
        corrected = [apply_pixel_correction(f, coef, sizes) for f in frames]
    match = temporal_match(corrected, cameras, bounds, max_step_m=max_step_m, max_accel_m=max_accel_m,
                           epipolar_px=gates[0], radius_px=gates[1], max_residual_px=gates[2], **options)
    return match, corrected, coef
