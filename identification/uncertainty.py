"""Uncertainty of identified parameters that covers the truth: a parametric bootstrap.

The Gauss-Newton standard errors of ``identify_prepared`` treat the virtual-work gaps as
independent; they are not (every gap shares the same noisy markers, and the smoothing spreads a
marker's noise over the whole field), so those errors were up to ~6x too small. Here the
measurement is re-simulated instead:

1. the measured displacement field as the identification saw it (the smoothed field, or the
   raw markers if unsmoothed) is taken as the truth, with the identified parameters;
2. marker noise at the level the data show (``marker_noise_level``: the scatter about the
   smoothed field, or the neighbour-mismatch estimate if unsmoothed; shaped marker by marker by
   the reconstruction's reported uncertainty when given), pressure-sensor and load-cell noise
   are added ``n_replicates`` times, and each replicate is prepared and identified again exactly as
   the data were (same mesh, smoothing basis, virtual fields);
3. the spread of the replicates (on a log scale for positive parameters) is the parameter
   uncertainty; it is inflated by the model error seen in the residuals, i.e. by how much larger
   the actual virtual-work gap is than the replicates' gaps (``model_error_factor``), and never
   narrower than the Gauss-Newton error of the actual residuals.

The 95 % interval is ``estimate -+ t(0.975, n - 1) * spread`` (back-transformed). The replicates'
mean offset from the estimate is reported as ``bias`` (not subtracted: measured, subtracting it
does not improve coverage; see docs/validation/identification.md, "Coverage").

Units SI as everywhere; shapes in the docstrings.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass, replace
from typing import Callable, Mapping

import numpy as np
from scipy.special import stdtrit  # scipy.stats costs ~0.4 s of import for one quantile

from .errors import IdentificationError
from .fit import identify_prepared
from .models import get_model
from .noise_weights import weighted_data
from .resimulation import fitted_positions, marker_noise_level, remeasured_mesh, resimulated_measurements
from .vfm import VFMData, prepare

__all__ = ["Uncertainty", "bootstrap", "fitted_positions", "marker_noise_level", "remeasured_mesh", "uncertainty_flags",
           "CONFIDENCE", "PRECISION"]

log = logging.getLogger(__name__)

#: Confidence level of the reported intervals.
CONFIDENCE = 0.95
#: Relative half-width of the 95 % interval above which a positive parameter is flagged as not
#: resolved (the paper's accuracy goal: 5 %).
PRECISION = 0.05
#: Fraction of failed replicates above which the uncertainty itself is flagged.
MAX_FAILED = 0.2


@dataclass(frozen=True)
class Uncertainty:
    """Parameter uncertainty from a parametric bootstrap.

    Attributes
    ----------
    stderr : dict
        Standard error of each parameter (SI), including the model-error inflation.
    interval : dict
        ``name -> (low, high)``, the ``CONFIDENCE`` interval (SI).
    bias : dict
        Mean of the replicates minus the estimate (SI): the estimator's bias at this noise level.
    covariance : ndarray, shape (n_params, n_params)
        Of the optimisation variables (log of positive parameters, the others in SI).
    replicates : ndarray, shape (n_ok, n_params)
        Identified parameters of the successful replicates (SI).
    marker_noise : float
        Per-coordinate marker noise simulated (m, median over markers).
    pressure_noise, force_noise : float
        Pa and N.
    model_error_factor : float
        Actual RMS virtual-work gap over the replicates' median (>= 1): the inflation applied.
    n_failed : int
        Replicates whose identification failed.
    gauss_newton_stderr : dict
        The Gauss-Newton standard errors of the fit (SI), for comparison.
    method : str
        "bootstrap" (this module), or "gls": the first-order covariance of a generalised least-squares fit
        (``efficient_uncertainty``: no replicates, ``bias`` NaN).
    """

    stderr: dict
    interval: dict
    bias: dict
    covariance: np.ndarray
    replicates: np.ndarray
    marker_noise: float
    pressure_noise: float
    force_noise: float
    model_error_factor: float
    n_failed: int
    gauss_newton_stderr: dict
    method: str = "bootstrap"

    @property
    def n_replicates(self) -> int:
        return int(self.replicates.shape[0]) + self.n_failed


def _to_x(model, values: np.ndarray) -> np.ndarray:
    """Parameters (..., n_params) -> optimisation variables (log of the positive ones)."""
    pos = np.array(model.positive)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(pos, np.log(np.where(values > 0, values, np.nan)), values)


def bootstrap(
    data: VFMData,
    result,
    positions: np.ndarray,
    *,
    marker_sigma: np.ndarray | None = None,
    pressure_noise: float = 0.0,
    force_noise: float = 0.0,
    n_replicates: int = 16,
    seed: int = 0,
    prepare_options: Mapping | None = None,
    gap_weights: np.ndarray | None = None,
    map_replicates: Callable | None = None,
    progress: Callable[[int, int, str], None] | None = None,
    load_noise_fraction: float = 0.0,
    reference_captures: np.ndarray | None = None,
    whitening: np.ndarray | None = None,
) -> Uncertainty:
    """Parametric bootstrap of an identification (see the module docstring).

    Parameters
    ----------
    data : VFMData
        What ``result`` was identified from (``prepare`` on ``positions``).
    result : IdentificationResult
    positions : ndarray, shape (n_steps, n_markers, 3)
        The measured positions (m), NaN = not observed.
    marker_sigma : ndarray, shape (n_steps, n_markers), optional
        Reported RMS 3-D uncertainty of each marker (m, the reconstruction's ``uncertainty``): shapes
        the simulated noise marker by marker (its overall level comes from the data).
    pressure_noise : float
        Standard deviation of a pressure reading (Pa).
    force_noise : float
        Standard deviation of a load-cell reading (N).
    n_replicates : int
        At least 5.
    seed : int
        Of the random generator (results are reproducible).
    prepare_options : mapping, optional
        The further options ``data`` was prepared with (fields, n_layers, quadrature, clamp_radius, toward).
    gap_weights : ndarray, shape (n_fields, n_steps), optional
        The weights of the virtual-work gaps ``result`` was fitted with (``noise_weights``): every
        replicate is weighted alike, so the spread describes the same estimator.
    map_replicates : callable, optional
        ``map``-like ``(function, replicates) -> results in order`` that runs the independent
        re-identifications, e.g. on several cores (``vfmlab.parallel.fork_map``); the builtin ``map``
        by default. The replicates are drawn in order before, so the result is the same either way.
    progress : callable, optional
        Called as ``progress(done, n_replicates, "bootstrap")`` before the first and after each replicate.
    load_noise_fraction : float
        Noise of a pressure or force reading as a fraction of the reading, added (in quadrature) to
        ``pressure_noise`` and ``force_noise`` (``identification.DEFAULTS``: 0.1 %).
    reference_captures : ndarray, shape (n_markers,), optional
        Captures of the reference averaged into step 0 (``reference_repeats``): simulated with their lower noise.
    whitening : ndarray, shape (n_fields * n_steps, n_fields * n_steps), optional
        The whitening ``result`` was fitted with (``weighting="efficient"``): every replicate is fitted with
        the same matrix (``result.residuals`` must then be the whitened ones).
    """
    model = get_model(result.model)
    level, replicates = resimulated_measurements(data, positions, marker_sigma=marker_sigma,
                                                 pressure_noise=pressure_noise, force_noise=force_noise,
                                                 n_replicates=n_replicates, seed=seed,
                                                 load_noise_fraction=load_noise_fraction,
                                                 reference_captures=reference_captures)
    options = dict(prepare_options or {})
    estimate = np.array([result.parameters[n] for n in model.parameter_names])
    reps, rms, failed = [], [], 0
    fit = functools.partial(_replicate_fit, data, model, result.parameters, options, gap_weights, whitening)
    tell = progress or (lambda done, total, what: None)
    tell(0, n_replicates, "bootstrap")
    for i, (values, value_rms) in enumerate((map_replicates or map)(fit, replicates)):
        tell(i + 1, n_replicates, "bootstrap")
        if values is None:
            failed += 1
            continue
        reps.append(values)
        rms.append(value_rms)
    return _summarise(model, estimate, np.array(reps).reshape(-1, len(estimate)), np.array(rms), result,
                      level, pressure_noise, force_noise, failed)


def _replicate_fit(data: VFMData, model, initial, options, gap_weights, whitening, replicate) -> tuple:
    """(parameters (n_params,) SI, RMS gap) of one replicate ``(pos, p, f, mesh)``; (None, nan) if its
    identification failed or did not converge (small, so that another process can send it back)."""
    pos, p, f, mesh = replicate
    res = _reidentify(data, model, initial, pos, p, f, mesh, options, gap_weights, whitening)
    values = None if res is None else np.array([res.parameters[n] for n in model.parameter_names])
    if values is None or not res.converged or not np.all(np.isfinite(_to_x(model, values))):
        return None, float("nan")
    return values, float(np.sqrt(np.mean(res.residuals**2)))


def _reidentify(data: VFMData, model, initial, pos, p, f, mesh, options, gap_weights, whitening=None):
    """One replicate prepared like ``data`` and identified from ``initial`` (one start); None if it fails."""
    if mesh is None:
        return None
    try:
        with np.errstate(all="ignore"):
            d = prepare(pos, p, f, thickness=data.thickness, wall=data.wall, ends=data.ends, mesh=mesh,
                        smoothing=data.smoothing, reject_outliers=False, estimate_noise=False,
                        dense_reuse=data.quadrature, **options)
            if gap_weights is not None:
                d = weighted_data(d, gap_weights)
            return identify_prepared(d, model, initial=initial, n_starts=1, whitening=whitening)
    except (IdentificationError, ValueError, np.linalg.LinAlgError) as exc:
        log.debug("bootstrap replicate failed: %s", exc)
        return None


def _summarise(model, estimate, reps, rms, result, level, pressure_noise, force_noise, failed) -> Uncertainty:
    """Spread, model-error inflation, intervals and bias of the replicates."""
    names = model.parameter_names
    n = len(reps)
    if n < 3:
        nan = {k: float("nan") for k in names}
        return Uncertainty(stderr=nan, interval={k: (float("nan"), float("nan")) for k in names}, bias=nan,
                           covariance=np.full((len(names),) * 2, np.nan), replicates=reps, marker_noise=level,
                           pressure_noise=pressure_noise, force_noise=force_noise, model_error_factor=float("nan"),
                           n_failed=failed, gauss_newton_stderr=dict(result.stderr))
    x_hat = _to_x(model, estimate)
    xs = _to_x(model, reps)
    actual = float(np.sqrt(np.mean(result.residuals**2)))
    typical = float(np.median(rms))
    factor = max(1.0, actual / typical) if typical > 0 else 1.0
    cov = np.cov(xs, rowvar=False).reshape(len(names), len(names)) * factor**2
    # never narrower than the Gauss-Newton error of the actual residuals (exact data: a tiny width)
    pos = np.array(model.positive)
    gn = np.array([result.stderr[k] for k in names], dtype=float)
    gn = np.where(pos, gn / np.where(estimate != 0, np.abs(estimate), 1.0), gn)
    sd = np.maximum(np.sqrt(np.clip(np.diag(cov), 0.0, None)), np.nan_to_num(gn))
    t = float(stdtrit(n - 1, 0.5 + CONFIDENCE / 2))
    lo, hi = x_hat - t * sd, x_hat + t * sd
    lo, hi = np.where(pos, np.exp(lo), lo), np.where(pos, np.exp(hi), hi)
    stderr = np.where(pos, np.abs(estimate) * sd, sd)
    bias = np.mean(reps, axis=0) - estimate
    return Uncertainty(
        stderr={k: float(v) for k, v in zip(names, stderr)},
        interval={k: (float(a), float(b)) for k, a, b in zip(names, lo, hi)},
        bias={k: float(v) for k, v in zip(names, bias)}, covariance=cov, replicates=reps, marker_noise=level,
        pressure_noise=float(pressure_noise), force_noise=float(force_noise), model_error_factor=factor,
        n_failed=int(failed), gauss_newton_stderr=dict(result.stderr))


def _said(lo: float, hi: float, unit: str) -> str:
    """An interval in the units people read: kPa for Pa, degrees for rad."""
    if unit == "Pa":
        return f"{lo / 1e3:.3g} to {hi / 1e3:.3g} kPa"
    if unit == "rad":
        return f"{np.degrees(lo):.3g} to {np.degrees(hi):.3g} deg"
    return f"{lo:.3g} to {hi:.3g}"


def uncertainty_flags(unc: Uncertainty, parameters: Mapping[str, float], positive: Mapping[str, bool],
                      skip: tuple = (), units: Mapping[str, str] | None = None) -> list[str]:
    """Plain-words warnings: parameters the data cannot resolve to ``PRECISION``, failed replicates.

    ``skip``: parameters already flagged as poorly identifiable (not repeated). ``units``: SI unit
    of each parameter ("Pa", "rad", "1"); intervals are said in kPa and degrees, as people read them.
    """
    flags = []
    cause = (f"at the marker noise of these data (~{unc.marker_noise * 1e3:.2g} mm); more markers, better cameras "
             "or more load levels would narrow it")
    if unc.model_error_factor > 1.2:
        cause = (f"with a virtual-work gap {unc.model_error_factor:.1f}x what the marker noise "
                 f"(~{unc.marker_noise * 1e3:.2g} mm) explains: check the model, --ends and --wall")
    for name, (lo, hi) in unc.interval.items():
        if name in skip or not positive.get(name, False):
            continue
        v = parameters[name]
        half = max(v - lo, hi - v) / abs(v) if v else float("inf")
        if not np.isfinite(half) or half > PRECISION:
            flags.append(f"{name} is not resolved to {PRECISION:.0%}: its {CONFIDENCE:.0%} interval is "
                         f"{_said(lo, hi, (units or {}).get(name, '1'))} "
                         f"({-(v - lo) / abs(v):+.0%}/{(hi - v) / abs(v):+.0%}) {cause}")
    total = unc.n_replicates
    if total and unc.n_failed > MAX_FAILED * total:
        flags.append(f"{unc.n_failed} of {total} re-simulated replicates failed to identify: the fit is "
                     "unstable at this noise level and its uncertainty is itself uncertain")
    if unc.model_error_factor > 2.0:
        flags.append(f"the virtual-work gap is {unc.model_error_factor:.1f}x larger than marker noise explains: "
                     "the model, the end condition or the wall form may not fit these data (uncertainties "
                     "are inflated accordingly)")
    return flags


def with_uncertainty(result, data: VFMData, positions: np.ndarray, **options):
    """``result`` with bootstrap standard errors (``result.stderr``), the ``Uncertainty`` in
    ``result.uncertainty`` and its flags added; ``options`` go to ``bootstrap``."""
    return with_given_uncertainty(result, bootstrap(data, result, positions, **options))


def with_given_uncertainty(result, unc: Uncertainty):
    """``result`` with the standard errors of ``unc`` (where finite), ``unc`` in ``result.uncertainty`` and its
    flags added."""
    model = get_model(result.model)
    poorly = tuple(n for n in model.parameter_names if any(f.startswith(f"{n} is poorly") for f in result.flags))
    flags = uncertainty_flags(unc, result.parameters, dict(zip(model.parameter_names, model.positive)), poorly,
                              units=dict(zip(model.parameter_names, model.units)))
    stderr = {k: (v if np.isfinite(v) else result.stderr[k]) for k, v in unc.stderr.items()}
    return replace(result, stderr=stderr, flags=tuple(result.flags) + tuple(flags), uncertainty=unc)


