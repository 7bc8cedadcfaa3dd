"""``identification.identify``: the identification with the command's defaults, judged trusted or doubtful.

The fit under one stated setting is ``optimize.identify``; this entry adds what the user did not state:
with ``ends=None`` or ``wall=None`` (the defaults, :data:`defaults.DEFAULTS`) every combination is fitted and
the data decide (``verdict``); the result is the one the data support (the thick wall when they cannot tell
the wall forms apart), with the others in ``result.hypotheses`` and a verdict that says why it is doubtful.
``vfmlab identify`` calls exactly this function, so the library's numbers are the command's.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Mapping

import numpy as np

from .defaults import DEFAULTS, PREFERRED_WALL, uncertainty_for
from .models import Model
from .noise_weights import used_positions
from .optimize import identify as identify_one
from .optimize import identify_gls
from .verdict import Hypothesis, fit_hypotheses, force_gaps, judge, law_gaps

__all__ = ["identify"]

_D = DEFAULTS


def _uncertainty_options(options: Mapping | None) -> dict:
    """The bootstrap's options with the default sensor noise where not given."""
    out = {"pressure_noise": _D.pressure_noise, "force_noise": _D.force_noise,
           "load_noise_fraction": _D.load_noise_fraction}
    out.update(options or {})
    return out


def _choose(hypotheses: list[Hypothesis], wall_stated: bool) -> Hypothesis:
    """The hypothesis with the smallest gaps in noise units; among those the data cannot tell from it, the
    preferred (thick) wall when the wall was not stated."""
    from .verdict import DECIDES

    best = min(hypotheses, key=lambda h: h.chi2)
    if not wall_stated and best.wall != PREFERRED_WALL:
        alike = [h for h in hypotheses if h.wall == PREFERRED_WALL and h.chi2 - best.chi2 < DECIDES]
        if alike:
            return min(alike, key=lambda h: h.chi2)
    return best


