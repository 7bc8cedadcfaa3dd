"""Calibration's initial guess: each camera alone (``cv2.calibrateCamera``), relative camera poses from shared
views chained along a maximum spanning tree of the camera graph, the board's reversal symmetry resolved, board poses
in the world. Steps 1-2 of :mod:`reconstruction.calibration`.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from .calibration_errors import CalibrationError
from .calibration_model import _N_CAM

log = logging.getLogger(__name__)


def _compose_inverse_pose(R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return R.T, -R.T @ t


def _mean_rotation(Rs: np.ndarray) -> np.ndarray:
    """Chordal L2 mean of rotation matrices ``(n, 3, 3)``."""
    U, _, Vt = np.linalg.svd(np.sum(Rs, axis=0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def _normalise_inputs(image_points, object_points):
    uv = np.asarray(image_points, float)
    if uv.ndim != 4 or uv.shape[-1] != 2:
        raise CalibrationError(f"image_points must have shape (n_cams, n_views, n_points, 2); got {uv.shape}")
    n_cams, n_views, n_points, _ = uv.shape
    obj = np.asarray(object_points, float)
    if obj.shape == (n_points, 3):
        obj = np.broadcast_to(obj, (n_views, n_points, 3))
    if obj.shape != (n_views, n_points, 3):
        raise CalibrationError(
            f"object_points must have shape (n_points, 3) or (n_views, n_points, 3) = ({n_views}, {n_points}, 3); got {obj.shape}"
        )
    return uv, obj


def _init_camera(uv_c, obj, size, min_points, name):
    """cv2.calibrateCamera on the views of one camera. Returns (K, dist, {view: (R, t)}, rms)."""
    views = [v for v in range(uv_c.shape[0]) if np.isfinite(uv_c[v]).all(-1).sum() >= min_points]
    if len(views) < 2:
        raise CalibrationError(f"camera {name!r}: board seen in {len(views)} views; need at least 2 (better >= 5)")
    op, ip = [], []
    planar = True
    for v in views:
        ok = np.isfinite(uv_c[v]).all(-1)
        op.append(obj[v, ok].astype(np.float32))
        ip.append(uv_c[v, ok].astype(np.float32).reshape(-1, 1, 2))
        planar = planar and np.ptp(obj[v, ok, 2]) == 0
    w, h = size
    K0 = np.array([[max(w, h), 0, (w - 1) / 2], [0, max(w, h), (h - 1) / 2], [0, 0, 1.0]])
    flags = 0 if planar else cv2.CALIB_USE_INTRINSIC_GUESS
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(op, ip, (w, h), K0, np.zeros(5), flags=flags, criteria=crit)
    poses = {v: (cv2.Rodrigues(r)[0], np.asarray(t, float).ravel()) for v, r, t in zip(views, rvecs, tvecs)}
    return K, np.asarray(dist, float).ravel()[:5], poses, float(rms)


def _angle(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """Angle (rad) of the rotation between two rotation matrices."""
    return float(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1.0, 1.0)))


def _reversal_symmetry(obj: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(R, t) with ``R @ obj[k] + t = obj[n-1-k]`` if the target is symmetric under reversal, else None."""
    a, b = obj, obj[::-1]
    ca, cb = a.mean(0), b.mean(0)
    U, _, Vt = np.linalg.svd((a - ca).T @ (b - cb))
    R = Vt.T @ np.diag([1, 1, np.sign(np.linalg.det(Vt.T @ U.T))]) @ U.T
    t = cb - R @ ca
    scale = max(np.ptp(a, axis=0).max(), 1e-300)
    return (R, t) if np.abs(a @ R.T + t - b).max() < 1e-6 * scale else None


def _relative_pose(pi: dict, pj: dict, views: np.ndarray, flip) -> tuple[np.ndarray, np.ndarray]:
    """Camera i -> camera j pose from shared views, robust to bad views (and to reversed targets if ``flip``).

    The candidate (per view, per order hypothesis) agreeing with most views within 2 deg wins;
    the agreeing candidates are averaged.
    """
    cands = []
    for v in views:
        Ri, ti = pi[v]
        hyps = [pj[v]] if flip is None else [pj[v], (pj[v][0] @ flip[0], pj[v][0] @ flip[1] + pj[v][1])]
        for Rj, tj in hyps:
            R = Rj @ Ri.T
            cands.append((v, R, tj - R @ ti))
    tol = np.deg2rad(2.0)
    best = max(range(len(cands)), key=lambda k: len({c[0] for c in cands if _angle(c[1], cands[k][1]) < tol}))
    chosen = {}
    for v, R, t in cands:
        d = _angle(R, cands[best][1])
        if d < tol and (v not in chosen or d < chosen[v][0]):
            chosen[v] = (d, R, t)
    Rs = np.array([c[1] for c in chosen.values()])
    ts = np.array([c[2] for c in chosen.values()])
    return _mean_rotation(Rs), np.median(ts, axis=0)


