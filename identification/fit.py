"""Minimise the virtual-work gap: variable-projection least squares (default) or Nelder-Mead.

Cost (paper eq. 9, normalised): ``cost = 1/2 sum_k sum_m ((IVW[k,m] - EVW[k,m]) / scale_k)^2`` with
``scale_k`` the RMS external virtual work of field k over the steps, so both fields weigh alike
whatever their units of work. Positive parameters are optimised on a log scale, the others scaled
by their typical magnitude.

The stress-like parameters (``Model.linear``: Fung and Delfino beta, HGO c and k1, neo-Hookean mu)
enter IVW linearly, so ``"lsq"`` solves them in closed form at every step (variable projection,
Golub & Pereyra 1973) and searches only the others; residuals and their exact Jacobian come from
one evaluation (``vfm.virtual_work_basis``: second-order AD of the energy or the model's closed
form). Standard errors and correlations are those of the full parameter vector (linear ones
included), from the exact Jacobian of all parameters at the solution.
"""

from __future__ import annotations

import logging
from typing import Mapping

import numpy as np
from scipy.optimize import least_squares, lsq_linear, minimize

from .errors import IdentificationError
from .models import Model, get_model
from .result import IdentificationResult
from .vfm import VFMData, internal_virtual_work, virtual_work_basis

__all__ = ["IdentificationResult", "identify_prepared", "PAPER_INITIAL_GUESS", "GAP_FOR_FLAGS"]

log = logging.getLogger(__name__)

#: The paper's footnote initial guess for the Fung model (Fung 1993): the Fung model's own ``initial_guess``.
PAPER_INITIAL_GUESS = dict(get_model("fung").initial_guess)

#: RMS relative virtual-work gap used to judge identifiability (1 %).
GAP_FOR_FLAGS = 0.01
#: A parameter is flagged when a change larger than this (relative, or in units of its typical
#: magnitude) still keeps the balance within ``GAP_FOR_FLAGS`` once the others compensate.
RESOLUTION_LIMIT = 0.3
LOG_RANGE = 12.0
#: Estimated marker noise (m) above which unsmoothed data are flagged.
NOISY_MARKERS = 0.02e-3
#: RMS normalised gap below which the balance is considered exact (no further starts are tried).
EXACT_GAP = 1e-5
#: Relative cost difference within which two starts are taken to have found the same minimum; the
#: remaining starts are then skipped (as they are after a first fit that ``_trusted`` accepts).
AGREEING_STARTS = 1e-6
#: ``scipy.optimize.least_squares`` method of the projected search. "dogbox" (rectangular trust
#: regions) needs half the iterations of "trf" on these small, well-scaled problems (Fung 8 vs 18
#: evaluations on the bench data, same minimum; ``bench_ident_timing --part timing``).
LSQ_METHOD = "dogbox"
#: Typical magnitude of parameters that may be zero or negative (for the scale of their changes).
TYPICAL = {"alpha12": 1.0, "phi": 0.5}


