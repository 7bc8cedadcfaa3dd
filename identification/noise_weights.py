"""Noise-weighted virtual-work balance: each gap weighted by the inverse of its noise.

The paper's cost sums the squared virtual-work gaps of every field and step with one scale per
field. Under marker noise the gaps are far from equally noisy: with an exponential law the
stress's sensitivity to strain grows with the load, and at 0.17 mm marker noise the gap noise of
the last pressure step is ~500 x that of the first stretched step (homogeneous tube, paper
protocol). The unweighted least squares is then dominated by the noisiest steps. Weighting each
gap by 1 / (its noise standard deviation) is the Gauss-Markov (noise-optimal) choice for
independent gaps, the spirit of the noise-optimal virtual fields of Marek, Davis & Pierron (2017)
applied to the weights of the given fields.

The noise of every gap is measured, not modelled: the displacement field as identification saw it
(the smoothed field) is re-measured with marker noise at the level the data show
(``uncertainty.fitted_positions`` / ``marker_noise_level``), prepared again like the data, and the
gaps are evaluated at the first (unweighted) estimate; their standard deviation per field and step
gives the weights. Exact data (no smoothing) keep the paper's cost.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Mapping

import numpy as np

from .errors import IdentificationError
from .resimulation import basis_size, fitted_positions, marker_noise_level, remeasured_mesh
from .vfm import VFMData, internal_virtual_work, prepare

__all__ = ["gap_noise", "weighted_data", "weights_from_noise", "WEIGHT_FLOOR"]

log = logging.getLogger(__name__)

#: Gap noise below this fraction of the largest is floored (the reference step's gap is 0 exactly).
WEIGHT_FLOOR = 1e-3


def gap_noise(data: VFMData, positions: np.ndarray, parameters: Mapping[str, float], model, *,
              n_replicates: int = 10, seed: int = 0, prepare_options: Mapping | None = None) -> np.ndarray:
    """Standard deviation of the normalised virtual-work gaps under re-simulated marker noise.

    Parameters
    ----------
    data : VFMData
        The prepared data (smoothed).
    positions : ndarray, shape (n_steps, n_markers, 3)
        The measured positions (m), NaN = not observed.
    parameters : mapping
        Where the gaps are evaluated (the unweighted estimate).
    n_replicates : int
        Re-measurements (at least 3).

    Returns
    -------
    sd : ndarray, shape (n_fields, n_steps)
        Of ``(IVW - EVW) / scale`` (dimensionless, the units of the optimiser's residuals).
    """
    if int(n_replicates) < 3:
        raise ValueError(f"n_replicates must be at least 3; got {n_replicates!r}")
    fitted, residual = fitted_positions(data, positions)
    level = marker_noise_level(data, residual, basis_size(data.smoothing))
    rng = np.random.default_rng(seed)
    options = dict(prepare_options or {})
    gaps = []
    for _ in range(int(n_replicates)):
        pos = fitted + level * rng.standard_normal(fitted.shape)
        try:
            with np.errstate(all="ignore"):
                d = prepare(pos, data.pressure, data.axial_force, thickness=data.thickness, wall=data.wall,
                            ends=data.ends, mesh=remeasured_mesh(data.mesh, pos[0]), smoothing=data.smoothing,
                            reject_outliers=False, dense_reuse=data.quadrature, **options)
                gaps.append((internal_virtual_work(d, model, parameters) - d.evw) / data.scale[:, None])
        except (IdentificationError, ValueError, np.linalg.LinAlgError) as exc:
            log.debug("gap-noise replicate failed: %s", exc)
    if len(gaps) < 3:
        raise IdentificationError(f"only {len(gaps)} of {n_replicates} gap-noise replicates could be prepared")
    with np.errstate(invalid="ignore"):
        g = np.array(gaps)
        g = np.where(np.isfinite(g), g, np.nan)  # a replicate's gap that overflowed: left out of that gap's spread
        n = np.sum(np.isfinite(g), axis=0)
        sd = np.sqrt(np.nansum((g - np.nanmean(g, axis=0)) ** 2, axis=0) / np.maximum(n - 1, 1))
    return np.where(n >= 2, sd, np.nan)


def weighted_data(data: VFMData, weights: np.ndarray) -> VFMData:
    """``data`` whose gap of field k at step m is multiplied by ``weights[k, m]`` (shape (n_fields, n_steps)).

    Internal and external virtual work are scaled alike, so the balance at the true parameters
    still holds exactly; only the relative weight of the gaps in the least squares changes. Each
    field's ``scale`` becomes the RMS of its weighted external work.
    """
    w = np.asarray(weights, dtype=float)
    if w.shape != data.evw.shape or not np.all(np.isfinite(w) & (w > 0)):
        bad = int(np.sum(~(np.isfinite(w) & (w > 0)))) if w.shape == data.evw.shape else w.size
        raise ValueError(f"weights must be positive and finite, shape {data.evw.shape} (n_fields, n_steps); "
                         f"got shape {w.shape} with {bad} weight(s) not positive and finite")
    evw = data.evw * w
    scale = np.sqrt(np.mean(evw**2, axis=1))  # normalised gaps of order 1 again, as the identifiability checks expect
    return dataclasses.replace(data, evw=evw, work_density=data.work_density * w[:, :, None, None],
                               pressure_work=data.pressure_work * w, end_work=data.end_work * w,
                               scale=np.where(scale > 0, scale, data.scale))


def weights_from_noise(sd: np.ndarray) -> np.ndarray:
    """1 / sd (floored at ``WEIGHT_FLOOR`` x the largest), normalised to RMS 1 over the loaded steps; a spread
    that is not finite counts as the largest. An IdentificationError when no spread is finite and positive."""
    sd = np.asarray(sd, dtype=float)
    finite = np.isfinite(sd) & (sd > 0)
    if not finite.any():
        raise IdentificationError("the gap noise could not be measured (no finite, positive spread): the paper's "
                                  "cost is kept")
    top = float(np.max(sd[finite]))
    # a gap whose spread is NaN (a replicate's gap not finite) or 0 gets the largest measured spread: least weight
    sd = np.where(np.isfinite(sd), sd, top)
    sd = np.maximum(sd, WEIGHT_FLOOR * top)
    w = 1.0 / sd
    return w / np.sqrt(np.mean(w[:, 1:] ** 2))


def in_physical_units(result, data: VFMData, model):
    """``result`` with the paper's (unweighted) data, virtual works (J) and normalised gaps: what is stored and
    what the setting checks compare against other end conditions and wall forms (weighted gaps are measured
    against the small work of the low-pressure steps and made a correct wall form look wrong)."""
    ivw = internal_virtual_work(data, model, result.parameters)
    return dataclasses.replace(result, data=data, ivw=ivw, evw=data.evw.copy(),
                               residuals=(ivw - data.evw) / data.scale[:, None])


def weighted_flags(result, first, data: VFMData, model) -> tuple[str, ...]:
    """The weighted fit's flags, its "poor fit" judged on the paper's (unweighted) gaps: the weighted
    gaps are measured against the small work of the low-pressure steps and look large on any noisy data."""
    POOR_FIT_GAP = 0.05  # fit.identify_prepared's threshold

    kept = tuple(f for f in first.flags if f.startswith(("steps ", "up to ")))  # about the data, not the fit
    flags = [f for f in result.flags if not f.startswith("poor fit")]
    gap = (internal_virtual_work(data, model, result.parameters) - data.evw) / data.scale[:, None]
    rms = float(np.sqrt(np.mean(gap**2)))
    if not np.isfinite(rms) or rms > POOR_FIT_GAP:
        flags.append(f"poor fit: the RMS virtual-work gap is {rms:.1%} of the external work; the model may not "
                     "describe this material or the data are too noisy")
    return tuple(flags) + kept


def used_positions(result, positions) -> np.ndarray:
    """The steps of ``positions`` that ``result`` was identified from (identify may leave some out)."""
    x = np.asarray(positions, dtype=float)
    steps = getattr(result, "steps", None)
    return x if steps is None else x[list(steps)]
