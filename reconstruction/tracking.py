"""Persistent marker identities through load steps.

Each step's unlabelled 3-D points are matched to the tracked markers by:

1. a global axisymmetric map of the previous configuration (radius, twist and axial coordinate
   as low-order polynomials of the axial position, plus an axis shift), initialised from the
   cylinder radii and axial quantiles of both point sets (or a given axial-ratio hint), refined
   ICP-style with ``scipy.optimize.linear_sum_assignment`` and a shrinking gate;
2. a local correction: each marker's predicted position gets the median residual displacement
   of its nearest matched neighbours (leave-one-out), which captures non-axisymmetric
   deformation;
3. a final optimal assignment with a tight gate; markers without a partner are lost for this
   step (NaN), keep their predicted position for the next step, and are found again later;
4. swap detection: after the assignment, each marker's displacement is compared with the local
   affine displacement field of its neighbours; a pair of inconsistent neighbours whose exchange
   makes both consistent is reported (and exchanged when ``fix_swaps``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares, linear_sum_assignment
from scipy.spatial import cKDTree

from reconstruction.surface import CylinderFit, fit_cylinder

__all__ = ["AxisymmetricMap", "StepMatch", "fit_axisymmetric_map", "match_step", "marker_spacing"]

log = logging.getLogger(__name__)

_BIG = 1e30


@dataclass(frozen=True)
class AxisymmetricMap:
    """``x -> x'`` in cylindrical coordinates about a reference axis.

    With ``s = (z - z0) / L`` (normalised axial coordinate of the source point)::

        r'     = r (a0 + a1 s + a2 s^2)
        theta' = theta + b0 + b1 s
        z'     = z0 + c0 L + L (c1 s + c2 s^2)
        x'     = cylinder frame back to world, plus an axis shift (d1, d2) in the transverse plane.
    """

    cylinder: CylinderFit
    z0: float
    L: float
    params: np.ndarray  # (10,) a0 a1 a2 b0 b1 c0 c1 c2 d1 d2

    @staticmethod
    def identity(cylinder: CylinderFit, z0: float, L: float) -> "AxisymmetricMap":
        return AxisymmetricMap(cylinder, z0, L, np.array([1.0, 0, 0, 0, 0, 0, 1.0, 0, 0, 0]))

    def apply(self, points: np.ndarray, params: np.ndarray | None = None) -> np.ndarray:
        return self.apply_cylindrical(self.cylinder.cylindrical(points), params)

    def apply_cylindrical(self, rtz: tuple, params: np.ndarray | None = None, *, jacobian: bool = False):
        """The map of points given by their cylindrical coordinates ``rtz`` = (r, theta, z), each
        (n,), about the reference axis: (n, 3) m; with ``jacobian``, also d x' / d params (n, 3, 10)."""
        p = self.params if params is None else params
        r, th, z = rtz
        s = (z - self.z0) / self.L
        r2 = r * (p[0] + p[1] * s + p[2] * s * s)
        th2 = th + p[3] + p[4] * s
        z2 = self.z0 + self.L * (p[5] + p[6] * s + p[7] * s * s)
        F = self.cylinder.frame()
        c, si = np.cos(th2), np.sin(th2)
        local = np.stack([r2 * c + p[8] * self.L, r2 * si + p[9] * self.L, z2], axis=1)
        out = self.cylinder.axis_point + local @ F
        if not jacobian:
            return out
        n, one = r.size, np.ones_like(r)
        d_r2 = np.stack([r, r * s, r * s * s], axis=1)  # (n, 3): d r2 / d (a0, a1, a2)
        d_th2 = np.stack([one, s], axis=1)  # d theta2 / d (b0, b1)
        J = np.zeros((n, 3, 10))
        J[:, 0, 0:3], J[:, 1, 0:3] = c[:, None] * d_r2, si[:, None] * d_r2
        J[:, 0, 3:5], J[:, 1, 3:5] = (-r2 * si)[:, None] * d_th2, (r2 * c)[:, None] * d_th2
        J[:, 2, 5:8] = self.L * np.stack([one, s, s * s], axis=1)
        J[:, 0, 8] = J[:, 1, 9] = self.L
        return out, np.einsum("nkp,kj->njp", J, F)