class _Transform:
    """Parameters <-> optimisation variables (log for positive, scaled otherwise)."""

    def __init__(self, model: Model, reference: Mapping[str, float]):
        self.model = model
        self.log = np.array(model.positive)
        self.scale = np.array([1.0 if lg else max(abs(reference[n]), TYPICAL.get(n, 1.0))
                               for n, lg in zip(model.parameter_names, model.positive)])
        lo = np.array(model.lower, dtype=float)
        hi = np.array(model.upper, dtype=float)
        # positive parameters may move at most LOG_RANGE e-folds (~5 decades) from the first start
        ref = np.array([reference[n] for n in model.parameter_names], dtype=float)
        centre = np.log(np.where(ref > 0, ref, 1.0))
        self.lower = np.where(self.log, centre - LOG_RANGE, lo / self.scale)
        self.upper = np.where(self.log, centre + LOG_RANGE, hi / self.scale)

    def to_x(self, p: Mapping[str, float]) -> np.ndarray:
        v = np.array([p[n] for n in self.model.parameter_names], dtype=float)
        if np.any(self.log & ~(v > 0)):
            bad = [n for n, lg, val in zip(self.model.parameter_names, self.log, v) if lg and not val > 0]
            raise IdentificationError(f"initial values of {bad} must be > 0 for model {self.model.name!r}")
        x = np.where(self.log, np.log(np.where(v > 0, v, 1.0)), v / self.scale)
        finite = np.isfinite(self.lower) & np.isfinite(self.upper)
        eps = np.where(finite, 1e-9 * np.where(finite, self.upper - self.lower, 0.0), 0.0)
        return np.clip(x, self.lower + eps, self.upper - eps)

    def to_x_unclipped(self, p: np.ndarray) -> np.ndarray:
        """Variables of the parameter vector ``p`` (model order), without clipping to the bounds."""
        p = np.asarray(p, dtype=float)
        return np.where(self.log, np.log(np.where(p > 0, p, np.finfo(float).tiny)), p / self.scale)

    def to_p(self, x: np.ndarray) -> np.ndarray:
        return np.where(self.log, np.exp(x), x * self.scale)

    def dp_dx(self, x: np.ndarray) -> np.ndarray:
        return np.where(self.log, np.exp(x), self.scale)

    def as_dict(self, values: np.ndarray) -> dict:
        values = np.asarray(values)
        return {n: values[..., i] for i, n in enumerate(self.model.parameter_names)}


def _default_starts(model: Model, initial: Mapping[str, float] | None, n_starts: int) -> list[dict]:
    first = dict(initial) if initial is not None else dict(model.initial_guess)
    first = model.check_parameters(first)
    starts = [first]
    base = model.check_parameters(model.initial_guess)
    for factor in (1.0, 0.2, 5.0):
        cand = {n: (v * factor if pos else v) for (n, v), pos in zip(base.items(), model.positive)}
        if all(not np.allclose(list(cand.values()), list(s.values())) for s in starts):
            starts.append(cand)
    return starts[: max(1, int(n_starts))]