def identify(
    positions: np.ndarray,
    pressure: np.ndarray,
    axial_force: np.ndarray,
    *,
    thickness: float,
    model: str | Model = _D.model,
    wall: str | None = _D.wall,
    ends: str | None = _D.ends,
    optimizer: str = _D.optimizer,
    smoothing: str | tuple[int, int] | None = _D.smoothing,
    uncertainty: str = _D.uncertainty,
    uncertainty_options: Mapping | None = None,
    weighting: str = _D.weighting,
    judged: bool = True,
    reference_repeats: int = 1,
    **options,
):
    """Identify constitutive parameters from marker positions, pressure and axial force, and judge them.

    Parameters
    ----------
    positions : ndarray, shape (n_steps, n_markers, 3)
        Marker positions (m, world frame, z towards the load cell), step 0 stress-free; NaN = not observed.
    pressure : ndarray, shape (n_steps,)
        Pa.
    axial_force : ndarray, shape (n_steps,)
        Axial force carried by the wall at the load-cell end (N).
    thickness : float
        Reference wall thickness (m).
    model : str or Model
        One of ``available_models()``.
    wall : {"thick", "membrane"} or None
        None (default): thick unless the data say membrane (both fitted and judged).
    ends : {"clamped", "free"} or None
        None (default): the data decide; where they cannot, the result is doubtful with both in ``hypotheses``.
    optimizer, uncertainty, uncertainty_options, weighting :
        As ``optimize.identify``; the bootstrap simulates ``DEFAULTS.pressure_noise`` / ``force_noise`` /
        ``load_noise_fraction`` unless ``uncertainty_options`` says otherwise. The defaults: the efficient
        weighting (generalised least squares) with its own covariance's 95 % intervals ("auto" -> "gls");
        ``optimizer="nelder-mead"`` is the paper's method and takes the paper's cost (and "auto" the bootstrap).
        The settings not stated are decided over the gaps' full covariance (``setting_noise``); the efficient
        fit under the setting chosen reuses its covariance.
    smoothing : "auto" (default), None or (axial degree, harmonics)
    judged : bool
        False: only the fit under the stated setting (``ends`` and ``wall`` must be given), no verdict.
    reference_repeats : int
        The first ``reference_repeats`` steps are captures of the stress-free reference, averaged into one
        (``reference_repeats.identify_repeated``); ``result.steps`` refer to the input steps.
    options
        Passed to ``prepare`` (fields, mesh, n_layers, quadrature, clamp_radius, ...).

    Returns
    -------
    IdentificationResult with ``verdict`` ("trusted" | "doubtful"), ``verdict_reasons``,
    ``parameter_verdicts``, ``parameter_reasons`` and ``hypotheses``.
    """
    if reference_repeats != 1:
        from .reference_repeats import identify_repeated

        return identify_repeated(identify, positions, pressure, axial_force, reference_repeats, thickness=thickness,
                                 model=model, wall=wall, ends=ends, optimizer=optimizer, smoothing=smoothing,
                                 uncertainty=uncertainty, uncertainty_options=uncertainty_options, weighting=weighting,
                                 judged=judged, **options)
    if optimizer != "lsq" and weighting != "paper":  # Nelder-Mead: the paper's method, for comparison (as the CLI)
        weighting = "paper"
    uncertainty = uncertainty_for(uncertainty, weighting)
    stated = {"ends": ends is not None, "wall": wall is not None}
    walls = [wall] if wall is not None else [PREFERRED_WALL, "membrane" if PREFERRED_WALL == "thick" else "thick"]
    ends_list = [ends] if ends is not None else ["clamped", "free"]
    unc_options = (_uncertainty_options(uncertainty_options) if uncertainty in ("bootstrap", "gls")
                   else uncertainty_options)  # "gls" takes the bootstrap's where the data are unsmoothed
    common = dict(thickness=thickness, model=model, optimizer=optimizer, smoothing=smoothing, **options)

    def final(w: str, e: str, covariance=None):
        if covariance is not None and weighting == "efficient" and optimizer == "lsq":  # the verdict's covariance
            given = {k: v for k, v in common.items() if k not in ("optimizer", "efficient")}
            return identify_gls(positions, pressure, axial_force, wall=w, ends=e, uncertainty=uncertainty,
                                uncertainty_options=unc_options, covariance=covariance,
                                settings=common.get("efficient"), **given)
        return identify_one(positions, pressure, axial_force, wall=w, ends=e, uncertainty=uncertainty,
                            uncertainty_options=unc_options, weighting=weighting, **common)

    if not judged:
        if wall is None or ends is None:
            raise ValueError(f"judged=False needs ends and wall; got ends={ends!r}, wall={wall!r}")
        return final(wall, ends)
    cheap = uncertainty == "gauss-newton" and weighting == "paper"
    first = identify_one(positions, pressure, axial_force, wall=walls[0], ends=ends_list[0],
                         uncertainty="gauss-newton", **common)
    if first.data is None or optimizer != "lsq":
        return final(walls[0], ends_list[0]) if not cheap else first
    used = used_positions(first, positions)
    hypotheses = fit_hypotheses(first, used, walls, ends_list, prepare_options=options,
                                efficient=weighting == "efficient")
    chosen = _choose(hypotheses, stated["wall"])
    if cheap and chosen.fit is first:
        result = first
    else:
        result = final(chosen.wall, chosen.ends, chosen.noise.covariance)
    others = [h for h in hypotheses if h is not chosen]
    laws = law_gaps(chosen)
    paper = chosen.fit if weighting == "noise" else None
    result = replace(result, flags=tuple(_true_flags(result)))
    return judge(result, chosen, others, stated=stated, laws=laws, paper_fit=paper, forces=force_gaps(chosen))


def _true_flags(result) -> list[str]:
    """The fit's flags without advice the data contradict: a "poorly identifiable" parameter whose bootstrap
    interval resolves it (the Gauss-Newton resolution is pessimistic where the bootstrap measured)."""
    from .uncertainty import PRECISION

    unc = result.uncertainty
    out = []
    for f in result.flags:
        name = f.split(" ")[0]
        if unc is not None and " is poorly identifiable" in f and name in unc.interval:
            lo, hi = unc.interval[name]
            v = result.parameters[name]
            if v and max(v - lo, hi - v) / abs(v) <= PRECISION:
                continue
        out.append(f)
    return out