def _spanning_tree(n_cams: int, weights: np.ndarray, root: int) -> list[tuple[int, int]]:
    """Maximum spanning tree edges (parent, child) by Prim's algorithm from ``root``."""
    inside = {root}
    edges = []
    while len(inside) < n_cams:
        best = None
        for i in inside:
            for j in range(n_cams):
                if j not in inside and weights[i, j] > 0 and (best is None or weights[i, j] > best[0]):
                    best = (weights[i, j], i, j)
        if best is None:
            break
        edges.append((best[1], best[2]))
        inside.add(best[2])
    return edges


def _initialise_cameras(uv, obj, image_sizes, min_points, names, fix_k3):
    """Step 1: each camera on its own (OpenCV): K, distortion, board poses per view, RMS."""
    Ks, dists, poses, init_rms = [], [], [], []
    for c in range(uv.shape[0]):
        K, d, p, r = _init_camera(uv[c], obj, image_sizes[c], min_points, names[c])
        if fix_k3:
            d[4] = 0.0
        Ks.append(K)
        dists.append(d)
        poses.append(p)
        init_rms.append(r)
        log.info("camera %s: initial RMS %.3f px over %d views", names[c], r, len(p))
    return Ks, dists, poses, init_rms


def _pose_graph(obj, names, counts, usable, poses, reference, resolve_flips):
    """Step 2: every camera's pose in the reference camera's frame, chained along the spanning tree of shared
    views; and the target's reversal symmetry when ``resolve_flips``."""
    n_cams = len(names)
    shared = np.zeros((n_cams, n_cams))
    for i in range(n_cams):
        for j in range(n_cams):
            if i != j:
                both = usable[i] & usable[j]
                shared[i, j] = np.minimum(counts[i], counts[j])[both].sum()
    edges = _spanning_tree(n_cams, shared, reference)
    flip = _reversal_symmetry(obj[np.flatnonzero(usable.any(0))[0]]) if resolve_flips and usable.any() else None
    if resolve_flips and flip is None:
        log.warning("resolve_flips: the target is not symmetric under reversal of its point order; nothing to resolve")
    Rw = {reference: np.eye(3)}
    tw = {reference: np.zeros(3)}
    for i, j in edges:
        vs = np.flatnonzero(usable[i] & usable[j])
        R, t = _relative_pose(poses[i], poses[j], vs, flip)
        Rw[j] = R @ Rw[i]
        tw[j] = R @ tw[i] + t
    missing = [names[c] for c in range(n_cams) if c not in Rw]
    if missing:
        raise CalibrationError(f"cameras {missing} share no board view with the others (directly or through other cameras)")
    return Rw, tw, flip


def _resolve_flips(uv, counts, usable, poses, Rw, flip):
    """Reverse the point order of the camera views that disagree with the camera seeing most of the view
    (updates ``poses`` in place; returns the re-ordered copy of ``uv``)."""
    uv = uv.copy()
    n_flipped = 0
    for v in np.flatnonzero(usable.sum(0) > 1):
        a = int(np.argmax(np.where(usable[:, v], counts[:, v], -1)))
        Ra = Rw[a].T @ poses[a][v][0]
        for c in np.flatnonzero(usable[:, v]):
            if c == a:
                continue
            Rc0 = Rw[c].T @ poses[c][v][0]
            Rc1 = Rc0 @ flip[0]
            if _angle(Rc1, Ra) < _angle(Rc0, Ra):
                Rcv, tcv = poses[c][v]
                poses[c][v] = (Rcv @ flip[0], Rcv @ flip[1] + tcv)
                uv[c, v] = uv[c, v, ::-1]
                n_flipped += 1
    if n_flipped:
        log.info("resolve_flips: reversed the point order of %d camera views to match the other cameras", n_flipped)
    return uv


def _board_poses(n_views, counts, usable, poses, Rw, tw) -> np.ndarray:
    """Board poses ``(n_views, 6)`` (Rodrigues, t) in the world, from the camera seeing most points; NaN = unseen."""
    Vp = np.full((n_views, 6), np.nan)
    for v in np.flatnonzero(usable.any(0)):
        c = int(np.argmax(np.where(usable[:, v], counts[:, v], -1)))
        Rcv, tcv = poses[c][v]
        R = Rw[c].T @ Rcv
        t = Rw[c].T @ (tcv - tw[c])
        Vp[v] = np.concatenate([cv2.Rodrigues(R)[0].ravel(), t])
    return Vp


def _camera_vectors(Ks, dists, Rw, tw) -> np.ndarray:
    """The adjustment's camera parameters ``(n_cams, _N_CAM)``: fx fy cx cy, k1 k2 p1 p2 k3, rvec, tvec."""
    Cp = np.zeros((len(Ks), _N_CAM))
    for c, K in enumerate(Ks):
        Cp[c] = np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], dists[c], cv2.Rodrigues(Rw[c])[0].ravel(), tw[c]])
    return Cp