class _Projection:
    """Variable projection (Golub-Pereyra) of the virtual-work balance onto its linear parameters.

    ``IVW = sum_l p_l A_l(q)`` with p the stress-like (``Model.linear``) parameters and q the
    others, so for given q the best p is a (bounded) linear least-squares solution and the search is
    over q only. ``A`` and its exact derivatives with respect to q come from one evaluation
    (``vfm.virtual_work_basis``); residuals and Jacobians are in the optimisation variables of
    ``_Transform`` (log scale for positive parameters).
    """

    def __init__(self, data: VFMData, model: Model, tr: _Transform, whitening: np.ndarray | None = None):
        self.data, self.model, self.tr = data, model, tr
        self.lin = np.flatnonzero(model.linear)
        self.nl = np.flatnonzero(~np.array(model.linear))
        self.scale = data.scale[:, None]
        self.y = (data.evw / self.scale).ravel()
        # generalised least squares (``efficient``): residuals W (IVW - EVW) / scale, W (n_res, n_res)
        self.whitening = None if whitening is None else np.asarray(whitening, dtype=float)
        if self.whitening is not None:
            self.y = self.whitening @ self.y
        # bounds of the linear parameters in parameter space (to_p is monotonic)
        self.p_lo = tr.to_p(tr.lower)[self.lin]
        self.p_hi = tr.to_p(tr.upper)[self.lin]
        self.n_evaluations = 0
        self._memo: tuple | None = None
        self._basis_memo: tuple | None = None

    def basis(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normalised ``A (n_res, n_lin)`` and ``dA/dq (n_res, n_lin, n_nl)``; None if not finite.

        The last evaluation is kept: the solution's parameters, trust test and covariance reuse it.
        """
        q = np.asarray(q, dtype=float)
        if self._basis_memo is not None and np.array_equal(self._basis_memo[0], q):
            return self._basis_memo[1]
        out = self._evaluate_basis(q)
        self._basis_memo = (q.copy(), out)
        return out

    def _evaluate_basis(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self.n_evaluations += 1
        values = dict(zip(self.model.parameter_names, np.zeros(len(self.model.parameter_names))))
        values.update({self.model.parameter_names[i]: v for i, v in zip(self.nl, q)})
        with np.errstate(over="ignore", invalid="ignore"):
            A, dA = virtual_work_basis(self.data, self.model, values)
        n_res = self.y.size
        A = np.moveaxis(A / self.scale, 0, -1).reshape(n_res, len(self.lin))
        dA = np.moveaxis(dA / self.scale, (0, 1), (-2, -1)).reshape(n_res, len(self.lin), len(self.nl))
        if self.whitening is not None:
            A, dA = self.whitening @ A, np.einsum("qr,rlj->qlj", self.whitening, dA)
        if not (np.all(np.isfinite(A)) and np.all(np.isfinite(dA))):
            return None, None
        return A, dA

    def linear_solve(self, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Best linear parameters within their bounds, and which of them are free (not on a bound)."""
        p = _solve_normal(A, self.y)
        if np.all((p > self.p_lo) & (p < self.p_hi)):
            return p, np.ones(len(p), bool)
        p = lsq_linear(A, self.y, bounds=(self.p_lo, self.p_hi), method="bvls").x
        free = (p > self.p_lo * (1 + 1e-12)) & (p < self.p_hi * (1 - 1e-12))
        return p, free

    def residual_jacobian(self, xq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Projected residual (n_res,) and its exact Jacobian (n_res, n_nl) at the nonlinear variables xq."""
        if self._memo is not None and np.array_equal(self._memo[0], xq):
            return self._memo[1], self._memo[2]
        q = self.tr.to_p(self._full_x(xq))[self.nl]
        A, dA = self.basis(q)
        if A is None:  # an exponential law overflowing on a wildly strained triangle: a large finite gap
            r, J = np.full(self.y.shape, 1e6), np.zeros((self.y.size, len(self.nl)))
        else:
            p, free = self.linear_solve(A)
            r = A @ p - self.y
            dq_dx = self.tr.dp_dx(self._full_x(xq))[self.nl]
            dAp = np.einsum("rlj,l->rj", dA, p)  # d(A p)/dq at fixed p
            Af = A[:, free]
            # Golub-Pereyra: p follows q, dp_free = -(Af^T Af)^-1 (Af^T dA p + dA_free^T r)
            rhs = Af.T @ dAp + np.einsum("rlj,r->lj", dA[:, free], r)
            dp = -_solve_normal(Af, None, rhs) if free.any() else np.zeros((0, len(self.nl)))
            J = (dAp + Af @ dp) * dq_dx
        self._memo = (xq.copy(), r, J)
        return r, J

    def _full_x(self, xq: np.ndarray) -> np.ndarray:
        x = np.zeros(len(self.model.parameter_names))
        x[self.nl] = xq
        return x

    def parameters(self, xq: np.ndarray) -> np.ndarray:
        """The full parameter vector (model order) at the nonlinear variables xq."""
        p = self.tr.to_p(self._full_x(xq))
        A, _ = self.basis(p[self.nl])
        if A is not None:
            p[self.lin] = self.linear_solve(A)[0]
        return p

    def full_jacobian(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unprojected residual ``(IVW - EVW) / scale`` (n_fields, n_steps) and its Jacobian with
        respect to all optimisation variables (n_res, n_params) at the parameters p."""
        A, dA = self.basis(p[self.nl])
        if A is None:
            raise IdentificationError(f"the virtual work of model {self.model.name!r} is not finite at {p.tolist()}")
        r = A @ p[self.lin] - self.y
        dp_dx = self.tr.dp_dx(self.tr.to_x_unclipped(p))
        J = np.zeros((r.size, len(p)))
        J[:, self.lin] = A * dp_dx[self.lin]
        J[:, self.nl] = np.einsum("rlj,l->rj", dA, p[self.lin]) * dp_dx[self.nl]
        return r.reshape(self.data.evw.shape), J


def _solve_normal(A: np.ndarray, y: np.ndarray | None, rhs: np.ndarray | None = None) -> np.ndarray:
    """``(A^T A)^-1 A^T y`` (or ``(A^T A)^-1 rhs``) for the few columns of A; pseudo-inverse if singular."""
    ata = A.T @ A
    b = A.T @ y if rhs is None else rhs
    try:
        out = np.linalg.solve(ata, b)
        if np.all(np.isfinite(out)):
            return out
    except np.linalg.LinAlgError:
        pass
    return np.linalg.pinv(ata, rcond=1e-13) @ b


def _fit_projected(vp: _Projection, starts: list[dict]) -> tuple:
    """Least squares over the nonlinear parameters from each start; the best (p, cost, ok, msg)."""
    tr, nl = vp.tr, vp.nl
    exact = 0.5 * EXACT_GAP**2 * vp.data.evw.size
    best = None
    tried = []
    for start in starts:
        x0 = tr.to_x(start)[nl]
        if any(np.allclose(x0, t, rtol=0, atol=1e-12) for t in tried):
            continue  # starts that differ only in the linear parameters are one start here
        tried.append(x0)
        if len(nl) == 0:
            sol_x, ok, msg = x0, True, "linear parameters only: solved in closed form"
        else:
            sol = least_squares(lambda x: vp.residual_jacobian(x)[0], x0, jac=lambda x: vp.residual_jacobian(x)[1],
                                bounds=(tr.lower[nl], tr.upper[nl]), method=LSQ_METHOD, x_scale=1.0,
                                xtol=1e-10, ftol=1e-10, gtol=1e-10, max_nfev=200)
            sol_x, ok, msg = sol.x, bool(sol.status > 0), str(sol.message)
        r, _ = vp.residual_jacobian(sol_x)
        cost = 0.5 * float(r @ r)
        agree = best is not None and abs(cost - best[1]) <= AGREEING_STARTS * best[1]
        if np.isfinite(cost) and (best is None or cost < best[1]):
            best = (vp.parameters(sol_x), cost, ok, msg)
        if best is not None and best[1] < exact:  # balance exact to quadrature: no start does better
            break
        if agree or (len(tried) == 1 and _trusted(vp, sol_x, cost, ok)):
            break
    return best


def _trusted(vp: _Projection, xq: np.ndarray, cost: float, ok: bool) -> bool:
    """A first fit that needs no other start: converged, inside the bounds, RMS gap below ``GAP_FOR_FLAGS``.

    With the linear parameters projected out, the first start's minimum was the best one on every
    data set of ``bench_ident_timing --part starts``; the other starts stay for doubtful fits.
    """
    lo, hi = vp.tr.lower[vp.nl], vp.tr.upper[vp.nl]
    width = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    inside = np.all(np.minimum(xq - lo, hi - xq) > 1e-6 * np.maximum(1.0, width))
    p_lin = vp.parameters(xq)[vp.lin]
    free = np.all((p_lin > vp.p_lo * (1 + 1e-6)) & (p_lin < vp.p_hi * (1 - 1e-6)))
    return bool(ok and inside and free and cost < 0.5 * GAP_FOR_FLAGS**2 * vp.y.size)


def _fit_nelder_mead(data: VFMData, model: Model, tr: _Transform, start: dict, max_evaluations: int, counter):
    """The paper's simplex over all parameters from one start; (p, cost, ok, msg)."""
    scale = data.scale[:, None]

    def fun(x):
        counter[0] += 1
        with np.errstate(over="ignore", invalid="ignore"):
            ivw = internal_virtual_work(data, model, tr.as_dict(tr.to_p(x)))
        r = ((ivw - data.evw) / scale).ravel()
        r = np.clip(np.where(np.isfinite(r), r, 1e6), -1e6, 1e6)
        return 0.5 * float(r @ r)

    with np.errstate(over="ignore", invalid="ignore"):
        sol = minimize(fun, tr.to_x(start), method="Nelder-Mead", bounds=list(zip(tr.lower, tr.upper)),
                       options={"xatol": 1e-10, "fatol": 1e-22, "maxfev": max_evaluations, "adaptive": True})
    return tr.to_p(sol.x), float(sol.fun), bool(sol.success), str(sol.message)


def _statistics(J: np.ndarray, cost: float, x: np.ndarray, model: Model, tr: _Transform):
    """Gauss-Newton standard errors, correlation and resolution from the full Jacobian J (n_res, n_params)."""
    m, n = J.shape
    try:
        inv = np.linalg.pinv(J.T @ J, rcond=1e-13)
    except (np.linalg.LinAlgError, ValueError):
        inv = np.full((n, n), np.inf)
    cov_x = 2.0 * cost / max(m - n, 1) * inv
    d = np.sqrt(np.clip(np.diag(inv), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = inv / np.outer(d, d)
    corr = np.where(np.isfinite(corr), corr, 0.0)
    dpdx = tr.dp_dx(x)
    names = model.parameter_names
    stderr = {nm: float(abs(g) * np.sqrt(max(cov_x[i, i], 0.0))) for i, (nm, g) in enumerate(zip(names, dpdx))}
    # resolution: parameter change (relative or in typical units) compensable within a 1 % RMS gap
    resolution = {}
    for i, nm in enumerate(names):
        dx = GAP_FOR_FLAGS * np.sqrt(m) * d[i]
        if not model.positive[i]:
            dx = dx * tr.scale[i] / TYPICAL.get(nm, tr.scale[i])
        resolution[nm] = float(dx)
    return stderr, corr, resolution


def axial_stretches(data: VFMData, tolerance: float = 0.02) -> int:
    """Number of distinct axial stretches among the loaded steps (median over the points of each step)."""
    c22 = np.asarray(data.c)[1:, :, 1]
    with np.errstate(invalid="ignore"):
        lz = np.sqrt(np.nanmedian(np.where(c22 > 0, c22, np.nan), axis=1))
    lz = np.sort(lz[np.isfinite(lz)])
    return int(1 + np.sum(np.diff(lz) > tolerance)) if lz.size else 0


def _flags(model: Model, data: VFMData, tr: _Transform, x, params, stderr, resolution, res, ok, msg) -> list[str]:
    """Plain-words warnings about the fit (identifiability, bounds, fit quality, data)."""
    flags = []
    for nm, value in resolution.items():
        if not np.isfinite(value) or value > RESOLUTION_LIMIT:
            unit = "relative" if model.positive[model.parameter_names.index(nm)] else f"x {TYPICAL.get(nm, 1.0):g}"
            flags.append(f"{nm} is poorly identifiable: a change of {value:.2g} ({unit}) can be compensated by the "
                         f"other parameters within a {GAP_FOR_FLAGS:.0%} virtual-work gap; do not trust its value"
                         + (" (load at two or more axial stretches to constrain it)"
                            if nm == "alpha12" and axial_stretches(data) < 2 else ""))
    for nm, se in stderr.items():
        i = model.parameter_names.index(nm)
        if model.positive[i] and se > 0.3 * abs(params[nm]):
            shown = f"{se / 1e3:.3g} kPa" if model.units[i] == "Pa" else f"{se:.3g}"  # people read kPa
            flags.append(f"{nm} is uncertain: standard error {shown} is more than 30 % of its value")
    rms = float(np.sqrt(np.mean(res**2)))
    at_bound = [nm for nm, xi, lo, hi in zip(model.parameter_names, x, tr.lower, tr.upper)
                if min(xi - lo, hi - xi) < 1e-6 * max(1.0, hi - lo if np.isfinite(hi - lo) else 1.0)]
    if at_bound:
        flags.append(f"{', '.join(at_bound)} ended on the search bounds: the fit is not to be trusted")
    if not np.isfinite(rms) or rms > 0.05:
        flags.append(f"poor fit: the RMS virtual-work gap is {rms:.1%} of the external work; the model may not "
                     "describe this material or the data are too noisy")
    if not ok:
        flags.append(f"the optimiser did not report convergence: {msg}")
    if data.smoothing is None and data.marker_noise > NOISY_MARKERS:
        flags.append(f"the markers look noisy (about {data.marker_noise * 1e3:.2g} mm): per-triangle strains are "
                     "dominated by noise and the exponential laws by a few triangles; smooth the displacements "
                     "(smoothing='auto', --smooth auto) or measure better")
    if np.any(data.n_outliers):
        flags.append(f"{int(np.sum(data.n_outliers))} marker observations disagreed with their neighbours "
                     "(mis-tracked?) and were ignored")
    if data.quadrature is not None:  # a dense cloud (``dense``): say how its balance was evaluated
        flags.append(data.quadrature.describe())
    return flags


def identify_prepared(
    data: VFMData,
    model: str | Model,
    *,
    initial: Mapping[str, float] | None = None,
    optimizer: str = "lsq",
    n_starts: int = 3,
    max_evaluations: int = 20000,
    whitening: np.ndarray | None = None,
) -> IdentificationResult:
    """Identify the parameters of ``model`` from prepared virtual-work data.

    Parameters
    ----------
    data : VFMData
        From ``prepare``.
    model : str or Model
    initial : mapping, optional
        First starting point (default: the model's ``initial_guess``, for Fung the paper's footnote
        guess); up to ``n_starts - 1`` generic starts are added and the best result kept.
        They run only when the first fit is doubtful (not converged, on a search bound, RMS gap
        above ``GAP_FOR_FLAGS``) and stop once two starts agree.
    optimizer : {"lsq", "nelder-mead"}
        ``"lsq"``: variable projection (the stress-like parameters solved in closed form at every
        step) with ``scipy.optimize.least_squares`` (trust-region reflective, bounded, exact
        Jacobian) over the others. ``"nelder-mead"``: the paper's simplex over all parameters from
        the first start only.
    max_evaluations : int
        Evaluation budget of Nelder-Mead.
    whitening : ndarray, shape (n_fields * n_steps, n_fields * n_steps), optional
        Generalised least squares (``optimizer="lsq"``): the residual vector ``(IVW - EVW) / scale`` (field-major,
        ``ravel`` of (n_fields, n_steps)) is multiplied by this matrix, e.g. the inverse Cholesky factor of the
        gaps' covariance (``efficient.GapCovariance``); ``residuals`` and ``cost`` are then whitened ones.
    """
    model = get_model(model)
    if optimizer not in ("lsq", "nelder-mead"):
        raise ValueError(f"optimizer must be 'lsq' or 'nelder-mead'; got {optimizer!r}")
    starts = _default_starts(model, initial, n_starts if optimizer == "lsq" else 1)
    tr = _Transform(model, starts[0])
    if whitening is not None and optimizer != "lsq":
        raise ValueError(f"whitening needs optimizer='lsq'; got optimizer={optimizer!r}")
    vp = _Projection(data, model, tr, whitening)
    counter = [0]
    if optimizer == "lsq":
        best = _fit_projected(vp, starts)
    else:
        best = _fit_nelder_mead(data, model, tr, starts[0], max_evaluations, counter)
    if best is None or not np.isfinite(best[1]):
        raise IdentificationError(f"the optimiser found no finite cost for model {model.name!r} from {starts}")
    p, _, ok, msg = best
    n_evaluations = vp.n_evaluations + counter[0]
    res, J = vp.full_jacobian(p)  # the covariance covers all parameters, the linear ones included
    cost = 0.5 * float(np.sum(res**2))
    x = tr.to_x_unclipped(p)
    params = {n: float(v) for n, v in zip(model.parameter_names, p)}
    stderr, corr, resolution = _statistics(J, cost, x, model, tr)
    flags = _flags(model, data, tr, x, params, stderr, resolution, res, ok, msg)
    ivw = res * data.scale[:, None] + data.evw
    return IdentificationResult(
        model=model.name, wall=data.wall, optimizer=optimizer, parameters=params, stderr=stderr, correlation=corr,
        resolution=resolution, flags=tuple(flags), cost=cost, residuals=res, ivw=ivw, evw=data.evw.copy(),
        field_names=data.field_names, converged=ok, message=msg, n_evaluations=int(n_evaluations),
        starts=tuple(starts),
    )