def marker_spacing(points: np.ndarray) -> float:
    """Median nearest-neighbour distance of finite points (n, 3), m."""
    P = np.asarray(points, dtype=float)
    P = P[np.all(np.isfinite(P), axis=1)]
    if P.shape[0] < 2:
        return np.inf
    d, _ = cKDTree(P).query(P, k=2)
    return float(np.median(d[:, 1]))


def fit_axisymmetric_map(src: np.ndarray, dst: np.ndarray, base: AxisymmetricMap) -> AxisymmetricMap:
    """Least-squares (soft-L1) map parameters taking matched ``src`` (m, 3) onto ``dst`` (m, 3)
    (analytic Jacobian; the source points' cylindrical coordinates computed once)."""
    scale = max(marker_spacing(dst) * 0.1, 1e-9)
    rtz = base.cylinder.cylindrical(src)
    n = src.shape[0]
    p0 = base.params.copy()
    free = np.ones(10, bool)
    if n < 30:  # too few pairs for the quadratic terms
        free[[2, 7]] = False
    if n < 12:
        free[[1, 4]] = False

    def full(q):
        p = p0.copy()
        p[free] = q
        return p

    def r_free(q):
        return (base.apply_cylindrical(rtz, full(q)) - dst).ravel()

    def j_free(q):
        return base.apply_cylindrical(rtz, full(q), jacobian=True)[1].reshape(-1, 10)[:, free]

    sol = least_squares(r_free, p0[free], jac=j_free, loss="soft_l1", f_scale=scale)
    return AxisymmetricMap(base.cylinder, base.z0, base.L, full(sol.x))


@dataclass(frozen=True)
class StepMatch:
    """Result of :func:`match_step`.

    Attributes
    ----------
    assignment : ndarray of int, shape (n_markers,)
        Index into the step's points per tracked marker, -1 = lost in this step.
    predicted : ndarray, shape (n_markers, 3)
        Predicted positions (map + local correction), m; the position carried forward for lost markers.
    residual : ndarray, shape (n_markers,)
        Distance between predicted and assigned point, m (NaN if lost).
    ambiguous : ndarray of bool, shape (n_markers,)
        The second-nearest point was not much farther than the assigned one (ratio > 0.6).
    swaps : ndarray of int, shape (n_swaps, 2)
        Marker pairs detected as exchanged (and corrected if requested).
    map : AxisymmetricMap
    gate : float
        Final assignment gate, m.
    """

    assignment: np.ndarray
    predicted: np.ndarray
    residual: np.ndarray
    ambiguous: np.ndarray
    swaps: np.ndarray
    map: AxisymmetricMap
    gate: float


def _assign(pred: np.ndarray, obs: np.ndarray, gate: float) -> np.ndarray:
    """Optimal one-to-one assignment within a gate; returns (n_pred,) index or -1."""
    out = np.full(pred.shape[0], -1, dtype=np.int64)
    okp = np.all(np.isfinite(pred), axis=1)
    if obs.shape[0] == 0 or not np.any(okp):
        return out
    tree = cKDTree(obs)
    # sparse gating: only pairs within the gate enter the cost matrix
    pi = np.flatnonzero(okp)
    lists = tree.query_ball_point(pred[pi], r=gate)
    rows = np.repeat(np.arange(pi.size), [len(l) for l in lists])
    if rows.size == 0:
        return out
    cols = np.concatenate([np.asarray(l, dtype=np.int64) for l in lists])
    ucols, cinv = np.unique(cols, return_inverse=True)
    urows, rinv = np.unique(rows, return_inverse=True)
    C = np.full((urows.size, ucols.size), _BIG)
    C[rinv, cinv] = np.sum((pred[pi[rows]] - obs[cols]) ** 2, axis=1)
    r, c = linear_sum_assignment(C)
    good = C[r, c] < _BIG
    out[pi[urows[r[good]]]] = ucols[c[good]]
    return out


