"""Membrane kinematics per triangle, interpolated in cylindrical coordinates.

Each triangle of the ``SurfaceMesh`` is parametrised by the reference cylindrical coordinates
xi = (Theta, Z) of its markers; r, theta, z of the current configuration (and any vector field
given by its cylindrical components) are interpolated linearly in xi. The surface is therefore a
piece of a cylinder-like surface, not a flat chord triangle: flat triangles over-estimate the hoop
virtual work by ~2 % at 300 markers (see ``docs/validation/identification.md``).

Local frame of a triangle (reference configuration): e1 along the circumferential tangent, e2 the
in-plane axial direction orthogonal to it (Gram-Schmidt). Frames and units: ``docs/decisions``;
positions in m, world frame; cylindrical components in the order (radial, circumferential, axial).

Every step is first brought onto the reference by the best rigid motion (Kabsch), so that the
results are objective: a rigid rotation of the deformed markers changes nothing.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_triangular
from scipy.sparse import csr_matrix

from .errors import DegenerateDataError
from .mesh import SurfaceMesh, unique_sorted, wrap_angle
from .step_axes import refit_axes

__all__ = ["AUTO_DEGREES", "Kinematics", "align_steps", "membrane_kinematics", "QUADRATURE", "select_smoothing",
           "smooth_cylindrical", "smoothing_basis"]

log = logging.getLogger(__name__)

# Barycentric quadrature rules on a triangle: (points (n_q, 3), weights (n_q,), summing to 1).
QUADRATURE = {
    1: (np.full((1, 3), 1.0 / 3.0), np.ones(1)),
    3: (np.array([[2 / 3, 1 / 6, 1 / 6], [1 / 6, 2 / 3, 1 / 6], [1 / 6, 1 / 6, 2 / 3]]), np.full(3, 1.0 / 3.0)),
}


def align_steps(positions: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rigidly align every step onto the reference configuration (Kabsch, finite markers only).

    Parameters
    ----------
    positions : ndarray, shape (n_steps, n_markers, 3)
        m, NaN = not observed.
    reference : ndarray, shape (n_markers, 3)

    Returns
    -------
    aligned : ndarray, shape (n_steps, n_markers, 3)
        ``R_m x + t_m`` for each step m.
    rotation : ndarray, shape (n_steps, 3, 3)
    translation : ndarray, shape (n_steps, 3)
    """
    x = np.asarray(positions, dtype=float)
    ref = np.asarray(reference, dtype=float)
    ok = np.all(np.isfinite(x), axis=-1) & np.all(np.isfinite(ref), axis=-1)[None]  # (n_steps, n_markers)
    w = ok.astype(float)
    count = np.maximum(w.sum(1), 1.0)[:, None]
    xz = np.where(ok[..., None], x, 0.0)
    rz = np.where(ok[..., None], ref[None], 0.0)
    cx = xz.sum(1) / count
    cr = rz.sum(1) / count
    H = np.swapaxes(w[..., None] * (xz - cx[:, None]), 1, 2) @ (rz - cr[:, None])  # (s, 3, 3)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, -1, -2) @ np.swapaxes(U, -1, -2)))
    D = np.zeros_like(H)
    D[:, 0, 0] = 1.0
    D[:, 1, 1] = 1.0
    D[:, 2, 2] = d
    R = np.swapaxes(Vt, -1, -2) @ D @ np.swapaxes(U, -1, -2)
    t = cr - (R @ cx[..., None])[..., 0]
    aligned = x @ np.swapaxes(R, 1, 2) + t[:, None]
    return aligned, R, t


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], -1)


@dataclass(frozen=True)
class TriangleGeometry:
    """Static reference quantities per triangle (internal to the stage).

    Attributes
    ----------
    dinv : ndarray, shape (n_tri, 2, 2)
        Inverse of the (Theta, Z) edge matrix: ``grad_xi f = [f1 - f0, f2 - f0] @ dinv``.
    param_area : ndarray, shape (n_tri,)
        Area of the triangle in the (Theta, Z) plane (rad m).
    theta_offset : ndarray, shape (n_tri, 3)
        Per-vertex multiple of 2 pi that unwraps the reference angles across the seam.
    """

    dinv: np.ndarray
    param_area: np.ndarray
    theta_offset: np.ndarray


def triangle_geometry(mesh: SurfaceMesh) -> TriangleGeometry:
    tri = mesh.triangles
    th = mesh.theta[tri]
    unwrapped = th[:, :1] + np.concatenate([np.zeros((len(tri), 1)), wrap_angle(th[:, 1:] - th[:, :1])], axis=1)
    z = mesh.z[tri]
    D0 = np.stack([unwrapped[:, 1:] - unwrapped[:, :1], z[:, 1:] - z[:, :1]], axis=1)  # rows (Theta, Z), cols edges
    det = D0[:, 0, 0] * D0[:, 1, 1] - D0[:, 0, 1] * D0[:, 1, 0]
    if np.any(np.abs(det) <= 0):
        raise DegenerateDataError("a mesh triangle has zero area in the (theta, z) plane")
    # the 2 x 2 inverses by their adjugate (a quarter of np.linalg.inv's time on ~600 small matrices)
    dinv = np.stack([np.stack([D0[:, 1, 1], -D0[:, 0, 1]], -1), np.stack([-D0[:, 1, 0], D0[:, 0, 0]], -1)], -2)
    return TriangleGeometry(dinv=dinv / det[:, None, None], param_area=0.5 * np.abs(det), theta_offset=unwrapped - th)


