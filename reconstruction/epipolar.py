"""Candidate pairs of detections between two calibrated views: within ``epipolar_px`` of each other's epipolar
line (straight rays) or curve (rays refracted through windows, sampled over a bounding box), with the rays'
mid-points. Used by :mod:`reconstruction.correspondence` and :mod:`reconstruction.volume_selfcal`.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["epipolar_curve_pairs"]


def _skew(t: np.ndarray) -> np.ndarray:
    return np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])


def _midpoints(c1, d1, c2, d2):
    """Closest-approach mid-points of ray pairs; d are (n, 3) unit directions."""
    w0 = c1 - c2
    a = np.sum(d1 * d1, 1)
    b = np.sum(d1 * d2, 1)
    c = np.sum(d2 * d2, 1)
    d = np.sum(d1 * w0, 1)
    e = np.sum(d2 * w0, 1)
    den = a * c - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (b * e - c * d) / den
        t = (a * e - b * d) / den
    return 0.5 * (c1 + s[:, None] * d1 + c2 + t[:, None] * d2), s, t


def _straight_pairs(i, j, dets, cameras, norm, rays, epipolar_px):
    """Detection pairs within ``epipolar_px`` of each other's epipolar line; their ray mid-points."""
    Ri, Rj = cameras[i].R, cameras[j].R
    Rij = Rj @ Ri.T
    tij = cameras[j].tvec - Rij @ cameras[i].tvec
    E = _skew(tij) @ Rij
    xi = np.hstack([norm[i], np.ones((len(norm[i]), 1))])
    xj = np.hstack([norm[j], np.ones((len(norm[j]), 1))])
    lj = xi @ E.T  # lines in j: (n_i, 3)
    li = xj @ E  # lines in i: (n_j, 3)
    num = xj @ lj.T  # (n_j, n_i) = x_j^T E x_i
    dj = np.abs(num) / np.linalg.norm(lj[:, :2], axis=1)[None, :] * cameras[j].K[0, 0]
    di = np.abs(num) / np.linalg.norm(li[:, :2], axis=1)[:, None] * cameras[i].K[0, 0]
    b, a = np.nonzero(np.maximum(di, dj) <= epipolar_px)
    X, s, t = _midpoints(rays[i][0][a], rays[i][1][a], rays[j][0][b], rays[j][1][b])
    return a, b, X, (s > 0) & (t > 0)