def _local_correction(prev: np.ndarray, mapped: np.ndarray, obs: np.ndarray, assignment: np.ndarray, k: int) -> np.ndarray:
    """Predicted positions: mapped + median residual displacement of the k nearest matched neighbours."""
    matched = assignment >= 0
    if matched.sum() < 4:
        return mapped
    d = obs[assignment[matched]] - mapped[matched]
    k = int(min(k, matched.sum() - 1))
    tree = cKDTree(prev[matched])
    _, nb = tree.query(prev, k=k + 1)
    idx_m = np.flatnonzero(matched)
    # leave-one-out: drop the marker itself from its own neighbourhood
    self_hit = idx_m[nb] == np.arange(prev.shape[0])[:, None]
    dn = d[nb]  # (n, k+1, 3)
    dn = np.where(self_hit[..., None], np.nan, dn)
    dn[:, -1] = np.where(self_hit.any(axis=1)[:, None], dn[:, -1], np.nan)  # keep exactly k
    corr = np.nanmedian(dn, axis=1)
    return mapped + np.nan_to_num(corr)


def _initial_map(prev: np.ndarray, obs: np.ndarray, cyl: CylinderFit, z0: float, L: float, axial_ratio: float | None) -> AxisymmetricMap:
    base = AxisymmetricMap.identity(cyl, z0, L)
    try:
        cyl_obs = fit_cylinder(obs, axis_guess=cyl.axis_direction)
    except ValueError:
        return base
    p = base.params.copy()
    p[0] = cyl_obs.radius / cyl.radius
    _, _, zp = cyl.cylindrical(prev)
    _, _, zo = cyl.cylindrical(obs)
    if axial_ratio is not None:
        p[6] = axial_ratio
        p[5] = (np.median(zo) - z0) / L - axial_ratio * (np.median(zp) - z0) / L
    else:
        qp = np.percentile(zp, [10, 50, 90])
        qo = np.percentile(zo, [10, 50, 90])
        p[6] = (qo[2] - qo[0]) / max(qp[2] - qp[0], 1e-12)
        p[5] = ((qo[1] - z0) - p[6] * (qp[1] - z0)) / L
    shift = (cyl_obs.axis_point - cyl.axis_point) @ cyl.frame()[:2].T
    p[8:10] = shift / L
    return AxisymmetricMap(cyl, z0, L, p)


def _icp(prev, obs, m: AxisymmetricMap, spacing: float, final_gate: float, iterations: int):
    """Iterated closest points from the start map ``m``: (map, last gate m, assignment (n,) at the
    final gate, -1 = none)."""
    g = 0.5 * spacing
    for _ in range(iterations):
        assignment = _assign(m.apply(prev), obs, g)
        ok = assignment >= 0
        if ok.sum() < 6:
            g *= 1.5
            continue
        m = fit_axisymmetric_map(prev[ok], obs[assignment[ok]], m)
        g = max(final_gate, 0.7 * g)
    return m, g, _assign(m.apply(prev), obs, max(final_gate, g))