def _grad(values: np.ndarray, dinv: np.ndarray) -> np.ndarray:
    """Vertex values ``(..., n_tri, 3)`` -> xi-gradient ``(..., n_tri, 2)``."""
    delta = values[..., 1:] - values[..., :1]
    # the two-term sum written out: ~3x faster than einsum's generic loop over the batch axes, same numbers
    return delta[..., :1] * dinv[:, 0] + delta[..., 1:] * dinv[:, 1]


@dataclass(frozen=True)
class SurfaceState:
    """Interpolated reference and current quantities at the quadrature points (internal).

    Shapes: ``(n_steps, n_tri, n_q)`` for values, with a trailing axis of 2 for xi-derivatives.
    """

    R: np.ndarray       # (n_tri, n_q) reference radius at the marker surface
    R_xi: np.ndarray    # (n_tri, 2)
    r: np.ndarray       # (n_steps, n_tri, n_q)
    r_xi: np.ndarray    # (n_steps, n_tri, 2)
    theta: np.ndarray   # (n_steps, n_tri, n_q) current angle
    theta_xi: np.ndarray
    z_xi: np.ndarray
    valid: np.ndarray   # (n_steps, n_tri) bool
    outliers: np.ndarray  # (n_steps, n_markers) bool, markers set unobserved by marker_outliers
    noise: np.ndarray     # (n_steps,) estimated marker noise (m)
    r_markers: np.ndarray      # (n_steps, n_markers) current cylindrical coordinates of the markers
    theta_markers: np.ndarray
    z_markers: np.ndarray
    axes: tuple
    bary: np.ndarray    # (n_q, 3)
    qweight: np.ndarray  # (n_q,)
    geometry: TriangleGeometry
    smoothing: tuple | None = None  # degrees used: three (nz, nt) pairs (r, theta, z), or None


def step_cylindrical(mesh: SurfaceMesh, aligned: np.ndarray):
    """Cylindrical coordinates of every step about its own fitted axis.

    The axis of each (rigidly aligned) step is refitted from its own markers, starting from the
    reference axis, so that a non-rigid deformation that fools the rigid alignment (e.g. an axial
    stretch of an unevenly marked tube) does not tilt the axis.

    Returns ``r, theta, z`` of shape (n_steps, n_markers) and the list of step axes.
    """
    observed = np.all(np.isfinite(aligned), axis=-1) & mesh.used
    axes = refit_axes(aligned, observed, mesh.axis)
    origin = np.stack([a.origin for a in axes])  # (n_steps, 3)
    basis = np.stack([a.basis for a in axes])  # (n_steps, 3, 3)
    local = (aligned - origin[:, None]) @ np.swapaxes(basis, 1, 2)  # (n_steps, n_markers, 3)
    return np.hypot(local[..., 0], local[..., 1]), np.arctan2(local[..., 1], local[..., 0]), local[..., 2], axes


#: Candidate smoothing bases (axial Legendre degree, circumferential harmonics) searched by
#: ``select_smoothing`` (``smoothing="auto"``).
AUTO_DEGREES = tuple((nz, nt) for nz in range(0, 9) for nt in range(0, 5))
#: Estimated marker noise (m) below which ``smoothing="auto"`` leaves the markers unsmoothed (exact data).
EXACT_MARKERS = 0.5e-6
#: ``smoothing`` strings: the basis chosen from the data by this criterion (``select_smoothing``).
SELECTION_CRITERIA = {"auto": "gcv", "bic": "bic"}
#: A candidate basis may use at most this fraction of the observed markers of a step.
MAX_BASIS_FRACTION = 1.0 / 3.0


