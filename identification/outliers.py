"""Mis-tracked markers and the marker noise: each marker's displacement against its mesh neighbours'.

``marker_outliers`` compares every marker's displacement with the affine fit of its 1-ring neighbours'
(mesh edges) and flags those that disagree; the mismatch gives the per-step marker noise estimate. Used by
``kinematics.surface_state``. Positions in m; shapes in the docstrings.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import csr_matrix

from .mesh import SurfaceMesh, unique_sorted, wrap_angle

__all__ = ["marker_outliers"]


def marker_outliers(mesh: SurfaceMesh, r, theta, z, *, floor: float = 0.25, n_sigma: float = 8.0) -> np.ndarray:
    """Markers whose displacement disagrees with their mesh neighbours (mis-tracked), per step.

    Each marker's cylindrical displacement (r - R, R_mean (theta - Theta), z - Z) is compared with
    the affine fit, in the reference (R_mean Theta, Z) plane, of its 1-ring neighbours' displacements
    (exact for any smooth field to second order). A marker is an outlier when the mismatch exceeds
    ``max(n_sigma * robust sigma of the step, floor * median mesh edge length)``.

    Parameters
    ----------
    r, theta, z : ndarray, shape (n_steps, n_markers)
        Current cylindrical coordinates (NaN = not observed).

    Returns
    -------
    outlier : ndarray, shape (n_steps, n_markers) bool
    noise : ndarray, shape (n_steps,)
        Estimated standard deviation of the marker coordinates (m): median mismatch / 2.2 (the
        median norm of a 3-D Gaussian is 1.54 sigma and the neighbours' fit adds its own scatter;
        the factor is calibrated on random marker layouts to within ~5 %).
    """
    n = mesh.n_markers
    edges = _mesh_edges(mesh.triangles, n)
    Rm = mesh.axis.radius
    ds = Rm * wrap_angle(mesh.theta[edges[:, 1]] - mesh.theta[edges[:, 0]])
    dz = mesh.z[edges[:, 1]] - mesh.z[edges[:, 0]]
    edge_len = float(np.median(np.hypot(ds, dz)))
    disp = np.stack([r - mesh.r, Rm * wrap_angle(theta - mesh.theta), z - mesh.z], -1)  # (s, n, 3)
    # both directions of every edge: (centre i, neighbour j, offset of j from i), grouped by centre
    ci = np.concatenate([edges[:, 0], edges[:, 1]])
    order = np.argsort(ci, kind="stable")
    ci, nj = ci[order], np.concatenate([edges[:, 1], edges[:, 0]])[order]
    off = np.concatenate([np.column_stack([ds, dz]), -np.column_stack([ds, dz])])[order]
    A = np.column_stack([np.ones(len(ci)), off / edge_len])  # (n_e2, 3), scaled for conditioning
    pair_sum, first_sum = _centre_sums(A, ci, n)
    outlier = np.zeros(disp.shape[:2], bool)
    n_s = disp.shape[0]
    for _ in range(2):  # second pass without the first pass's outliers among the neighbours
        if _ == 1 and not outlier.any():
            break  # the second pass would repeat the first exactly
        ok = np.all(np.isfinite(disp), -1) & ~outlier
        w = ok[:, nj].astype(float)  # (s, n_e2)
        dj = np.where(ok[..., None], disp, 0.0)[:, nj]  # (s, n_e2, 3)
        a00, a01, a02, a11, a12, a22 = (pair_sum @ w.T).reshape(6, n, n_s).transpose(0, 2, 1)  # each (s, n)
        # only the fit's value at the centre is needed: the first row of the adjugate of A^T W A
        row = np.stack([a11 * a22 - a12 * a12, a02 * a12 - a01 * a22, a01 * a12 - a02 * a11])  # (3, s, n)
        det = row[0] * a00 + row[1] * a01 + row[2] * a02
        Atd = (first_sum @ np.moveaxis(dj, 1, 0).reshape(len(nj), -1)).reshape(3, n, n_s, 3)  # (k, n, s, c)
        enough = (a00 >= 4) & (det > 1e-6)  # a00: the number of observed neighbours
        centre = np.einsum("ksn,knsc->snc", row, Atd) / np.where(enough, det, 1.0)[..., None]
        gap = disp - centre
        dev = np.sqrt(np.einsum("snc,snc->sn", gap, gap))
        dev = np.where(enough & ok, dev, np.nan)
        sigma = 1.4826 * _nanmedian_rows(dev)[:, None]
        limit = np.maximum(n_sigma * sigma, floor * edge_len)
        outlier |= np.nan_to_num(dev) > limit
    noise = _nanmedian_rows(np.where(outlier, np.nan, dev)) / 2.2
    return outlier, noise


def _centre_sums(A: np.ndarray, ci: np.ndarray, n: int):
    """Sparse operators summing per-edge terms over each centre's edges (edges sorted by centre ``ci``).

    ``pair_sum`` (6 n, n_e2): rows m n + i sum A_k A_l over the edges of centre i, for the six (k, l) of
    ``_PAIRS``; ``first_sum`` (3 n, n_e2): rows k n + i sum A_k.
    """
    m = len(ci)
    e = np.arange(m)
    row_end = np.cumsum(np.bincount(ci, minlength=n))  # the edges of centre i end there (sorted by centre)
    indptr = np.concatenate([[0]] + [row_end + k * m for k in range(6)])  # block k: the k-th product's rows
    pair_vals = np.concatenate([A[:, k] * A[:, j] for k, j in _PAIRS])
    pair_sum = csr_matrix((pair_vals, np.tile(e, 6), indptr), shape=(6 * n, m))
    first_sum = csr_matrix((A.T.ravel(), np.tile(e, 3), indptr[:3 * n + 1]), shape=(3 * n, m))
    return pair_sum, first_sum


#: The six (k, l), k <= l, of a symmetric 3 x 3 matrix, in the order a00, a01, a02, a11, a12, a22.
_PAIRS = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def _nanmedian_rows(a: np.ndarray) -> np.ndarray:
    """``np.nanmedian(a, axis=1)`` of a (s, n) without its overhead (NaN for a row with no finite value)."""
    srt = np.sort(a, axis=1)  # NaN sort last
    k = np.isfinite(a).sum(axis=1)
    lo = np.take_along_axis(srt, np.maximum((k - 1) // 2, 0)[:, None], axis=1)[:, 0]
    hi = np.take_along_axis(srt, (k // 2)[:, None], axis=1)[:, 0]
    return np.where(k > 0, 0.5 * (lo + hi), np.nan)


def _mesh_edges(tri: np.ndarray, n: int) -> np.ndarray:
    """Undirected edges (lower index first) of the triangles ``tri`` (t, 3) over n markers, sorted: (e, 2)."""
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    key = unique_sorted(np.minimum(e[:, 0], e[:, 1]).astype(np.int64) * n + np.maximum(e[:, 0], e[:, 1]))
    return np.column_stack([key // n, key % n])


def _inverse_first_row(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First row of the adjugate and the determinant of symmetric 3 x 3 matrices ``a (..., 3, 3)``."""
    row = np.stack([a[..., 1, 1] * a[..., 2, 2] - a[..., 1, 2] * a[..., 2, 1],
                    a[..., 0, 2] * a[..., 2, 1] - a[..., 0, 1] * a[..., 2, 2],
                    a[..., 0, 1] * a[..., 1, 2] - a[..., 0, 2] * a[..., 1, 1]], -1)
    return row, np.einsum("...k,...k->...", row, a[..., :, 0])
