"""The result of a regional identification: per-band profiles, their statistics and plain-words flags.

``with_profile_uncertainty`` puts standard errors (Gauss-Newton or bootstrap) into a ``RegionalResult`` and
derives from them the pooled value, the contrast of each band and the flags. SI units (m, Pa).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Mapping, Sequence

import numpy as np

from .fit import GAP_FOR_FLAGS, RESOLUTION_LIMIT
from .result import IdentificationResult
from .models import Model, get_model

__all__ = ["RegionalResult", "with_profile_uncertainty", "SIGNIFICANCE", "MIN_CONTRAST"]


#: A band is reported as different from the others when its value departs from the pooled one by more than this
#: many standard errors *and* by more than ``MIN_CONTRAST`` (relative): the method's error on exact data
#: (1-4 % at 3-8 bands) is not news.
SIGNIFICANCE = 3.0

MIN_CONTRAST = 0.05


@dataclass(frozen=True)
class RegionalResult:
    """Outcome of a regional identification.

    Attributes
    ----------
    model : str
    regional : tuple of str
        Names of the parameters identified per band.
    edges, centres : ndarray, shapes (n_bands + 1,), (n_bands,)
        Band (profile cell) edges and centres, m, reference axial coordinate of the mesh.
    profiles, stderr : dict of ndarray, shape (n_bands,)
        Per-band values and standard errors of the regional parameters (SI).
    parameters, parameter_stderr : dict of float
        The shared parameters and their standard errors.
    pooled : dict of float
        Inverse-variance weighted mean of each regional profile.
    contrast : dict of ndarray, shape (n_bands,)
        Relative departure of each band from the median band.
    z_score : dict of ndarray, shape (n_bands,)
        That departure in standard errors (band and median combined).
    differs : ndarray, shape (n_bands,) bool
        Bands where a regional parameter departs from the median band beyond ``SIGNIFICANCE`` standard errors and
        ``MIN_CONTRAST``.
    resolution : dict of ndarray, shape (n_bands,)
        As ``IdentificationResult.resolution``, per band.
    flags : tuple of str
    cost : float
    residuals : ndarray, shape (n_fields, n_steps)
    field_names : tuple of str
    converged : bool
    message : str
    homogeneous : IdentificationResult
        The global (paper) fit of the same measurements, for comparison.
    kind : {"bands", "legendre"}
    coefficients : dict of ndarray, shape (n_coefficients,)
        Of each regional parameter (log of it for positive ones): band values or Legendre coefficients.
    interval : dict of ndarray, shape (n_bands, 2)
        ``CONFIDENCE`` interval of each profile value (SI).
    uncertainty : str
        "gauss-newton" or "bootstrap" (then ``bootstrap`` holds the details).
    covariance : ndarray, shape (n_x, n_x)
        Of the optimisation variables (coefficients of the regional parameters, then the shared ones).
    bootstrap : object or None
        ``regional_uncertainty.BandUncertainty`` when the bootstrap was run.
    """

    model: str
    regional: tuple
    edges: np.ndarray
    centres: np.ndarray
    profiles: dict
    stderr: dict
    parameters: dict
    parameter_stderr: dict
    pooled: dict
    contrast: dict
    z_score: dict
    differs: np.ndarray
    resolution: dict
    flags: tuple
    cost: float
    residuals: np.ndarray
    field_names: tuple
    converged: bool
    message: str
    homogeneous: IdentificationResult
    kind: str = "bands"
    coefficients: dict = field(default_factory=dict)
    interval: dict = field(default_factory=dict)
    uncertainty: str = "gauss-newton"
    covariance: np.ndarray | None = None
    bootstrap: object = None

    @property
    def n_bands(self) -> int:
        return len(self.centres)


def _pooled(v: np.ndarray, s: np.ndarray) -> tuple[float, float]:
    """Inverse-variance weighted mean and its standard error (plain mean when an error is 0)."""
    if np.all(s > 0):
        w = 1.0 / s**2
        return float(np.sum(w * v) / np.sum(w)), float(1.0 / np.sqrt(np.sum(w)))
    return float(np.mean(v)), 0.0


def _band_statistics(profiles: dict, stderr: dict):
    """Pooled values, and each band's contrast and z-score against the median band.

    The median of the bands is the reference (the healthy majority of a locally diseased segment; the mean of a
    homogeneous one); its standard error is taken as sqrt(pi/2) times that of the pooled mean.
    """
    pooled, contrast, z_score = {}, {}, {}
    for n, v in profiles.items():
        s = stderr[n]
        pooled[n] = _pooled(v, s)[0]
        if v.size == 1:
            contrast[n], z_score[n] = np.zeros(1), np.zeros(1)
            continue
        ref = float(np.median(v))
        s_diff = np.hypot(s, np.sqrt(0.5 * np.pi) * _pooled(v, s)[1])
        contrast[n] = v / ref - 1.0
        with np.errstate(divide="ignore", invalid="ignore"):
            z_score[n] = np.where(s_diff > 0, (v - ref) / s_diff, np.inf * np.sign(v - ref))
    return pooled, contrast, z_score


def _where(edges: np.ndarray, kind: str) -> list[str]:
    span = [f"{edges[b] * 1e3:.1f} to {edges[b + 1] * 1e3:.1f} mm" for b in range(len(edges) - 1)]
    return [f"band {b} ({s})" if kind == "bands" else f"the profile at {s}" for b, s in enumerate(span)]


def _band_flags(model: Model, result: RegionalResult) -> list[str]:
    """Plain-words warnings per band (as the global fit: poorly identifiable, uncertain) and the differing bands."""
    flags = []
    where = _where(result.edges, result.kind)
    fewer = "use fewer bands" if result.kind == "bands" else "use fewer coefficients"
    for n in result.regional:
        i = model.parameter_names.index(n)
        kpa = model.units[i] == "Pa"
        res, v, se = result.resolution[n], result.profiles[n], result.stderr[n]
        for b in np.flatnonzero(~np.isfinite(res) | (res > RESOLUTION_LIMIT)):
            flags.append(f"{n} in {where[b]} is poorly identifiable: a change of {res[b]:.2g} (relative) "
                         f"can be compensated within a {GAP_FOR_FLAGS:.0%} virtual-work gap; {fewer}")
        for b in np.flatnonzero(se > 0.3 * np.abs(v)):
            shown = f"{se[b] / 1e3:.3g} kPa" if kpa else f"{se[b]:.3g}"
            flags.append(f"{n} in {where[b]} is uncertain: standard error {shown} is more than 30 % of its value")
        z, c = result.z_score[n], result.contrast[n]
        for b in np.flatnonzero((np.abs(z) > SIGNIFICANCE) & (np.abs(c) > MIN_CONTRAST)):
            flags.append(f"{n} in {where[b]} differs from the median band by {c[b]:+.0%} ({z[b]:+.1f} standard errors)")
    return flags


def _intervals(profiles: dict, stderr: dict, positive: Mapping[str, bool], t: float = 1.959964) -> dict:
    """``CONFIDENCE`` intervals (n_bands, 2): on the log scale for positive parameters."""
    out = {}
    for n, v in profiles.items():
        if positive[n]:
            rel = stderr[n] / np.where(v != 0, np.abs(v), 1.0)
            out[n] = np.stack([v * np.exp(-t * rel), v * np.exp(t * rel)], -1)
        else:
            out[n] = np.stack([v - t * stderr[n], v + t * stderr[n]], -1)
    return out


def with_profile_uncertainty(result: RegionalResult, profile_stderr: dict, shared_stderr: dict, t: float,
                             label: str, flags: Sequence[str] = (), details=None) -> RegionalResult:
    """``result`` with other standard errors (e.g. the bootstrap's): the intervals, z-scores, differing bands and
    flags follow them. ``t``: the multiplier of the 95 % interval (1.96, or Student's for a bootstrap)."""
    model = get_model(result.model)
    positive = dict(zip(model.parameter_names, model.positive))
    stderr = {n: np.asarray(profile_stderr[n], dtype=float) for n in result.regional}
    pooled, contrast, z_score = _band_statistics(result.profiles, stderr)
    differs = np.zeros(result.n_bands, dtype=bool)
    for n in result.regional:
        differs |= (np.abs(z_score[n]) > SIGNIFICANCE) & (np.abs(contrast[n]) > MIN_CONTRAST)
    out = replace(result, stderr=stderr, pooled=pooled, contrast=contrast, z_score=z_score, differs=differs,
                  parameter_stderr=dict(shared_stderr), interval=_intervals(result.profiles, stderr, positive, t),
                  uncertainty=label, bootstrap=details)
    base = [f for f in result.flags if f.startswith(("poor fit", "the optimiser"))]
    return replace(out, flags=tuple(_band_flags(model, out)) + tuple(base) + tuple(flags))