def smoothing_basis(mesh: SurfaceMesh, degree: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Legendre(Z) x Fourier(Theta) functions at the reference markers.

    Returns ``basis`` of shape (n_markers, (degree[0] + 1) (2 degree[1] + 1)) and the markers
    usable for fitting, shape (n_markers,) bool. Columns of the largest basis (at least the
    ``AUTO_DEGREES`` ones) evaluated once for the last mesh asked: the same numbers (the Legendre
    recurrence and the harmonics do not depend on the degree asked), without re-evaluating them for
    every candidate of ``select_smoothing`` and every component of ``smooth_cylindrical``.
    """
    global _BASIS_CACHE
    nz, nt = int(degree[0]), int(degree[1])
    cached, full, ok_ref, (cz, ct) = _BASIS_CACHE
    if cached is not mesh or nz > cz or nt > ct:
        cz, ct = max(nz, _AUTO_NZ), max(nt, _AUTO_NT)
        full, ok_ref = _evaluate_basis(mesh, cz, ct)
        _BASIS_CACHE = (mesh, full, ok_ref, (cz, ct))  # one assignment: safe with other threads
    cols = (np.arange(2 * nt + 1)[:, None] * (cz + 1) + np.arange(nz + 1)[None]).ravel()
    return full[:, cols], ok_ref


#: (mesh, basis, usable markers, (nz, nt)) of the last ``smoothing_basis`` evaluation.
_BASIS_CACHE: tuple = (None, None, None, (-1, -1))
_AUTO_NZ = max(d[0] for d in AUTO_DEGREES)
_AUTO_NT = max(d[1] for d in AUTO_DEGREES)


def _evaluate_basis(mesh: SurfaceMesh, nz: int, nt: int) -> tuple[np.ndarray, np.ndarray]:
    """``smoothing_basis(mesh, (nz, nt))`` evaluated (no cache)."""
    Z, T = mesh.z, mesh.theta
    ok_ref = mesh.used & np.isfinite(Z)
    z0 = 0.5 * (np.nanmax(Z[ok_ref]) + np.nanmin(Z[ok_ref]))
    half = 0.5 * (np.nanmax(Z[ok_ref]) - np.nanmin(Z[ok_ref]))
    leg = np.polynomial.legendre.legvander(np.nan_to_num((Z - z0) / half), nz)
    four = [np.ones_like(T)] + [f(k * np.nan_to_num(T)) for k in range(1, nt + 1) for f in (np.cos, np.sin)]
    return np.concatenate([leg * f[:, None] for f in four], axis=1), ok_ref


def smoothing_basis_derivative(mesh: SurfaceMesh, degree: tuple[int, int], axis: int) -> np.ndarray:
    """Derivative of ``smoothing_basis`` with respect to Theta (``axis=0``, per rad) or Z (``axis=1``,
    per m), shape (n_markers, n_basis)."""
    nz, nt = int(degree[0]), int(degree[1])
    Z, T = mesh.z, np.nan_to_num(mesh.theta)
    ok_ref = mesh.used & np.isfinite(Z)
    z0 = 0.5 * (np.nanmax(Z[ok_ref]) + np.nanmin(Z[ok_ref]))
    half = 0.5 * (np.nanmax(Z[ok_ref]) - np.nanmin(Z[ok_ref]))
    x = np.nan_to_num((Z - z0) / half)
    leg = np.polynomial.legendre.legvander(x, nz)
    four = [np.ones_like(T)] + [f(k * T) for k in range(1, nt + 1) for f in (np.cos, np.sin)]
    if axis == 1:
        eye = np.eye(nz + 1)
        dleg = np.stack([np.polynomial.legendre.legval(x, np.polynomial.legendre.legder(eye[j]))
                         if nz else np.zeros_like(x) for j in range(nz + 1)], axis=1) / half
        return np.concatenate([dleg * f[:, None] for f in four], axis=1)
    dfour = [np.zeros_like(T)] + [g for k in range(1, nt + 1) for g in (-k * np.sin(k * T), k * np.cos(k * T))]
    return np.concatenate([leg * f[:, None] for f in dfour], axis=1)


def regressor_noise_correction(mesh: SurfaceMesh, degree, fit: np.ndarray, variance: float, axis: int) -> np.ndarray:
    """Remove the errors-in-variables bias of a smoothed displacement component (n_steps, n_markers).

    The smoothing regresses ``x - X`` on functions of the *measured* reference coordinates X, whose
    noise n0 also enters the data with the opposite sign (d = u(X - n0) - n0 + n = u(X) - F n0 + n):
    the fit is biased by ``-variance (B^T B)^-1 sum_i dB/dX(X_i) F(X_i)`` (Stein's lemma, first order),
    e.g. the axial stretch by -lambda sigma^2 / var(Z) (a sigma^2 bias of ~0.5 % on E22 at 0.17 mm
    over 27 mm). Returns ``fit`` with that bias added back; ``axis`` 0 = Theta, 1 = Z.
    """
    basis, ok_ref = smoothing_basis(mesh, degree)
    dbasis = smoothing_basis_derivative(mesh, degree, axis)
    B, dB = basis[ok_ref], dbasis[ok_ref]
    f = np.where(np.isfinite(fit[:, ok_ref]), fit[:, ok_ref], 0.0)  # (s, n_ok), the fitted field (in the span)
    coef, *_ = np.linalg.lstsq(B, f.T, rcond=None)  # (p, s)
    grad = 1.0 + (dB @ coef).T  # (s, n_ok) dx/dX of the component along its own coordinate
    moved = np.any(np.abs(f) > 0, axis=1)  # the reference step (d = X - X = 0) has no such bias
    shift = np.linalg.solve(B.T @ B, dB.T @ grad.T) * variance * moved  # (p, s)
    return fit + np.where(ok_ref, (basis @ shift).T, 0.0)


def _displacements(mesh: SurfaceMesh, r, theta, z) -> list[np.ndarray]:
    """Cylindrical displacement components (r - R, wrapped theta - Theta, z - Z), each (n_steps, n_markers)."""
    return [r - mesh.r[None], wrap_angle(theta - mesh.theta[None]), z - mesh.z[None]]


def _unique_rows(ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(ok, axis=0, return_inverse=True)`` of a boolean (n_rows, n) array, same rows in the same
    (lexicographic) order, without its structured-dtype overhead (~1 ms a call; a bootstrap makes ~100):
    the rows are packed into bytes (first element the most significant bit) and compared as such."""
    packed = np.ascontiguousarray(np.packbits(ok, axis=1))
    keys = packed.view(np.dtype((np.void, packed.shape[1]))).ravel()
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    return ok[first], inverse.ravel()


def _fit_basis(basis, ok_ref, d, weights=None):
    """Weighted least-squares projection of every step of ``d`` (n_steps, n_markers) on ``basis``.

    Returns the fitted values at every marker of the reference mesh (also where a step did not
    observe it; NaN elsewhere), the weighted residual sum of squares and the number of observations
    per step, shape (n_steps,).
    """
    ok = ok_ref[None] & np.isfinite(d)
    w = np.ones_like(d) if weights is None else np.where(np.isfinite(weights), weights, 0.0)
    sw = np.sqrt(np.where(ok, w, 0.0))
    fit = np.full_like(d, np.nan)
    rss = np.zeros(d.shape[0])
    count = ok.sum(axis=1)
    masks, inverse = _unique_rows(ok)
    few = masks.sum(axis=1) <= basis.shape[1]
    if few.any():
        raise DegenerateDataError(
            f"smoothing with {basis.shape[1]} basis functions needs more observed markers than that; steps "
            f"{np.flatnonzero(few[inverse]).tolist()} have {masks.sum(axis=1)[few].tolist()}")
    if weights is None:
        try:
            fit = _fit_normal(basis, ok_ref, d, ok, masks, inverse)
        except np.linalg.LinAlgError:  # a singular Gram matrix: the SVD least squares below copes
            pass
        else:
            return fit, np.nansum(np.where(ok, (d - fit) ** 2, 0.0), axis=1), count
    for g, mask in enumerate(masks):  # steps sharing the same observed markers share one factorisation
        steps = np.flatnonzero(inverse.ravel() == g)
        if weights is None:
            coef, *_ = np.linalg.lstsq(basis[mask], d[steps][:, mask].T, rcond=None)  # (n_basis, n_group)
            fit[steps] = np.where(ok_ref, (basis @ coef).T, np.nan)
        else:
            for k in steps:
                coef, *_ = np.linalg.lstsq(basis[mask] * sw[k, mask, None], d[k, mask] * sw[k, mask], rcond=None)
                fit[k] = np.where(ok_ref, basis @ coef, np.nan)
    rss = np.nansum(np.where(ok, w * (d - fit) ** 2, 0.0), axis=1)
    return fit, rss, count


def _fit_normal(basis, ok_ref, d, ok, masks, inverse) -> np.ndarray:
    """The unweighted projections of ``_fit_basis`` from the normal equations, every step at once (one
    Gram matrix per set of observed markers ``masks``, steps -> set ``inverse``): ~4x faster than an SVD
    least squares per set and the same fit to ~1e-12 (these bases are well conditioned, as in
    ``_ProjectionRSS``). Raises ``LinAlgError`` on a singular Gram matrix."""
    gram = (basis.T[None] * masks[:, None, :]) @ basis  # (n_masks, P, P)
    bty = np.where(ok, d, 0.0) @ basis  # (n_steps, P)
    coef = np.linalg.solve(gram[inverse], bty[..., None])[..., 0]  # (n_steps, P)
    return np.where(ok_ref[None], coef @ basis.T, np.nan)


class _ProjectionRSS:
    """Residual sums of squares of the unweighted least-squares projections of every step of every
    component of ``d`` (n_components, n_steps, n_markers) on the candidate smoothing bases.

    Same quantity as ``_fit_basis(basis, ok_ref, d[c])[1:]`` (to ~1e-10 relative), much faster:
    every candidate basis is a set of columns of the largest one (``smoothing_basis`` evaluates the
    same Legendre recurrence and harmonics), so the Gram matrices of each set of observed markers
    and the projections of the data are formed once, and each candidate solves its sub-blocks
    (normal equations: these bases are well conditioned) and takes the residuals explicitly.
    """

    def __init__(self, mesh: SurfaceMesh, candidates, d: np.ndarray):
        self.nz = max(int(c[0]) for c in candidates)
        self.nt = max(int(c[1]) for c in candidates)
        self.basis, ok_ref = smoothing_basis(mesh, (self.nz, self.nt))  # (n_markers, P)
        n_c, n_s, n_m = d.shape
        ok = ok_ref[None, None] & np.isfinite(d)
        self.shape = (n_c, n_s)
        self.count = ok.sum(axis=2)  # (n_c, n_s)
        masks, inverse = _unique_rows(ok.reshape(-1, n_m))
        self.n_mask = masks.sum(axis=1)
        self.inverse = inverse.ravel()
        self.gram = (self.basis.T[None] * masks[:, None, :]) @ self.basis  # (n_masks, P, P)
        self.ok = ok.reshape(-1, n_m)
        self.y = np.where(self.ok, d.reshape(-1, n_m), 0.0)  # (n_rows, n_markers)
        self.bty = self.y @ self.basis  # (n_rows, P)
        self._blocks = None  # {(nz, nt): rss (n_c, n_s)} of ``_leading_blocks``, once asked

    def _leading_blocks(self) -> dict:
        """RSS of every (nz <= self.nz, nt) basis at once: with the columns in Legendre-degree-major order
        the bases (0..nz, nt) are leading blocks, whose RSS are ``|y|^2`` minus the running sums of the
        squared forward-substituted projections (one batched Cholesky factor per number of harmonics; y
        centred per row, as the constant is in every basis). The same RSS to ~1e-10 relative, ~5x faster
        than a solve per candidate. {} if a Gram matrix is not positive definite."""
        count = np.maximum(self.ok.sum(axis=1), 1)
        yc = np.where(self.ok, self.y - (self.y.sum(axis=1) / count)[:, None], 0.0)
        yy = np.sum(yc**2, axis=1)  # (n_rows,)
        groups = [np.flatnonzero(self.inverse == g) for g in range(len(self.gram))]
        out = {}
        for nt in range(self.nt + 1):
            cols = (np.arange(self.nz + 1)[:, None] + (self.nz + 1) * np.arange(2 * nt + 1)[None]).ravel()
            try:
                chol = np.linalg.cholesky(self.gram[:, cols[:, None], cols[None, :]])  # (n_masks, q, q)
            except np.linalg.LinAlgError:
                return {}
            rhs = yc @ self.basis[:, cols]  # (n_rows, q)
            proj = np.empty_like(rhs)
            for g, rows in enumerate(groups):  # forward substitution, the rows of one set of markers at once
                proj[rows] = solve_triangular(chol[g], rhs[rows].T, lower=True, check_finite=False).T
            rss = np.maximum(yy[:, None] - np.cumsum(proj**2, axis=1), 0.0)  # (n_rows, q)
            for nz in range(self.nz + 1):
                out[nz, nt] = rss[:, (nz + 1) * (2 * nt + 1) - 1].reshape(self.shape)
        return out

    def columns(self, degree) -> np.ndarray:
        """Columns of the largest basis that make ``smoothing_basis(mesh, degree)`` (same order)."""
        nz, nt = int(degree[0]), int(degree[1])
        return (np.arange(2 * nt + 1)[:, None] * (self.nz + 1) + np.arange(nz + 1)[None]).ravel()

    def __call__(self, degree) -> list[tuple[np.ndarray, np.ndarray]]:
        """One (rss (n_steps,), count (n_steps,)) pair per component for the basis ``degree``."""
        cols = self.columns(degree)
        if self.n_mask.min() <= len(cols):
            raise DegenerateDataError(
                f"smoothing with {len(cols)} basis functions needs more observed markers than that; some steps "
                f"have {int(self.n_mask.min())}")
        if self._blocks is None:
            self._blocks = self._leading_blocks()
        if (int(degree[0]), int(degree[1])) in self._blocks:
            rss = self._blocks[int(degree[0]), int(degree[1])]
            return [(rss[c], self.count[c]) for c in range(self.shape[0])]
        gram = self.gram[:, cols[:, None], cols[None, :]][self.inverse]  # (n_rows, p, p)
        coef = np.linalg.solve(gram, self.bty[:, cols, None])[..., 0]  # (n_rows, p)
        resid = np.where(self.ok, self.y - coef @ self.basis[:, cols].T, 0.0)
        rss = np.sum(resid**2, axis=1).reshape(self.shape)
        return [(rss[c], self.count[c]) for c in range(self.shape[0])]


def smooth_cylindrical(mesh: SurfaceMesh, r, theta, z, degree, weights: np.ndarray | None = None,
                       reference_noise: float | None = None):
    """Least-squares smoothing of the displacement field of every step.

    Each cylindrical displacement component (r - R, theta - Theta, z - Z) of a step is replaced by
    its projection on Legendre polynomials of the reference Z (degree ``degree[0]``) times a
    Fourier series in Theta (``degree[1]`` harmonics), fitted to the observed markers. Noise
    averages out at the cost of a bias where the true field varies faster than the basis.
    A marker of the reference mesh that a step did not observe gets the fitted field there, so that
    its triangles still count in the balance (leaving them out biases the axial virtual work,
    whose external part is the whole measured force, by the missing area: ~7 % on the default
    simulated rig).

    Parameters
    ----------
    r, theta, z : ndarray, shape (n_steps, n_markers)
    degree : (int, int), or three such pairs (one per component r, theta, z; ``select_smoothing``)
    weights : ndarray, shape (n_steps, n_markers), optional
        Relative weights of the markers (1 / variance, e.g. from the reconstruction's reported
        uncertainty); default equal.
    reference_noise : float, optional
        Standard deviation (m) of the reference markers' coordinates: the errors-in-variables bias
        it causes in the theta and z components is removed (``regressor_noise_correction``).

    Returns
    -------
    r, theta, z : ndarray, shape (n_steps, n_markers); NaN only at markers outside the mesh.
    """
    degrees = per_component_degrees(degree)
    out = []
    for c, (d, refv, deg) in enumerate(zip(_displacements(mesh, r, theta, z), (mesh.r, mesh.theta, mesh.z), degrees)):
        basis, ok_ref = smoothing_basis(mesh, deg)
        fit, _, _ = _fit_basis(basis, ok_ref, d, weights)
        if reference_noise and c > 0:
            variance = (reference_noise / mesh.axis.radius) ** 2 if c == 1 else reference_noise**2
            fit = regressor_noise_correction(mesh, deg, fit, variance, axis=c - 1)
        out.append(refv[None] + fit)
    return out[0], out[1], out[2]


def per_component_degrees(degree) -> tuple[tuple[int, int], ...]:
    """``(nz, nt)`` or ``((nz, nt),) * 3`` -> three (nz, nt) pairs for the r, theta, z components."""
    arr = np.asarray(degree, dtype=int)
    if arr.shape == (2,):
        arr = np.repeat(arr[None], 3, axis=0)
    if arr.shape != (3, 2) or arr.min() < 0:
        raise ValueError(f"smoothing must be (axial degree, harmonics) or three such pairs (r, theta, z), "
                         f"non-negative; got {degree!r}")
    return tuple((int(a), int(b)) for a, b in arr)


def select_smoothing(mesh: SurfaceMesh, r, theta, z, *, weights: np.ndarray | None = None,
                     candidates=AUTO_DEGREES, criterion: str = "gcv") -> tuple[tuple[tuple[int, int], ...], np.ndarray]:
    """Smoothing basis of each displacement component chosen from the data (generalised cross-validation).

    For every candidate (axial degree, harmonics) and component the projection's GCV score
    ``RSS / (n (1 - p / n)^2)`` (p basis functions, n observed markers) is summed over the steps;
    one basis per component is kept for all steps, so the displacements stay in one space as the
    load grows. Candidates with more than ``MAX_BASIS_FRACTION`` of the observed markers are skipped.
    ``criterion="bic"``: the Bayesian information criterion ``n log(RSS / n) + p log n`` summed over
    the steps instead (a stronger penalty per function: at 300 markers GCV keeps a function that
    lowers the RSS by ~2 noise variances, BIC asks for ~5.7).

    Returns
    -------
    degrees : three (nz, nt) pairs, for the r, theta, z components.
    scores : ndarray, shape (n_candidates, 3); inf for skipped candidates.
    """
    disp = _displacements(mesh, r, theta, z)
    n_obs = int(np.min(np.sum(np.isfinite(disp[0]) & mesh.used[None], axis=1)))
    scores = np.full((len(candidates), 3), np.inf)
    projections = _ProjectionRSS(mesh, candidates, np.stack(disp)) if weights is None else None
    for i, deg in enumerate(candidates):
        basis, ok_ref = smoothing_basis(mesh, deg)
        p = basis.shape[1]
        if p > MAX_BASIS_FRACTION * n_obs:
            continue
        try:  # unweighted: the three components at once, from one set of Gram matrices
            fits = projections(deg) if projections is not None else None
        except np.linalg.LinAlgError:  # a singular Gram matrix: the SVD least squares copes
            fits = None
        if fits is None:
            fits = [_fit_basis(basis, ok_ref, d, weights)[1:] for d in disp]
        for c, (rss, n) in enumerate(fits):
            if criterion == "bic":
                scores[i, c] = float(np.sum(n * np.log(np.maximum(rss, 1e-300) / n) + p * np.log(n)))
            else:
                scores[i, c] = float(np.sum(rss / (n * (1.0 - p / n) ** 2)))
    if not np.isfinite(scores).any():
        raise DegenerateDataError(f"too few observed markers ({n_obs}) to choose a smoothing basis")
    best = np.argmin(scores, axis=0)
    return tuple(tuple(candidates[b]) for b in best), scores


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
    pair_vals = np.concatenate([A[:, k] * A[:, l] for k, l in _PAIRS])
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


def surface_state(mesh: SurfaceMesh, aligned: np.ndarray, quadrature: int = 1,
                  smoothing: tuple | str | None = None, reject_outliers: bool = True,
                  weights: np.ndarray | None = None, smooth_reference: bool = False,
                  reference_noise_correction: bool = False, estimate_noise: bool = True) -> SurfaceState:
    """Cylindrical interpolation of the aligned positions ``(n_steps, n_markers, 3)``.

    ``smoothing=(axial degree, circumferential harmonics)`` smooths the displacement field first
    (``smooth_cylindrical``); ``"auto"`` chooses the basis of each component from the data
    (``select_smoothing``) unless the markers look exact (estimated noise below ``EXACT_MARKERS``).
    ``weights`` (n_steps, n_markers): relative marker weights (1 / variance) of the smoothing fit.
    ``smooth_reference`` (with smoothing): the reference radius too is replaced by its smooth fit
    (``smooth_reference_radius``), so the noise of the reference markers' radius does not enter the
    reference metric (its slope noise biases the strains by ~sigma^2, see docs "Noise").
    ``reference_noise_correction`` (with smoothing): remove the errors-in-variables bias that the
    reference markers' own noise (estimated from the reference step) causes in the smoothed field.
    ``estimate_noise=False`` (with ``reject_outliers=False``, a given smoothing basis and no reference noise
    correction, as a bootstrap replicate): skip ``marker_outliers``, whose noise estimate (``noise``, NaN then) is
    then used by nothing. ``reject_outliers`` first sets mis-tracked markers (``marker_outliers``)
    to NaN in the steps where they disagree with their neighbours. Triangles that are inverted in a step (a noisy marker crossed an
    edge) are excluded from that step like unobserved ones.
    """
    if quadrature not in QUADRATURE:
        raise ValueError(f"quadrature must be one of {sorted(QUADRATURE)}; got {quadrature}")
    bary, qw = QUADRATURE[quadrature]
    geo = triangle_geometry(mesh)
    tri = mesh.triangles
    r, th, z, axes = step_cylindrical(mesh, aligned)  # (n_steps, n_markers)
    if estimate_noise or reject_outliers or isinstance(smoothing, str) or reference_noise_correction:
        outliers, noise = marker_outliers(mesh, r, th, z)
    else:
        outliers, noise = np.zeros(r.shape, bool), np.full(r.shape[0], np.nan)
    if reject_outliers:
        if outliers.any():
            log.warning("markers disagreeing with their neighbours (set unobserved) per step: %s",
                        outliers.sum(axis=1).tolist())
            r, th, z = (np.where(outliers, np.nan, a) for a in (r, th, z))
    else:
        outliers = np.zeros(r.shape, bool)
    smoothing = resolve_smoothing(mesh, r, th, z, smoothing, noise, weights)
    R_ref = mesh.r
    if smoothing is not None:
        # the reference step's own "noise" is 0 (d = X - X); the reference markers are measured like the others
        level = float(np.nanmedian(noise[1:])) if reference_noise_correction and noise.size > 1 else float("nan")
        ref_noise = level if reference_noise_correction and np.isfinite(level) else None
        r, th, z = smooth_cylindrical(mesh, r, th, z, smoothing, weights, reference_noise=ref_noise)
        if smooth_reference:
            R_ref = smooth_reference_radius(mesh)
            r = r + (R_ref - mesh.r)[None]  # same displacement, from the smooth reference surface
    cyl = np.stack([r, th, z])[:, :, tri]  # (r, theta, z) at the vertices: (3, n_steps, n_tri, 3)
    valid = np.all(np.isfinite(cyl), axis=(0, -1))
    # unwrap the current angles of each triangle relative to its first vertex
    thv = cyl[1]
    cyl[1] = thv[..., :1] + np.concatenate([np.zeros_like(thv[..., :1]), wrap_angle(thv[..., 1:] - thv[..., :1])], -1)
    cyl = np.where(valid[..., None], cyl, 0.0)
    rv, thv, zv = cyl
    Rv = R_ref[tri]
    r_xi, theta_xi, z_xi = _grad(cyl, geo.dinv)
    jac = theta_xi[..., 0] * z_xi[..., 1] - theta_xi[..., 1] * z_xi[..., 0]
    inverted = valid & ~(jac > 0.05)  # area in (theta, z) shrunk 20-fold or flipped: a marker crossed an edge
    if inverted.any():
        log.warning("excluded inverted/collapsed triangles per step: %s", inverted.sum(axis=1).tolist())
        valid = valid & ~inverted
    return SurfaceState(
        R=Rv @ bary.T, R_xi=_grad(Rv, geo.dinv),
        r=rv @ bary.T, r_xi=r_xi,
        theta=thv @ bary.T, theta_xi=theta_xi, z_xi=z_xi,
        valid=valid, outliers=outliers, noise=noise, r_markers=r, theta_markers=th, z_markers=z, axes=tuple(axes),
        bary=bary, qweight=qw, geometry=geo, smoothing=smoothing,
    )


def smooth_reference_radius(mesh: SurfaceMesh, candidates=AUTO_DEGREES) -> np.ndarray:
    """The reference radius of the markers, shape (n_markers,), replaced by its least-squares fit on
    the Legendre(Z) x Fourier(Theta) basis chosen by generalised cross-validation (as
    ``select_smoothing``); NaN outside the mesh."""
    R = np.where(mesh.used, mesh.r, np.nan)[None]
    n_obs = int(np.sum(np.isfinite(R)))
    scores = _nested_gcv(mesh, candidates, R[0])
    best, best_score = None, np.inf
    projections = None
    for deg in candidates:
        p = (int(deg[0]) + 1) * (2 * int(deg[1]) + 1)
        if p > MAX_BASIS_FRACTION * n_obs:
            continue
        score = scores.get(tuple(deg)) if scores is not None else None
        if score is None:  # a singular Gram matrix: the projections, or the SVD least squares, cope
            projections = projections or _ProjectionRSS(mesh, candidates, R[None])
            try:
                ((rss, n),) = projections(deg)
            except np.linalg.LinAlgError:
                _, rss, n = _fit_basis(*smoothing_basis(mesh, deg), R)
            score = float(rss[0] / (n[0] * (1.0 - p / n[0]) ** 2))
        if score < best_score:
            best, best_score = deg, score
    if best is None:
        raise DegenerateDataError(f"too few markers ({n_obs}) to smooth the reference radius")
    best_fit = _fit_basis(*smoothing_basis(mesh, best), R)[0][0]
    log.info("reference radius smoothed on (axial degree, harmonics) %s", best)
    return np.where(mesh.used, best_fit, np.nan)


def _nested_gcv(mesh: SurfaceMesh, candidates, values: np.ndarray) -> dict | None:
    """GCV score ``RSS / (n (1 - p / n)^2)`` of the least-squares fit of ``values`` (n_markers,) on every
    candidate basis ``(nz, nt)``, from one Cholesky factor per number of harmonics: with the columns in
    Legendre-degree-major order the bases (0..nz, nt) are leading blocks, whose RSS are ``|y|^2`` minus the
    running sums of the squared forward-substituted projections (y centred: the constant is in every
    basis). ~10x faster than a solve per candidate (the bootstrap does it once per replicate); the
    same scores to ~1e-10. None if a Gram matrix is singular."""
    nz_max = max(int(c[0]) for c in candidates)
    nt_max = max(int(c[1]) for c in candidates)
    basis, ok_ref = smoothing_basis(mesh, (nz_max, nt_max))  # columns: harmonic h, degree j at h (nz_max + 1) + j
    ok = ok_ref & np.isfinite(values)
    n = int(ok.sum())
    y = values[ok] - np.mean(values[ok])
    B = basis[ok]
    scores = {}
    for nt in sorted({int(c[1]) for c in candidates}):
        cols = (np.arange(nz_max + 1)[:, None] + (nz_max + 1) * np.arange(2 * nt + 1)[None]).ravel()
        Bn = B[:, cols]
        try:
            chol = np.linalg.cholesky(Bn.T @ Bn)
        except np.linalg.LinAlgError:
            return None
        proj = solve_triangular(chol, Bn.T @ y, lower=True)
        rss = np.maximum(float(y @ y) - np.cumsum(proj**2), 0.0)
        for nz in range(nz_max + 1):
            p = (nz + 1) * (2 * nt + 1)
            if p < n:
                scores[(nz, nt)] = float(rss[p - 1] / (n * (1.0 - p / n) ** 2))
    return scores


def resolve_smoothing(mesh: SurfaceMesh, r, theta, z, smoothing, noise, weights=None):
    """The smoothing degrees to use: None, three (nz, nt) pairs, chosen from the data for ``"auto"``."""
    if smoothing is None:
        return None
    if isinstance(smoothing, str):
        if smoothing not in SELECTION_CRITERIA:
            raise ValueError(f"smoothing must be None, one of {tuple(SELECTION_CRITERIA)} or (axial degree, harmonics); "
                             f"got {smoothing!r}")
        level = float(np.nanmedian(noise))
        if not level > EXACT_MARKERS:
            log.info("estimated marker noise %.2g mm: markers look exact, not smoothing", level * 1e3)
            return None
        degrees, _ = select_smoothing(mesh, r, theta, z, weights=weights, criterion=SELECTION_CRITERIA[smoothing])
        log.info("estimated marker noise %.2g mm: smoothing (axial degree, harmonics) r %s, theta %s, z %s "
                 "chosen by %s", level * 1e3, *degrees, SELECTION_CRITERIA[smoothing])
        return degrees
    return per_component_degrees(smoothing)


def reference_frame(R_xi: np.ndarray, R_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gram-Schmidt local frame of the reference surface.

    Returns ``ginv (..., 2, 2)`` mapping xi-components to local (circumferential, axial) ones
    (``F = F_xi @ ginv``) and the area factor ``|T_Theta x T_Z|`` (m per rad) of shape ``(...)``.
    """
    R_t = R_xi[..., 0]
    R_z = R_xi[..., 1]
    a = np.sqrt(R_t**2 + R_s**2)
    b = R_t * R_z / a
    c = np.sqrt(R_z**2 + 1.0 - b**2)
    zero = np.zeros_like(a)
    ginv = np.stack([np.stack([1.0 / a, -b / (a * c)], -1), np.stack([zero, 1.0 / c], -1)], -2)
    return ginv, a * c


def tangents(r_s, r_s_xi, theta_xi, z_xi) -> np.ndarray:
    """Current tangent vectors ``F_xi`` (..., 3, 2) in the local cylindrical basis (r, theta, z)."""
    cols = [np.stack([r_s_xi[..., j], r_s * theta_xi[..., j], np.broadcast_to(z_xi[..., j], r_s.shape)], -1)
            for j in (0, 1)]
    return np.stack(cols, -1)


@dataclass(frozen=True)
class Kinematics:
    """Per-triangle membrane kinematics at the triangle centroids (marker surface).

    Attributes
    ----------
    F : ndarray, shape (n_steps, n_triangles, 3, 2)
        Deformation gradient from the local reference frame (circumferential, axial) to current
        cylindrical components (radial, circumferential, axial) at the centroid.
    C, E : ndarray, shape (n_steps, n_triangles, 2, 2)
        Right Cauchy-Green and Green-Lagrange tensors in the local frame.
    area_ratio : ndarray, shape (n_steps, n_triangles)
        a / A = sqrt(det C).
    thickness : ndarray, shape (n_steps, n_triangles)
        e0 / (a / A) from incompressibility (m); NaN if no reference thickness was given.
    normal : ndarray, shape (n_steps, n_triangles, 3)
        Outward unit normal, world frame.
    centroid : ndarray, shape (n_steps, n_triangles, 3)
        Interpolated centroid, world frame (m).
    reference_area : ndarray, shape (n_triangles,)
        m^2.
    valid : ndarray, shape (n_steps, n_triangles) bool
        False where a vertex was not observed (all other arrays are NaN there).
    """

    F: np.ndarray
    C: np.ndarray
    E: np.ndarray
    area_ratio: np.ndarray
    thickness: np.ndarray
    normal: np.ndarray
    centroid: np.ndarray
    reference_area: np.ndarray
    valid: np.ndarray


def membrane_kinematics(mesh: SurfaceMesh, positions: np.ndarray, *, thickness: float | None = None,
                        reference: np.ndarray | None = None) -> Kinematics:
    """Deformation of every triangle from the reference to each step.

    Parameters
    ----------
    mesh : SurfaceMesh
    positions : ndarray, shape (n_steps, n_markers, 3)
        Marker positions (m, world frame), NaN = not observed.
    thickness : float, optional
        Reference wall thickness e0 (m).
    reference : ndarray, shape (n_markers, 3), optional
        Reference positions (default: rebuilt from the mesh).
    """
    x = np.asarray(positions, dtype=float)
    if x.ndim != 3 or x.shape[1:] != (mesh.n_markers, 3):
        raise ValueError(f"positions must have shape (n_steps, {mesh.n_markers}, 3); got {x.shape}")
    if reference is None:
        local = np.column_stack([mesh.r * np.cos(mesh.theta), mesh.r * np.sin(mesh.theta), mesh.z])
        reference = local @ mesh.axis.basis + mesh.axis.origin
    aligned, rot, trans = align_steps(x, reference)
    st = surface_state(mesh, aligned, 1)
    ginv, area_factor = reference_frame(st.R_xi[:, None, :], st.R)  # (n_tri, 1, 2, 2)
    Fxi = tangents(st.r, st.r_xi[:, :, None, :], st.theta_xi[:, :, None, :], st.z_xi[:, :, None, :])
    F = (Fxi @ ginv)[:, :, 0]
    C = np.swapaxes(F, -1, -2) @ F
    nan = ~st.valid
    area_ratio = np.sqrt(np.linalg.det(C))
    n_cyl = _cross(Fxi[..., 0], Fxi[..., 1])[:, :, 0]
    n_cyl /= np.linalg.norm(n_cyl, axis=-1, keepdims=True)
    th = st.theta[:, :, 0]
    cos, sin = np.cos(th), np.sin(th)
    n_spec = np.stack([n_cyl[..., 0] * cos - n_cyl[..., 1] * sin, n_cyl[..., 0] * sin + n_cyl[..., 1] * cos,
                       n_cyl[..., 2]], -1)
    zv = np.where(st.valid[..., None], st.z_markers[:, mesh.triangles], np.nan)
    zc = zv.mean(-1)
    c_spec = np.stack([st.r[:, :, 0] * cos, st.r[:, :, 0] * sin, zc], -1)
    # back from each step's specimen frame to the world frame of that step
    basis = np.stack([a.basis for a in st.axes])
    origin = np.stack([a.origin for a in st.axes])
    n_aligned = np.einsum("stj,sji->sti", n_spec, basis)
    c_aligned = np.einsum("stj,sji->sti", c_spec, basis) + origin[:, None]
    normal = np.einsum("sji,stj->sti", rot, n_aligned)
    centroid = np.einsum("sji,stj->sti", rot, c_aligned - trans[:, None])
    e0 = np.nan if thickness is None else float(thickness)

    def mask(a):
        return np.where(nan.reshape(nan.shape + (1,) * (a.ndim - 2)), np.nan, a)

    E = 0.5 * (C - np.eye(2))
    return Kinematics(F=mask(F), C=mask(C), E=mask(E), area_ratio=mask(area_ratio), thickness=mask(e0 / area_ratio),
                      normal=mask(normal), centroid=mask(centroid),
                      reference_area=st.geometry.param_area * area_factor[:, 0], valid=st.valid)