def _refracted_pairs(i, j, dets, cameras, rays, epipolar_px, chunk: int = 200_000):
    """Pairs along the epipolar curves through the windows (see :func:`match_views`), every pair tested.

    A loose 3-D gate on the distance between the rays in the bath (4 pixel footprints per
    ``epipolar_px``) keeps the candidates few; the exact gate (:func:`_curve_gate`) follows.
    Processed in blocks of about ``chunk`` pairs to bound memory.
    """
    (oi, di), (oj, dj) = rays[i], rays[j]
    ci, cj = cameras[i].center, cameras[j].center
    fi, fj = cameras[i].K[0, 0], cameras[j].K[0, 0]
    step = max(1, chunk // max(len(oj), 1))
    parts = []
    for start in range(0, len(oi), step):
        a, b = np.meshgrid(np.arange(start, min(start + step, len(oi))), np.arange(len(oj)), indexing="ij")
        a, b = a.ravel(), b.ravel()
        _, s, t = _midpoints(oi[a], di[a], oj[b], dj[b])
        pa, pb = oi[a] + s[:, None] * di[a], oj[b] + t[:, None] * dj[b]
        foot = np.maximum(np.linalg.norm(pa - ci, axis=1) / fi, np.linalg.norm(pb - cj, axis=1) / fj)
        keep = (s > 0) & (t > 0) & (np.linalg.norm(pa - pb, axis=1) <= 4.0 * epipolar_px * foot)
        parts.append((a[keep], b[keep]))
    a, b = (np.concatenate([p[k] for p in parts]) for k in range(2))
    return _curve_gate(a, b, i, j, dets, cameras, rays, epipolar_px)


def _curve_gate(a, b, i, j, dets, cameras, rays, epipolar_px):
    """Exact gate of candidate pairs ``(a, b)`` (detection indices in cameras i, j): each ray's
    closest-approach point, projected into the other camera, within ``epipolar_px`` of the detection
    there. Returns the kept ``a, b``, their mid-points ``(m, 3)`` and an all-True mask."""
    (oi, di), (oj, dj) = rays[i], rays[j]
    _, s, t = _midpoints(oi[a], di[a], oj[b], dj[b])
    front = (s > 0) & (t > 0)
    a, b, s, t = a[front], b[front], s[front], t[front]
    pa, pb = oi[a] + s[:, None] * di[a], oj[b] + t[:, None] * dj[b]
    err_j = np.linalg.norm(cameras[j].project(pa) - dets[j][b], axis=1)
    err_i = np.linalg.norm(cameras[i].project(pb) - dets[i][a], axis=1)
    ok = np.maximum(err_i, err_j) <= epipolar_px
    return a[ok], b[ok], 0.5 * (pa[ok] + pb[ok]), np.ones(int(ok.sum()), bool)


def _ray_box(origins, directions, lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """Ray parameters ``(t0, t1)`` (each (n,)) where rays ``(n, 3)`` cross the box [lo, hi] (t0 > t1: they miss)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ta = (lo - origins) / directions
        tb = (hi - origins) / directions
    t0 = np.nanmax(np.minimum(ta, tb), axis=1)
    t1 = np.nanmin(np.maximum(ta, tb), axis=1)
    return np.maximum(t0, 1e-6), t1  # 1 um past the origin (a window surface: projects to NaN on it)


def epipolar_curve_pairs(i, j, dets, cameras, rays, epipolar_px, bounds, spacing_px: float = 6.0,
                         max_samples: int = 400):
    """Detection pairs of cameras ``i`` and ``j`` along the epipolar curves through the windows, searched in the
    box ``bounds`` ((3,), (3,) m): each ray of camera i is sampled
    across the box, the samples are projected into camera j in one batch, and the detections of j
    within ``epipolar_px`` + half the sample spacing of a sample (KD-trees) are the candidates; the
    exact gate (:func:`_curve_gate`) follows.

    ``dets``: per camera the detections ``(n_c, 2)`` px; ``rays``: per camera ``(origins, directions)`` of its
    detections in water (``Camera.rays``). Returns the kept detection indices ``a`` (camera i) and ``b``
    (camera j), each ``(m,)``, the pairs' mid-points ``(m, 3)`` m and an all-True mask ``(m,)``."""
    (oi, di) = rays[i]
    margin = 1e-3  # m: mid-points near a face of the box have closest-approach points just outside it
    t0, t1 = _ray_box(oi, di, np.asarray(bounds[0]) - margin, np.asarray(bounds[1]) + margin)
    hit = np.flatnonzero(t1 > t0)
    if hit.size == 0:
        return _curve_gate(np.zeros(0, int), np.zeros(0, int), i, j, dets, cameras, rays, epipolar_px)
    ends = cameras[j].project(np.concatenate([oi[hit] + t0[hit, None] * di[hit], oi[hit] + t1[hit, None] * di[hit]]))
    length = np.linalg.norm(ends[: hit.size] - ends[hit.size:], axis=1)
    n_samples = int(np.clip(np.ceil(np.nanmax(length, initial=0.0) / spacing_px), 2, max_samples)) + 1
    u = np.linspace(0.0, 1.0, n_samples)
    t = t0[hit, None] + (t1 - t0)[hit, None] * u  # (m, k)
    pts = oi[hit, None, :] + t[..., None] * di[hit, None, :]
    px = cameras[j].project(pts.reshape(-1, 3)).reshape(hit.size, n_samples, 2)
    gap = np.nanmax(np.linalg.norm(np.diff(px, axis=1), axis=-1), initial=0.0)
    fin = np.all(np.isfinite(px), axis=-1).ravel()
    owner = np.repeat(hit, n_samples)[fin]
    near = cKDTree(px.reshape(-1, 2)[fin]).sparse_distance_matrix(
        cKDTree(dets[j]), epipolar_px + 0.5 * gap + 1e-9, output_type="ndarray")
    pairs = np.unique(np.stack([owner[near["i"]], near["j"]], axis=1), axis=0)
    return _curve_gate(pairs[:, 0], pairs[:, 1], i, j, dets, cameras, rays, epipolar_px)
