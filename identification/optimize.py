"""Identification from marker positions: the entry that wires the fit, the weighting and the uncertainty.

``identify`` prepares the virtual-work data (``vfm.prepare``), fits them (``fit.identify_prepared``),
optionally with noise-weighted gaps (``identify_noise_weighted``, built on ``noise_weights``) and a
bootstrap uncertainty (``uncertainty.with_uncertainty``). The modules it wires depend only downwards:
``fit`` <- ``noise_weights`` <- ``uncertainty`` <- this module.
"""

from __future__ import annotations

import dataclasses
from dataclasses import replace
from typing import Mapping

import numpy as np

from .defaults import uncertainty_for
from .efficient import EfficientSettings, identify_efficient
from .efficient_uncertainty import gls_uncertainty
from .reference import refine_reference
from .reference_repeats import reference_marker_sigma
from .resimulation import basis_size, fitted_positions, marker_noise_level, remeasured_mesh
from .errors import IdentificationError
from .fit import IdentificationResult, identify_prepared
from .models import Model
from .noise_weights import weighted_flags, in_physical_units, used_positions, gap_noise, weighted_data, weights_from_noise
from .uncertainty import with_given_uncertainty, with_uncertainty
from .vfm import prepare

__all__ = ["identify", "identify_noise_weighted", "identify_gls", "WEIGHTINGS", "drop_partial_steps", "per_step_rows", "MIN_COVERAGE",
           "MISSING_AREA"]


#: ``identify``'s weightings of the virtual-work gaps.
WEIGHTINGS = ("paper", "noise", "efficient")


#: Fraction of the reference markers a loaded step must observe to enter the balance (``identify``).
MIN_COVERAGE = 0.8


#: Fraction of a step's triangles left out (unobserved markers) above which unsmoothed fits are flagged.
MISSING_AREA = 0.01


def drop_partial_steps(positions, pressure, axial_force):
    """Leave out the loaded steps in which fewer than ``MIN_COVERAGE`` of the reference step's markers
    were observed (a region out of view: smoothing would extrapolate into it and the balance would
    miss its area). Returns the kept positions, pressure, force and the dropped step indices."""
    x = np.asarray(positions, dtype=float)
    if x.ndim != 3 or x.shape[0] < 3:
        return positions, pressure, axial_force, []
    seen = np.all(np.isfinite(x), axis=-1)
    ref = seen[0]
    coverage = (seen & ref[None]).sum(axis=1) / max(int(ref.sum()), 1)
    keep = (coverage >= MIN_COVERAGE) | (coverage == 0)  # an empty step is an input error: prepare says so
    keep[0] = True
    if keep.all() or keep.sum() < 2:
        return positions, pressure, axial_force, []
    return (x[keep], np.asarray(pressure, float).reshape(-1)[keep], np.asarray(axial_force, float).reshape(-1)[keep],
            np.flatnonzero(~keep).tolist())


def per_step_rows(options: Mapping | None, n_steps: int, dropped) -> dict | None:
    """``options`` with the ``dropped`` steps left out of every per-step array among them (``marker_sigma``,
    ``marker_weights``: shape (n_steps, n_markers[, ...]) with ``n_steps`` rows)."""
    if options is None:
        return None
    keep = np.setdiff1d(np.arange(n_steps), dropped)
    return {k: (np.asarray(v)[keep] if k in ("marker_sigma", "marker_weights") and np.ndim(v) >= 2
                and np.shape(v)[0] == n_steps else v) for k, v in options.items()}


