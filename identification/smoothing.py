"""Smoothing of the measured displacement field: a Legendre(Z) x Fourier(Theta) basis per cylindrical component.

The displacement of every marker (radial, circumferential, axial, in the frame of its step's axis) is fitted
by least squares on a basis of axial Legendre polynomials times circumferential harmonics of the reference
coordinates (``smooth_cylindrical``); ``select_smoothing`` chooses the degrees from the data (generalised
cross-validation, or BIC). Used by ``kinematics.surface_state``. Positions in m; shapes in the docstrings.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.linalg import solve_triangular

from .errors import DegenerateDataError
from .mesh import SurfaceMesh, wrap_angle

__all__ = ["AUTO_DEGREES", "select_smoothing", "smooth_cylindrical", "smoothing_basis"]

log = logging.getLogger(__name__)


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
    if len(ok) and (ok == ok[:1]).all():  # every row alike (every step saw the same markers): the same answer
        return ok[:1].copy(), np.zeros(len(ok), dtype=np.intp)
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


def smooth_reference_radius(mesh: SurfaceMesh, candidates=AUTO_DEGREES) -> np.ndarray:
    """The reference radius of the markers, shape (n_markers,), replaced by its least-squares fit on
    the Legendre(Z) x Fourier(Theta) basis chosen by generalised cross-validation (as
    ``select_smoothing``); NaN outside the mesh."""
    R = np.where(mesh.used, mesh.r, np.nan)[None]
    best = reference_radius_degree(mesh, candidates)
    best_fit = _fit_basis(*smoothing_basis(mesh, best), R)[0][0]
    log.info("reference radius smoothed on (axial degree, harmonics) %s", best)
    return np.where(mesh.used, best_fit, np.nan)


def reference_radius_degree(mesh: SurfaceMesh, candidates=AUTO_DEGREES) -> tuple[int, int]:
    """The (axial degree, harmonics) of ``smooth_reference_radius``'s fit, chosen by generalised cross-validation."""
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
    return best


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
