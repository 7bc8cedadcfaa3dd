"""Minimise the virtual-work gap: Levenberg-Marquardt style least squares (default) or Nelder-Mead.

Cost (paper eq. 9, normalised): ``cost = 1/2 sum_k sum_m ((IVW[k,m] - EVW[k,m]) / scale_k)^2`` with
``scale_k`` the RMS external virtual work of field k over the steps, so both fields weigh alike
whatever their units of work. Positive parameters are optimised on a log scale, the others scaled
by their typical magnitude. The Jacobian is evaluated in one vectorised call (central differences
over the parameters of exact complex-step stresses).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np
from scipy.optimize import least_squares, minimize, nnls

from .errors import IdentificationError
from .models import Model, get_model
from .vfm import VFMData, internal_virtual_work, prepare

__all__ = ["IdentificationResult", "identify", "identify_prepared", "PAPER_INITIAL_GUESS", "GAP_FOR_FLAGS"]

log = logging.getLogger(__name__)

#: The paper's footnote initial guess for the Fung model (Fung 1993).
PAPER_INITIAL_GUESS = {"beta": 29e3, "alpha11": 2.5, "alpha22": 0.5, "alpha12": 0.17}

#: RMS relative virtual-work gap used to judge identifiability (1 %).
GAP_FOR_FLAGS = 0.01
#: A parameter is flagged when a change larger than this (relative, or in units of its typical
#: magnitude) still keeps the balance within ``GAP_FOR_FLAGS`` once the others compensate.
RESOLUTION_LIMIT = 0.3
LOG_RANGE = 12.0
#: Estimated marker noise (m) above which unsmoothed data are flagged.
NOISY_MARKERS = 0.02e-3
#: Smoothing used by ``identify(..., smoothing="auto")`` when the markers look noisy.
AUTO_SMOOTHING = (4, 2)
#: RMS normalised gap below which the balance is considered exact (no further starts are tried).
EXACT_GAP = 1e-5
#: Typical magnitude of parameters that may be zero or negative (for the scale of their changes).
TYPICAL = {"alpha12": 1.0, "phi": 0.5}


@dataclass(frozen=True)
class IdentificationResult:
    """Outcome of a VFM identification.

    Attributes
    ----------
    model, wall, optimizer : str
    parameters : dict
        Identified values, SI (Pa, rad, 1), keyed by the paper's names.
    stderr : dict
        Gauss-Newton standard errors from the residual scatter (0 on exact data).
    correlation : ndarray, shape (n_params, n_params)
    resolution : dict
        Change of each parameter (relative for positive ones, else in units of its typical
        magnitude) that the others can compensate within a 1 % RMS virtual-work gap: large values
        mean the data hardly constrain the parameter.
    flags : tuple of str
        Plain-words warnings (poorly identifiable parameters, non-convergence, poor fit).
    cost : float
        1/2 sum of squared normalised gaps.
    residuals : ndarray, shape (n_fields, n_steps)
        Normalised gaps (IVW - EVW) / scale.
    ivw, evw : ndarray, shape (n_fields, n_steps)
        Internal and external virtual work (J) at the solution (paper Figs. 5-6).
    field_names : tuple of str
    converged : bool
    message : str
    n_evaluations : int
        Cost evaluations (a Jacobian counts as 2 n_params).
    starts : tuple of dict
        Initial guesses tried.
    """

    model: str
    wall: str
    optimizer: str
    parameters: dict
    stderr: dict
    correlation: np.ndarray
    resolution: dict
    flags: tuple
    cost: float
    residuals: np.ndarray
    ivw: np.ndarray
    evw: np.ndarray
    field_names: tuple
    converged: bool
    message: str
    n_evaluations: int
    starts: tuple = field(default=())

    @property
    def residual_per_step(self) -> np.ndarray:
        """RMS normalised gap of each step over the fields, shape (n_steps,)."""
        return np.sqrt(np.mean(self.residuals**2, axis=0))

    @property
    def residual_per_field(self) -> np.ndarray:
        """RMS normalised gap of each field over the steps, shape (n_fields,)."""
        return np.sqrt(np.mean(self.residuals**2, axis=1))

    @property
    def parameter_names(self) -> tuple:
        return tuple(self.parameters)


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

    def to_p(self, x: np.ndarray) -> np.ndarray:
        return np.where(self.log, np.exp(x), x * self.scale)

    def dp_dx(self, x: np.ndarray) -> np.ndarray:
        return np.where(self.log, np.exp(x), self.scale)

    def as_dict(self, values: np.ndarray) -> dict:
        values = np.asarray(values)
        return {n: values[..., i] for i, n in enumerate(self.model.parameter_names)}


def _default_starts(model: Model, initial: Mapping[str, float] | None, n_starts: int) -> list[dict]:
    first = dict(initial) if initial is not None else (
        dict(PAPER_INITIAL_GUESS) if model.name == "fung" else dict(model.initial_guess))
    first = model.check_parameters(first)
    starts = [first]
    base = model.check_parameters(model.initial_guess)
    for factor in (1.0, 0.2, 5.0):
        cand = {n: (v * factor if pos else v) for (n, v), pos in zip(base.items(), model.positive)}
        if all(not np.allclose(list(cand.values()), list(s.values())) for s in starts):
            starts.append(cand)
    return starts[: max(1, int(n_starts))]


def identify_prepared(
    data: VFMData,
    model: str | Model,
    *,
    initial: Mapping[str, float] | None = None,
    optimizer: str = "lsq",
    n_starts: int = 3,
    max_evaluations: int = 20000,
) -> IdentificationResult:
    """Identify the parameters of ``model`` from prepared virtual-work data.

    Parameters
    ----------
    data : VFMData
        From ``prepare``.
    model : str or Model
    initial : mapping, optional
        First starting point (default: the paper's footnote guess for Fung, the model's generic
        guess otherwise); ``n_starts - 1`` generic starts are added and the best result kept.
    optimizer : {"lsq", "nelder-mead"}
        ``"lsq"``: ``scipy.optimize.least_squares`` (trust-region reflective, bounded). ``"nelder-mead"``:
        the paper's simplex method from the first start only.
    """
    model = get_model(model)
    if optimizer not in ("lsq", "nelder-mead"):
        raise ValueError(f"optimizer must be 'lsq' or 'nelder-mead'; got {optimizer!r}")
    starts = _default_starts(model, initial, n_starts if optimizer == "lsq" else 1)
    tr = _Transform(model, starts[0])
    scale = data.scale[:, None]
    n_eval = [0]

    def residual(x):
        n_eval[0] += 1
        with np.errstate(over="ignore", invalid="ignore"):
            ivw = internal_virtual_work(data, model, tr.as_dict(tr.to_p(x)))
        r = ((ivw - data.evw) / scale).ravel()
        # an exponential law overflowing on a wildly strained (noisy) triangle: a large finite gap
        return np.clip(np.where(np.isfinite(r), r, 1e6), -1e6, 1e6)

    def jacobian(x, *_):
        n = len(x)
        h = 1e-6
        xs = np.concatenate([x + h * np.eye(n), x - h * np.eye(n)])
        n_eval[0] += 2 * n
        with np.errstate(over="ignore", invalid="ignore"):
            ivw = internal_virtual_work(data, model, tr.as_dict(tr.to_p(xs)))
        r = ((ivw - data.evw[None]) / scale[None]).reshape(2 * n, -1)
        r = np.clip(np.where(np.isfinite(r), r, 1e6), -1e6, 1e6)
        jac = ((r[:n] - r[n:]) / (2 * h)).T
        return np.where(np.isfinite(jac), jac, 0.0)

    def linear_prefit(start: dict) -> dict:
        """Rescale the stress-like parameters of a start to their best non-negative linear fit."""
        lin = [i for i, flag in enumerate(model.linear) if flag]
        if not lin:
            return start
        base = np.array([start[n] for n in model.parameter_names], dtype=float)
        sets = np.repeat(base[None], len(lin), axis=0)
        for row, i in enumerate(lin):
            sets[row, [j for j in lin if j != i]] = 0.0
        n_eval[0] += len(lin)
        with np.errstate(over="ignore", invalid="ignore"):
            ivw = internal_virtual_work(data, model, tr.as_dict(sets))  # (n_lin, n_fields, n_steps)
        A = (ivw / scale[None]).reshape(len(lin), -1).T
        if not np.all(np.isfinite(A)):
            return start
        a, _ = nnls(A, (data.evw / scale).ravel())
        out = dict(start)
        for row, i in enumerate(lin):
            if a[row] > 0:
                out[model.parameter_names[i]] = float(base[i] * a[row])
        return out

    best = None
    for start in starts:
        x0 = tr.to_x(linear_prefit(start) if optimizer == "lsq" else start)
        with np.errstate(over="ignore", invalid="ignore"):
            if optimizer == "lsq":
                sol = least_squares(residual, x0, jac=jacobian, bounds=(tr.lower, tr.upper), method="trf",
                                    x_scale=1.0, xtol=1e-10, ftol=1e-10, gtol=1e-10, max_nfev=200)
                x, cost, ok, msg = sol.x, float(sol.cost), bool(sol.status > 0), str(sol.message)
            else:
                def fun(x):
                    r = residual(x)
                    return 0.5 * float(r @ r) if np.all(np.isfinite(r)) else np.inf

                sol = minimize(fun, x0, method="Nelder-Mead", bounds=list(zip(tr.lower, tr.upper)),
                               options={"xatol": 1e-10, "fatol": 1e-22, "maxfev": max_evaluations, "adaptive": True})
                x, cost, ok, msg = sol.x, float(sol.fun), bool(sol.success), str(sol.message)
        if not np.isfinite(cost):
            continue
        if best is None or cost < best[1]:
            best = (x, cost, ok, msg)
        if best[1] < 0.5 * EXACT_GAP**2 * data.evw.size:  # balance exact to quadrature: no start does better
            break
    if best is None:
        raise IdentificationError(f"the optimiser found no finite cost for model {model.name!r} from {starts}")
    x, cost, ok, msg = best
    p = tr.to_p(x)
    params = {n: float(v) for n, v in zip(model.parameter_names, p)}
    with np.errstate(over="ignore", invalid="ignore"):
        ivw = internal_virtual_work(data, model, params)
    res = (ivw - data.evw) / scale
    n_calls = n_eval[0]
    J = jacobian(x)
    n_eval[0] = n_calls + 0  # the diagnostic Jacobian is not counted as optimiser work
    m, n = J.shape
    JtJ = J.T @ J
    try:
        inv = np.linalg.pinv(JtJ, rcond=1e-13)
    except (np.linalg.LinAlgError, ValueError):
        inv = np.full((n, n), np.inf)
    dof = max(m - n, 1)
    s2 = 2.0 * cost / dof
    cov_x = s2 * inv
    d = np.sqrt(np.clip(np.diag(inv), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = inv / np.outer(d, d)
    corr = np.where(np.isfinite(corr), corr, 0.0)
    dpdx = tr.dp_dx(x)
    stderr = {nm: float(abs(g) * np.sqrt(max(cov_x[i, i], 0.0))) for i, (nm, g) in enumerate(zip(model.parameter_names, dpdx))}
    # resolution: parameter change (relative or in typical units) compensable within a 1 % RMS gap
    resolution = {}
    for i, nm in enumerate(model.parameter_names):
        dx = GAP_FOR_FLAGS * np.sqrt(m) * d[i]
        if not model.positive[i]:
            dx = dx * tr.scale[i] / TYPICAL.get(nm, tr.scale[i])
        resolution[nm] = float(dx)
    flags = []
    for nm, value in resolution.items():
        if not np.isfinite(value) or value > RESOLUTION_LIMIT:
            unit = "relative" if model.positive[model.parameter_names.index(nm)] else f"x {TYPICAL.get(nm, 1.0):g}"
            flags.append(f"{nm} is poorly identifiable: a change of {value:.2g} ({unit}) can be compensated by the "
                         f"other parameters within a {GAP_FOR_FLAGS:.0%} virtual-work gap; do not trust its value"
                         + (" (load at two or more axial stretches to constrain it)" if nm == "alpha12" else ""))
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
                     "(smoothing=(4, 2), --smooth 4,2) or measure better")
    if np.any(data.n_outliers):
        flags.append(f"{int(np.sum(data.n_outliers))} marker observations disagreed with their neighbours "
                     "(mis-tracked?) and were ignored")
    return IdentificationResult(
        model=model.name, wall=data.wall, optimizer=optimizer, parameters=params, stderr=stderr, correlation=corr,
        resolution=resolution, flags=tuple(flags), cost=float(cost), residuals=res, ivw=ivw, evw=data.evw.copy(),
        field_names=data.field_names, converged=ok, message=msg, n_evaluations=int(n_eval[0]),
        starts=tuple(starts),
    )


def identify(
    positions: np.ndarray,
    pressure: np.ndarray,
    axial_force: np.ndarray,
    *,
    thickness: float,
    model: str | Model = "fung",
    wall: str = "membrane",
    ends: str = "clamped",
    optimizer: str = "lsq",
    initial: Mapping[str, float] | None = None,
    n_starts: int = 3,
    **prepare_options,
) -> IdentificationResult:
    """Identify constitutive parameters from marker positions, pressure and axial force.

    Parameters
    ----------
    positions : ndarray, shape (n_steps, n_markers, 3)
        Marker positions (m, world frame, z towards the load cell), step 0 stress-free; NaN = not
        observed.
    pressure : ndarray, shape (n_steps,)
        Pa.
    axial_force : ndarray, shape (n_steps,)
        Axial force carried by the wall at the load-cell end (N).
    thickness : float
        Reference wall thickness (m).
    model : {"fung", "delfino", "hgo", "neohookean"} or Model
    wall : {"membrane", "thick"}
    ends : {"clamped", "free"}
    optimizer : {"lsq", "nelder-mead"}
    initial : mapping, optional
    prepare_options
        Passed to ``prepare`` (fields, mesh, n_layers, quadrature, clamp_radius, smoothing...).
        ``smoothing="auto"`` smooths with ``AUTO_SMOOTHING`` only when the estimated marker noise
        exceeds ``NOISY_MARKERS`` (0.02 mm).
    """
    smoothing = prepare_options.pop("smoothing", None)
    auto = isinstance(smoothing, str)
    if auto and smoothing != "auto":
        raise ValueError(f"smoothing must be None, 'auto' or (axial degree, harmonics); got {smoothing!r}")
    data = prepare(positions, pressure, axial_force, thickness=thickness, wall=wall, ends=ends,
                   smoothing=None if auto else smoothing, **prepare_options)
    if auto and data.marker_noise > NOISY_MARKERS:
        log.info("estimated marker noise %.3g mm: smoothing the displacements with %s", data.marker_noise * 1e3,
                 AUTO_SMOOTHING)
        opts = dict(prepare_options)
        opts["mesh"] = data.mesh
        data = prepare(positions, pressure, axial_force, thickness=thickness, wall=wall, ends=ends,
                       smoothing=AUTO_SMOOTHING, **opts)
    return identify_prepared(data, model, initial=initial, optimizer=optimizer, n_starts=n_starts)