def identify(
    positions: np.ndarray,
    pressure: np.ndarray,
    axial_force: np.ndarray,
    *,
    thickness: float,
    model: str | Model = "fung",
    wall: str,
    ends: str,
    optimizer: str = "lsq",
    initial: Mapping[str, float] | None = None,
    n_starts: int = 3,
    uncertainty: str = "gauss-newton",
    uncertainty_options: Mapping | None = None,
    weighting: str = "paper",
    efficient: EfficientSettings | None = None,
    reference_captures: np.ndarray | None = None,
    **prepare_options,
) -> IdentificationResult:
    """Identify constitutive parameters from marker positions, pressure and axial force under one stated setting.

    The fit alone: ``identification.identify`` (``judged.identify``) is the entry with the defaults
    (``identification.DEFAULTS``) that decides the settings not given and judges the result.

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
    model : str (one of ``available_models()``) or Model
    wall : {"membrane", "thick"}
    ends : {"clamped", "free"}
    optimizer : {"lsq", "nelder-mead"}
    initial : mapping, optional
    uncertainty : {"gauss-newton", "bootstrap", "gls", "auto"}
        "bootstrap": standard errors and 95 % intervals from re-simulated measurements
        (``uncertainty.bootstrap``; ~20 re-identifications) instead of the Gauss-Newton ones,
        which are too small when the markers are noisy. "gls" (``weighting="efficient"`` only): from the
        generalised least squares' own first-order covariance (``efficient_uncertainty``; no re-identification).
        "auto": "gls" for ``weighting="efficient"``, "bootstrap" for the others.
    uncertainty_options : mapping, optional
        Passed to ``uncertainty.bootstrap`` (marker_sigma, pressure_noise, force_noise, n_replicates, seed);
        "gls" ignores them (its noise model is ``efficient``'s) unless the data are unsmoothed (below).
    weighting : {"paper", "noise", "efficient"}
        "paper": the paper's cost (one scale per field). "noise": each virtual-work gap weighted by
        the inverse of its measured noise (``noise_weights.identify_noise_weighted``; smoothed data
        only, ``optimizer="lsq"``): at 0.17 mm marker noise Fung beta within 5 % in 80 % of seeds
        instead of 38 % (docs/validation/identification.md "Noise"). "efficient": generalised least squares
        over the full first-order covariance of the gaps (marker noise through the smoothing basis, the reference
        step treated as measured, the readings' noise; ``efficient``), iterated; ``optimizer="lsq"`` only
        (docs/validation/efficiency.md). Exact-looking (unsmoothed) data keep the paper's fit, and its
        bootstrap for "gls".
    efficient : EfficientSettings, optional
        Noise model of the readings, marker noise and iterations of ``weighting="efficient"``.
    reference_captures : ndarray of int, shape (n_markers,), optional
        Captures of the reference averaged into step 0, per marker (``reference_repeats.identify_repeated``):
        its noise is the loaded steps' / sqrt(captures) for ``weighting="efficient"`` and the bootstrap.
    prepare_options
        Passed to ``prepare`` (fields, mesh, n_layers, quadrature, clamp_radius, smoothing...).
        ``smoothing="auto"`` smooths with a basis chosen from the data (generalised
        cross-validation, ``smoothing.select_smoothing``) unless the markers look exact.
    """
    if weighting not in WEIGHTINGS:
        raise ValueError(f"weighting must be one of {WEIGHTINGS}; got {weighting!r}")
    uncertainty = uncertainty_for(uncertainty, weighting)
    if weighting == "efficient":
        if optimizer != "lsq" or initial is not None:
            raise ValueError(f"weighting='efficient' needs optimizer='lsq' and no initial guess; got "
                             f"optimizer={optimizer!r}, initial={initial!r}")
        return identify_gls(positions, pressure, axial_force, thickness=thickness, model=model, wall=wall, ends=ends,
                            uncertainty=uncertainty, uncertainty_options=uncertainty_options, n_starts=n_starts,
                            settings=efficient, reference_captures=reference_captures, **prepare_options)
    if weighting == "noise":
        if optimizer != "lsq" or initial is not None:
            raise ValueError(f"weighting='noise' needs optimizer='lsq' and no initial guess; got "
                             f"optimizer={optimizer!r}, initial={initial!r}")
        return identify_noise_weighted(positions, pressure, axial_force, thickness=thickness, model=model, wall=wall,
                                       ends=ends, uncertainty=uncertainty, uncertainty_options=uncertainty_options,
                                       n_starts=n_starts, **prepare_options)
    n_input = np.shape(positions)[0]
    positions, pressure, axial_force, dropped = drop_partial_steps(positions, pressure, axial_force)
    if dropped:
        uncertainty_options = per_step_rows(uncertainty_options, n_input, dropped)
        prepare_options = per_step_rows(prepare_options, n_input, dropped)
    data = prepare(positions, pressure, axial_force, thickness=thickness, wall=wall, ends=ends, **prepare_options)
    result = replace(identify_prepared(data, model, initial=initial, optimizer=optimizer, n_starts=n_starts),
                     smoothing=data.smoothing, data=data, steps=tuple(k for k in range(n_input) if k not in dropped))
    if dropped:
        result = replace(result, flags=result.flags + (
            f"steps {dropped} were left out: the cameras saw less than {MIN_COVERAGE:.0%} of the reference markers "
            "there (markers out of view), too little to fill in the rest of the surface",))
    missing = 1.0 - data.n_valid_triangles[1:] / max(data.mesh.n_triangles, 1)
    if data.smoothing is None and missing.size and missing.max() > MISSING_AREA:
        result = replace(result, flags=result.flags + (
            f"up to {missing.max():.0%} of the triangles of a step had an unobserved marker and were left out: the "
            "axial balance (whose external work is the whole measured force) misses their share and the parameters "
            "are biased; smooth the displacements (smoothing='auto', --smooth auto) to fill them in",))
    if uncertainty == "bootstrap":
        options = {k: v for k, v in prepare_options.items() if k not in ("mesh", "smoothing", "reject_outliers",
                                                                          "marker_weights")}
        unc = dict(uncertainty_options or {})
        if reference_captures is not None:
            unc["reference_captures"] = reference_captures
        result = with_uncertainty(result, data, positions, prepare_options=options, **unc)
    return result