def match_step(
    previous: np.ndarray,
    points: np.ndarray,
    *,
    axial_ratio: float | None = None,
    gate: float | None = None,
    neighbours: int = 8,
    icp_iterations: int = 6,
    fix_swaps: bool = True,
    axis_guess: np.ndarray | None = None,
) -> StepMatch:
    """Assign this step's unlabelled points to tracked markers.

    Parameters
    ----------
    previous : ndarray, shape (n_markers, 3)
        Positions of every tracked marker in the previous step (measured, or the prediction
        carried forward for markers lost there), m. All rows finite.
    points : ndarray, shape (n_points, 3)
        This step's reconstructed points, m.
    axial_ratio : float, optional
        Expected ratio of axial lengths (e.g. from the prescribed stretch); default estimated.
    gate : float, optional
        Final gate on the distance between prediction and point, m. Default: 0.35 x the median
        marker spacing.
    neighbours : int
        Neighbours for the local correction and swap checks.
    icp_iterations : int
    fix_swaps : bool
        Exchange detected swapped pairs.
    axis_guess : ndarray, shape (3,), optional
        Start of the axis search of the previous positions' cylinder (e.g. the tracker's specimen
        axis: one fit); default: each principal direction of the points (three fits).

    Returns
    -------
    StepMatch
    """
    prev = np.asarray(previous, dtype=float)
    obs = np.asarray(points, dtype=float).reshape(-1, 3)
    obs = np.where(np.all(np.isfinite(obs), axis=1)[:, None], obs, np.inf)
    if not np.all(np.isfinite(prev)):
        raise ValueError("previous must be finite for every tracked marker (carry predictions forward for lost markers)")
    n = prev.shape[0]
    cyl = fit_cylinder(prev, axis_guess=axis_guess)
    _, _, zp = cyl.cylindrical(prev)
    z0 = float(np.median(zp))
    L = float(max(np.ptp(zp) / 2, 1e-6))
    spacing = marker_spacing(prev)
    final_gate = 0.35 * spacing if gate is None else float(gate)
    fin_obs = np.all(np.isfinite(obs), axis=1)
    identity = AxisymmetricMap.identity(cyl, z0, L)
    start = _initial_map(prev, obs[fin_obs], cyl, z0, L, axial_ratio) if fin_obs.sum() >= 6 else identity
    m, g, assignment = _icp(prev, obs, start, spacing, final_gate, icp_iterations)
    # the initial map comes from the point set's extent (percentiles along the axis): a step whose
    # points cover the tube unevenly can start the ICP far off, and it then locks on a few markers.
    # The previous positions themselves (the steps are small) are the second start; keep the better.
    expected = min(n, int(fin_obs.sum()))
    if start is not identity and np.count_nonzero(assignment >= 0) < 0.8 * expected:
        alt = _icp(prev, obs, identity, spacing, final_gate, icp_iterations)
        if np.count_nonzero(alt[2] >= 0) > np.count_nonzero(assignment >= 0):
            m, g, assignment = alt
    mapped = m.apply(prev)
    pred = _local_correction(prev, mapped, obs, assignment, neighbours)
    assignment = _assign(pred, obs, final_gate)
    # second local pass with the better assignment
    pred = _local_correction(prev, mapped, obs, assignment, neighbours)
    assignment = _assign(pred, obs, final_gate)
    swaps = _detect_swaps(prev, pred, obs, assignment, neighbours, final_gate)
    if fix_swaps and swaps.size:
        a = assignment.copy()
        a[swaps[:, 0]], a[swaps[:, 1]] = assignment[swaps[:, 1]], assignment[swaps[:, 0]]
        assignment = a
    residual = np.full(n, np.nan)
    ok = assignment >= 0
    residual[ok] = np.linalg.norm(obs[assignment[ok]] - pred[ok], axis=1)
    ambiguous = np.zeros(n, bool)
    if fin_obs.sum() >= 2:
        d2, _ = cKDTree(obs[fin_obs]).query(pred, k=2)
        ambiguous = ok & (residual > 0.6 * d2[:, 1])
    return StepMatch(assignment, pred, residual, ambiguous, swaps, m, final_gate)


def _detect_swaps(prev, pred, obs, assignment, k, gate) -> np.ndarray:
    """Pairs (i, j) of neighbouring markers whose exchange reduces both prediction errors markedly."""
    ok = np.flatnonzero(assignment >= 0)
    if ok.size < 4:
        return np.zeros((0, 2), np.int64)
    err = np.full(prev.shape[0], np.nan)
    err[ok] = np.linalg.norm(obs[assignment[ok]] - pred[ok], axis=1)
    scale = np.nanmedian(err) * 4 + 1e-12
    suspects = ok[err[ok] > max(scale, 0.1 * gate)]
    if suspects.size < 2:
        return np.zeros((0, 2), np.int64)
    tree = cKDTree(prev[suspects])
    pairs = tree.query_pairs(r=3 * gate + marker_spacing(prev), output_type="ndarray")
    out = []
    used = set()
    for a, b in pairs:  # suspects are few: this loop is over flagged pairs only
        i, j = suspects[a], suspects[b]
        if i in used or j in used:
            continue
        e_swap_i = np.linalg.norm(obs[assignment[j]] - pred[i])
        e_swap_j = np.linalg.norm(obs[assignment[i]] - pred[j])
        if e_swap_i < 0.5 * err[i] and e_swap_j < 0.5 * err[j]:
            out.append((i, j))
            used.update((i, j))
    return np.array(out, dtype=np.int64).reshape(-1, 2)
