"""Uncertainty of regional profiles that covers the truth, and the band count chosen from the data.

Bootstrap (``with_bootstrap``): the project's parametric bootstrap (``uncertainty.resimulated_measurements``: the
fitted displacement field plus marker, pressure and load-cell noise at the level the data show) re-identified with the
same bands or Legendre basis (``regional.reprepare`` / ``regional.refit``). Per profile value (log scale for positive
parameters) the spread of the replicates, inflated by the model error seen in the residuals (actual RMS gap over the
replicates' median, as ``uncertainty``) and never narrower than the Gauss-Newton error, gives the random part of the
standard error. Two systematic parts are added in quadrature, because the replicates cannot see them:

- the smoothing bias: a local weakening is a local feature of the displacement field, which the smoothing basis rounds
  off, and the replicates are simulated from the smoothed field itself. Estimated as the change of the profile when the
  data are smoothed with 4 more axial degrees (measured on exact data, 4 bands: smoothing (4, 2) moved bands by up to
  4.8 %, (8, 2) by 1.6 %; without this term the bootstrap covered 3 of the 8 band means in a 2-seed test);
- the estimator's bias at this noise level: the replicates' mean offset from the estimate.

The 95 % interval is ``estimate -+ t(0.975, n - 1) sd``.

Band count (``choose_bands``): the finest candidate (``n_max`` bands) is fitted with its bootstrap errors; every
coarser count n is fitted as a step profile to it (weighted least squares on log beta of the fine bands, each fine band
given to the coarse band holding its centre), and the count with the least Akaike criterion chi2(n) + 2 n (per
regional parameter) is chosen. The fine-band errors are floored at ``METHOD_ERROR`` (relative): the method's own error
on exact data (1-3 % at 3-6 bands), which is not evidence of heterogeneity. Measured at 0.05 mm (4 seeds): the
40 % weakening gets 3 bands in 4 of 4 seeds with this rule, 2 in 3 of 4 with the first rule tried (the fewest bands
within chi-square's 99 % quantile); the homogeneous tube 1 band with both.

Pure functions over arrays; SI units.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.special import stdtrit  # scipy.stats costs ~0.4 s of import for one quantile

from .errors import IdentificationError
from .models import get_model
from .regional import (RegionalData, RegionalResult, identify_regional, prepare_regional, refit, reprepare,
                       with_profile_uncertainty)
from .uncertainty import CONFIDENCE, MAX_FAILED, resimulated_measurements

__all__ = ["BandUncertainty", "with_bootstrap", "choose_bands", "BandChoice", "METHOD_ERROR"]

log = logging.getLogger(__name__)

#: Relative error of a band's beta on exact data at 3-6 bands (measured: 1-3 %), a floor of the fine profile's errors
#: when choosing the band count.
METHOD_ERROR = 0.02


@dataclass(frozen=True)
class BandUncertainty:
    """Parametric bootstrap of a regional fit.

    Attributes
    ----------
    replicates : dict of ndarray, shape (n_ok, n_bands)
        Profiles of the successful replicates (SI).
    shared_replicates : ndarray, shape (n_ok, n_shared)
    marker_noise : float
        Simulated per-coordinate marker noise (m).
    pressure_noise, force_noise : float
        Pa and N.
    model_error_factor : float
        Actual RMS virtual-work gap over the replicates' median (>= 1): the inflation applied.
    n_failed : int
    gauss_newton_stderr : dict of ndarray, shape (n_bands,)
    t : float
        Student's multiplier of the 95 % intervals.
    smoothing_shift, bias : dict of ndarray, shape (n_bands,)
        The systematic parts added to the spread (SI): profile change with a richer smoothing, replicates' mean offset.
    """

    replicates: dict
    shared_replicates: np.ndarray
    marker_noise: float
    pressure_noise: float
    force_noise: float
    model_error_factor: float
    n_failed: int
    gauss_newton_stderr: dict
    t: float
    smoothing_shift: dict
    bias: dict

    @property
    def n_replicates(self) -> int:
        return int(self.shared_replicates.shape[0]) + self.n_failed


def _replicate_fits(rd: RegionalData, result: RegionalResult, positions, options, progress=None):
    """Profiles, shared values and RMS gaps of the re-simulated replicates; number failed.
    ``progress(done, n_replicates, "bootstrap")`` after each replicate."""
    level, reps = resimulated_measurements(rd.data, positions, **options)
    profiles, shared, rms, failed = {n: [] for n in result.regional}, [], [], 0
    tell = progress or (lambda done, total, what: None)
    for i, (pos, p, f, mesh) in enumerate(reps):
        tell(i, int(options["n_replicates"]), "bootstrap")
        if mesh is None:
            failed += 1
            continue
        try:
            with np.errstate(all="ignore"):
                prof, sh, gap, ok = refit(reprepare(rd, pos, p, f, mesh), result)
        except (IdentificationError, ValueError, np.linalg.LinAlgError) as exc:
            log.debug("regional bootstrap replicate failed: %s", exc)
            failed += 1
            continue
        if not ok or not all(np.all(np.isfinite(v)) for v in prof.values()):
            failed += 1
            continue
        for n in result.regional:
            profiles[n].append(prof[n])
        shared.append([sh[n] for n in result.parameters])
        rms.append(gap)
    return level, {n: np.array(v).reshape(-1, result.n_bands) for n, v in profiles.items()}, \
        np.array(shared).reshape(-1, len(result.parameters)), np.array(rms), failed


def _spread(estimate: np.ndarray, reps: np.ndarray, positive: bool, factor: float, gn: np.ndarray) -> np.ndarray:
    """Standard error (SI) of ``estimate`` (..., k) from replicates (n, k): log-scale spread for positive values,
    inflated by ``factor``, never below the Gauss-Newton ``gn``."""
    if positive:
        sd = np.std(np.log(reps), axis=0, ddof=1) * factor * np.abs(estimate)
    else:
        sd = np.std(reps, axis=0, ddof=1) * factor
    return np.maximum(sd, np.nan_to_num(gn))


#: Axial degrees added to the smoothing to measure its bias.
SMOOTHING_PROBE = 4


def smoothing_shift(result: RegionalResult, rd: RegionalData, positions: np.ndarray) -> dict | None:
    """Change of each profile (SI, (n_bands,)) when the data are smoothed with ``SMOOTHING_PROBE`` more axial degrees
    (None for unsmoothed data or when that fit fails)."""
    if rd.data.smoothing is None:
        return None
    richer = tuple((nz + SMOOTHING_PROBE, nt) for nz, nt in rd.data.smoothing)
    try:
        with np.errstate(all="ignore"):
            rich = reprepare(rd, positions, rd.data.pressure, rd.data.axial_force, rd.data.mesh, smoothing=richer,
                              reject_outliers=rd.options.get("reject_outliers", True))
            prof, _, _, ok = refit(rich, result)
    except (IdentificationError, ValueError, np.linalg.LinAlgError) as exc:
        log.debug("smoothing probe failed: %s", exc)
        return None
    return {n: prof[n] - result.profiles[n] for n in result.regional} if ok else None


def with_bootstrap(result: RegionalResult, rd: RegionalData, positions: np.ndarray, *,
                   marker_sigma: np.ndarray | None = None, pressure_noise: float = 0.0, force_noise: float = 0.0,
                   n_replicates: int = 16, seed: int = 0,
                   progress: Callable[[int, int, str], None] | None = None) -> RegionalResult:
    """``result`` with bootstrap standard errors and 95 % intervals of its profiles (and shared parameters); the
    z-scores, differing bands and flags follow them.

    Parameters
    ----------
    result : RegionalResult
        From ``identify_regional(rd, ...)``.
    rd : RegionalData
    positions : ndarray, shape (n_steps, n_markers, 3)
        The measured positions (m) ``rd`` was prepared from.
    marker_sigma, pressure_noise, force_noise, n_replicates, seed, progress : as ``uncertainty.bootstrap``.
    """
    model = get_model(result.model)
    positive = dict(zip(model.parameter_names, model.positive))
    options = dict(marker_sigma=marker_sigma, pressure_noise=pressure_noise, force_noise=force_noise,
                   n_replicates=n_replicates, seed=seed)
    level, profiles, shared, rms, failed = _replicate_fits(rd, result, positions, options, progress)
    if progress is not None:
        progress(n_replicates, n_replicates, "bootstrap")
    n_ok = len(rms)
    flags = []
    if failed > MAX_FAILED * n_replicates:
        flags.append(f"{failed} of {n_replicates} re-simulated replicates failed to identify: the profile is "
                     "unstable at this noise level and its uncertainty is itself uncertain")
    if n_ok < 3:
        return with_profile_uncertainty(result, result.stderr, result.parameter_stderr, 1.959964, "gauss-newton",
                                        flags)
    actual = float(np.sqrt(np.mean(result.residuals**2)))
    typical = float(np.median(rms))
    factor = max(1.0, actual / typical) if typical > 0 else 1.0
    se = {n: _spread(result.profiles[n], profiles[n], positive[n], factor, result.stderr[n]) for n in result.regional}
    shift = smoothing_shift(result, rd, positions) or {n: np.zeros(result.n_bands) for n in result.regional}
    bias = {n: np.mean(profiles[n], axis=0) - result.profiles[n] for n in result.regional}
    se = {n: np.sqrt(se[n] ** 2 + shift[n] ** 2 + bias[n] ** 2) for n in result.regional}
    shared_se = {n: float(_spread(np.array([v]), shared[:, [j]], positive[n], factor,
                                  np.array([result.parameter_stderr[n]]))[0])
                 for j, (n, v) in enumerate(result.parameters.items())}
    if factor > 2.0:
        flags.append(f"the virtual-work gap is {factor:.1f}x larger than marker noise explains: the band model, the "
                     "end condition or the wall form may not fit these data (uncertainties are inflated accordingly)")
    t = float(stdtrit(n_ok - 1, 0.5 + CONFIDENCE / 2))
    details = BandUncertainty(replicates=profiles, shared_replicates=shared, marker_noise=level,
                              pressure_noise=float(pressure_noise), force_noise=float(force_noise),
                              model_error_factor=factor, n_failed=int(failed),
                              gauss_newton_stderr={n: result.stderr[n].copy() for n in result.regional}, t=t,
                              smoothing_shift=shift, bias=bias)
    return with_profile_uncertainty(result, se, shared_se, t, "bootstrap", flags, details)


@dataclass(frozen=True)
class BandChoice:
    """How ``choose_bands`` chose.

    Attributes
    ----------
    n_bands : int
        Chosen count.
    candidates : ndarray, shape (n_candidates,) int
    chi2 : ndarray, shape (n_candidates,)
        Misfit of each count's step profile to the finest profile (in its standard errors).
    criterion : ndarray, shape (n_candidates,)
        chi2 + 2 x (number of band values): the least is chosen.
    finest : RegionalResult
        The finest fit, with its bootstrap errors.
    """

    n_bands: int
    candidates: np.ndarray
    chi2: np.ndarray
    criterion: np.ndarray
    finest: RegionalResult


def _step_misfit(y: np.ndarray, sd: np.ndarray, centres: np.ndarray, edges: np.ndarray) -> float:
    """Weighted least-squares misfit of a step profile on ``edges`` to values ``y`` (k,) at ``centres`` (k,)."""
    cell = np.clip(np.searchsorted(edges, centres, side="right") - 1, 0, len(edges) - 2)
    w = 1.0 / sd**2
    chi2 = 0.0
    for c in np.unique(cell):
        sel = cell == c
        mean = np.sum(w[sel] * y[sel]) / np.sum(w[sel])
        chi2 += float(np.sum(w[sel] * (y[sel] - mean) ** 2))
    return chi2


def choose_bands(positions: np.ndarray, pressure: np.ndarray, axial_force: np.ndarray, *, thickness: float,
                 model: str = "fung", n_max: int = 6, bootstrap_options: dict | None = None,
                 progress: Callable[[int, int, str], None] | None = None, **prepare_options) -> BandChoice:
    """Choose the number of equal axial bands (1..``n_max``) from the data (module docstring).

    Parameters are those of ``prepare_regional`` (positions (n_steps, n_markers, 3) m, pressure (n_steps,) Pa,
    axial_force (n_steps,) N, thickness m) and ``with_bootstrap`` (``bootstrap_options``). ``progress(done, total,
    what)`` is told of the finest fit ("fitting N bands", done 0 of 1) and of its bootstrap.
    """
    if isinstance(n_max, bool) or not isinstance(n_max, (int, np.integer)) or not 2 <= n_max <= 12:
        raise ValueError(f"n_max must be an integer number of bands from 2 to 12; got {n_max!r}")
    if progress is not None:
        progress(0, 1, f"fitting {int(n_max)} bands")
    rd = prepare_regional(positions, pressure, axial_force, thickness=thickness, n_bands=int(n_max), **prepare_options)
    fine = identify_regional(rd, model)
    fine = with_bootstrap(fine, rd, positions, **(bootstrap_options or {}), progress=progress)
    m = get_model(model)
    positive = {n: m.positive[m.parameter_names.index(n)] for n in fine.regional}
    candidates = np.arange(1, int(n_max) + 1)
    chi2 = np.zeros(candidates.size)
    for n in fine.regional:
        v, se = fine.profiles[n], fine.stderr[n]
        # log scale (relative errors, floored at the method's error) for positive parameters
        y, sd = (np.log(v), np.hypot(se / np.abs(v), METHOD_ERROR)) if positive[n] else (v, se)
        for i, k in enumerate(candidates):
            chi2[i] += _step_misfit(y, sd, fine.centres, np.linspace(rd.edges[0], rd.edges[-1], k + 1))
    criterion = chi2 + 2.0 * candidates * len(fine.regional)
    chosen = int(candidates[int(np.argmin(criterion))])
    return BandChoice(n_bands=chosen, candidates=candidates, chi2=chi2, criterion=criterion, finest=fine)