def identify_noise_weighted(positions, pressure, axial_force, *, thickness: float, model="fung",
                            uncertainty: str = "gauss-newton", uncertainty_options: Mapping | None = None,
                            n_weight_replicates: int = 10, weight_seed: int = 0, **prepare_options):
    """``identify`` with the gaps weighted by their measured noise (the ``noise_weights`` module docstring).

    First the paper's (unweighted) fit; if the data were smoothed, the gap noise at that estimate
    (``gap_noise``), then the weighted fit started from it. With ``uncertainty="bootstrap"`` the
    replicates are weighted alike (same weights), so the interval describes this estimator.
    Unsmoothed (exact-looking) data return the unweighted fit unchanged.
    Returns an ``IdentificationResult`` whose ``data``, ``ivw``, ``evw`` and ``residuals`` are the paper's
    (unweighted; the weights only chose the estimate and its interval).
    """
    first = identify(positions, pressure, axial_force, thickness=thickness, model=model, **prepare_options)
    data = first.data
    if data.smoothing is None:
        if uncertainty == "bootstrap":
            return identify(positions, pressure, axial_force, thickness=thickness, model=model,
                            uncertainty=uncertainty, uncertainty_options=uncertainty_options, **prepare_options)
        return first
    options = {k: v for k, v in prepare_options.items() if k not in ("mesh", "smoothing", "reject_outliers",
                                                                      "marker_weights", "wall", "ends", "n_starts")}
    sd = gap_noise(data, used_positions(first, positions), first.parameters, model,
                   n_replicates=n_weight_replicates, seed=weight_seed, prepare_options=options)
    try:
        w = weights_from_noise(sd)
    except IdentificationError as exc:
        said = (f"weighting='noise' not applied: {exc}",)
        if uncertainty == "bootstrap":
            first = identify(positions, pressure, axial_force, thickness=thickness, model=model,
                             uncertainty=uncertainty, uncertainty_options=uncertainty_options, **prepare_options)
        return dataclasses.replace(first, flags=first.flags + said)
    wdata = weighted_data(data, w)
    result = dataclasses.replace(identify_prepared(wdata, model, initial=first.parameters),
                                 smoothing=data.smoothing, data=wdata, steps=first.steps)
    result = dataclasses.replace(result, flags=weighted_flags(result, first, data, model))
    if uncertainty == "bootstrap":
        n_input = np.shape(positions)[0]
        dropped = [] if first.steps is None else sorted(set(range(n_input)) - set(first.steps))
        result = with_uncertainty(result, data, used_positions(first, positions), prepare_options=options,
                                  gap_weights=w, **(per_step_rows(uncertainty_options, n_input, dropped) or {}))
    return in_physical_units(result, data, model)


def with_reference_sigma(settings: EfficientSettings, data, positions, reference_captures) -> EfficientSettings:
    """``settings`` with ``marker_sigma`` (n_steps, n_markers): the level (given as a number, or the one the data
    show with the averaged reference's lower noise accounted for) at the loaded steps, level / sqrt(captures) at
    the reference. A given per-marker array is kept as it is (the caller knows the noise)."""
    n_captures = np.asarray(reference_captures, dtype=float)
    if settings.marker_sigma is not None and np.ndim(settings.marker_sigma) > 0:
        return settings
    if settings.marker_sigma is not None:
        level = float(settings.marker_sigma)
    else:
        _, residual = fitted_positions(data, positions)
        used = data.mesh.used & (n_captures > 0)
        level = marker_noise_level(data, residual, basis_size(data.smoothing),
                                   reference_variance=float(np.mean(1.0 / n_captures[used])) if used.any() else 1.0)
    return replace(settings, marker_sigma=reference_marker_sigma(level, positions.shape[0], n_captures))


def identify_gls(positions, pressure, axial_force, *, thickness: float, model="fung",
                 uncertainty: str = "gauss-newton", uncertainty_options: Mapping | None = None,
                 settings: EfficientSettings | None = None, reference_captures: np.ndarray | None = None,
                 covariance=None, **prepare_options):
    """``identify`` with ``weighting="efficient"``: the paper's fit, then generalised least squares over the full
    covariance of the gaps (``efficient.identify_efficient``). Returns an ``IdentificationResult`` whose ``data``,
    ``ivw``, ``evw`` and ``residuals`` are the paper's (unweighted), like ``identify_noise_weighted``.

    ``uncertainty``: "gauss-newton" (the generalised least squares' ``stderr``, no interval), "gls" (``stderr``
    and 95 % intervals from its covariance, ``efficient_uncertainty``) or "bootstrap" (re-simulated
    measurements, each fitted with the same whitening). Exact-looking data (no smoothing: the paper's fit is
    kept) get the bootstrap for "gls". ``covariance``: the gaps' ``efficient.GapCovariance`` of these data and
    settings when already built (the verdict's); not used with ``settings.refine_reference``."""
    settings = settings or EfficientSettings()
    first = identify(positions, pressure, axial_force, thickness=thickness, model=model, **prepare_options)
    options = {k: v for k, v in prepare_options.items() if k not in ("n_starts",)}
    x = used_positions(first, positions)
    if settings.refine_reference and first.data.smoothing is not None:
        x = refine_reference(x, first.data.mesh, first.data.smoothing)
        given = {k: v for k, v in prepare_options.items() if k not in ("mesh", "smoothing")}
        first = replace(identify(x, first.data.pressure, first.data.axial_force, thickness=thickness, model=model,
                                 mesh=remeasured_mesh(first.data.mesh, x[0]), smoothing=first.data.smoothing,
                                 **given), steps=first.steps, flags=first.flags)
    if reference_captures is not None and first.data.smoothing is not None:
        settings = with_reference_sigma(settings, first.data, x, reference_captures)
    result, W = identify_efficient(first, x, model, settings, options,
                                   covariance=None if settings.refine_reference else covariance)
    result = dataclasses.replace(result, flags=_identifiability_of(first, weighted_flags(result, first, first.data,
                                                                                          model)))
    boot = {k: v for k, v in options.items() if k not in ("mesh", "smoothing", "reject_outliers", "marker_weights",
                                                           "wall", "ends")}
    n_input = np.shape(positions)[0]
    dropped = [] if first.steps is None else sorted(set(range(n_input)) - set(first.steps))
    unc = dict(per_step_rows(uncertainty_options, n_input, dropped) or {})
    if reference_captures is not None:  # the bootstrap re-simulates the averaged reference with its lower noise
        unc["reference_captures"] = reference_captures
    if uncertainty in ("bootstrap", "gls") and (W is None or first.data.smoothing is None):
        return with_uncertainty(first, first.data, x, prepare_options=boot, **unc)
    if uncertainty == "bootstrap":  # the whitened result: the replicates' gaps are whitened alike
        result = with_uncertainty(result, first.data, x, prepare_options=boot, whitening=W, **unc)
    result = in_physical_units(result, first.data, model)
    if uncertainty == "gls":
        result = _with_gls(result, first.data, W, x, settings)
    return result


def _identifiability_of(first, flags) -> tuple[str, ...]:
    """``flags`` with the paper's fit's "NAME is poorly identifiable" flags instead of their own: identifiability
    is the data's (a change of NAME compensated within a 1 % gap of the external work), while the whitened gaps
    are in noise units, where every parameter looks resolved."""
    poorly = tuple(f for f in first.flags if " is poorly identifiable" in f)
    return tuple(f for f in flags if " is poorly identifiable" not in f) + poorly


def _with_gls(result, data, W, positions, settings: EfficientSettings):
    """``result`` with the generalised least squares' ``Uncertainty`` (``efficient_uncertainty``), its
    ``stderr`` and flags (as ``uncertainty.with_uncertainty`` gives the bootstrap's)."""
    if settings.marker_sigma is not None:
        level = float(np.median(settings.marker_sigma))
    else:
        _, residual = fitted_positions(data, positions)
        level = float(marker_noise_level(data, residual, basis_size(data.smoothing)))
    unc = gls_uncertainty(result, data, W, marker_noise=level, pressure_noise=settings.pressure_floor,
                          force_noise=settings.force_floor)
    return with_given_uncertainty(result, unc)
