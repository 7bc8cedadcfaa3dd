"""Trusted or doubtful: the settings the data support, the fit against the noise, and a verdict per parameter.

An identification rests on settings the markers alone do not give: the end conditions (clamped or free), the
wall form (thick or membrane) and the law. Where the user does not state them, each is fitted and judged by
the virtual-work gaps *in noise units*: the gaps whitened by their full first-order covariance (marker noise,
the reference's error shared by every step, the readings; floored at ``NOISE_FLOOR`` for the discretisation:
``setting_noise``), each setting refitted by generalised least squares, the whitened gaps squared and summed
(``chi2``). Two settings whose ``chi2`` differ by more than ``DECIDES``
are told apart by the data; otherwise the data cannot tell, and a parameter whose estimates under them differ
by more than ``AGREE`` of its 95 % half-width is doubtful, with the option to pass. The same sum over the
degrees of freedom says whether the model fits within the noise (``POOR_FIT``).

Trusted means: every setting given or supported by the data, the model fits within the noise, no other law
fits clearly better, and a 95 % interval meant to cover (the bootstrap's, or the efficient fit's covariance's:
``efficient_uncertainty``). Thresholds measured in
``docs/validation/trust.md`` (``python -m benchmarks.bench_trust --part table``). Pure functions over arrays.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Any, Mapping

import numpy as np

from .checks import with_end_force, with_ends
from .errors import IdentificationError
from .fit import axial_stretches, identify_prepared
from .setting_noise import NOISE_FLOOR, SettingNoise, setting_noise, whitened_fit
from .vfm import VFMData, prepare

__all__ = ["AGREE", "DECIDES", "LAWS", "NOISE_FLOOR", "POOR_FIT", "Hypothesis", "axial_stretches", "fit_hypotheses",
           "force_gaps", "judge", "law_gaps", "with_force"]

log = logging.getLogger(__name__)

#: Difference of the summed squared gaps in noise units above which the data tell two settings apart.
DECIDES = 9.0
#: Mean squared gap in noise units (per degree of freedom) above which the model does not fit within the noise.
POOR_FIT = 4.0
#: Two settings the data cannot tell apart matter for a parameter whose estimates differ by more than this
#: fraction of its 95 % half-width.
AGREE = 0.5
#: Laws compared with the one identified (one more fit each).
LAWS = ("fung", "delfino", "hgo")


@dataclass(frozen=True)
class Hypothesis:
    """One setting of the data: ``wall``, ``ends``, the data prepared so, the fit (the paper's, or the generalised
    least squares' for the efficient weighting), the setting's gap noise ``noise`` (``SettingNoise``) and ``chi2``
    (the summed squared whitened gaps of the generalised least-squares fit: the smallest this setting reaches)."""

    wall: str
    ends: str
    data: VFMData
    fit: Any  # IdentificationResult
    noise: SettingNoise
    chi2: float

    @property
    def dof(self) -> int:
        return max(int(self.fit.residuals[:, 1:].size) - len(self.fit.parameters), 1)

    @property
    def noise_units(self) -> float:
        """RMS gap over its noise (1: the model fits within the noise)."""
        return float(np.sqrt(self.chi2 / self.dof))


def _best_fit(data: VFMData, model, initial):
    fits = [identify_prepared(data, model, initial=initial)]
    try:
        fits.append(identify_prepared(data, model))
    except (IdentificationError, ValueError) as exc:
        log.debug("multi-start refit failed: %s", exc)
    return min(fits, key=lambda f: f.cost if np.isfinite(f.cost) else np.inf)


def _judged(wall: str, ends: str, data: VFMData, paper, model, noise: SettingNoise, efficient: bool) -> Hypothesis:
    """The hypothesis of ``data`` with its paper's fit ``paper``: refitted by generalised least squares."""
    try:
        gls, _, chi2 = whitened_fit(data, model, noise, paper.parameters)
    except (IdentificationError, ValueError, np.linalg.LinAlgError) as exc:
        log.info("%s wall, %s ends not refitted with the gaps' covariance (%s)", wall, ends, exc)
        W = noise.whitening(model, paper.parameters, data.scale)
        gls, chi2 = paper, float(np.sum(np.nan_to_num((W @ paper.residuals.ravel()), nan=1e6) ** 2))
    return Hypothesis(wall, ends, data, gls if efficient else paper, noise, chi2)


def fit_hypotheses(first, positions: np.ndarray, walls, ends_list, *, prepare_options: Mapping | None = None,
                   efficient: bool = False):
    """Fit ``first``'s model under every (wall, ends) of ``walls`` x ``ends_list`` and judge each over the gaps'
    full covariance (``setting_noise``).

    ``first`` is an ``IdentificationResult`` of ``identify`` under (walls[0], ends_list[0]) with its data;
    ``positions`` (n_steps, n_markers, 3) are the steps it used. ``efficient``: each hypothesis's ``fit`` is its
    generalised least-squares fit (what ``weighting="efficient"`` reports), else the paper's.
    Returns a list of :class:`Hypothesis`.
    """
    data0, model = first.data, first.model
    given = dict(prepare_options or {})
    options = {k: v for k, v in given.items()
               if k not in ("mesh", "smoothing", "wall", "ends", "reject_outliers", "marker_weights",
                            "reference_captures", "efficient")}
    out, noise = [], None
    for wall in walls:
        if wall == data0.wall:
            dw = data0
        else:
            try:
                dw = prepare(positions, data0.pressure, data0.axial_force, thickness=data0.thickness, wall=wall,
                             ends=data0.ends, mesh=data0.mesh, smoothing=data0.smoothing, **options)
            except (IdentificationError, ValueError) as exc:
                log.info("wall form %s not tried: %s", wall, exc)
                continue
        for ends in ends_list:
            d = dw if ends == dw.ends else with_ends(dw, ends)
            fit = first if d is data0 else _best_fit(d, model, first.parameters)
            # one covariance built: the other ends' from the same moved sets (``for_ends``), of a dense cloud the
            # other wall form's too (``for_wall``); elsewhere one per wall form
            noise = setting_noise(d, positions, options=given, like=noise)
            out.append(_judged(wall, ends, d, fit, model, noise, efficient))
    return out


def _chi2(h: Hypothesis, data: VFMData, model, initial) -> float:
    """The smallest summed squared whitened gaps of ``model`` on ``data`` (``h``'s noise, rescaled to ``data``'s
    external-work scale), from ``initial`` or the model's starts."""
    W = h.noise.whitening(h.fit.model, h.fit.parameters, data.scale)
    fit = identify_prepared(data, model, initial=initial, whitening=W)
    return float(np.sum(np.where(np.isfinite(fit.residuals), fit.residuals, 1e6) ** 2))


def law_gaps(h: Hypothesis, laws=LAWS) -> dict[str, float]:
    """``chi2`` of each other law of ``laws`` fitted to the chosen hypothesis's data (one generalised
    least-squares fit each, with the chosen fit's covariance)."""
    out = {}
    for law in laws:
        if law == h.fit.model:
            continue
        try:
            out[law] = _chi2(h, h.data, law, None)
        except (IdentificationError, ValueError, np.linalg.LinAlgError) as exc:
            log.debug("law %s not compared: %s", law, exc)
    return out


def with_force(data: VFMData, axial_force: np.ndarray) -> VFMData:
    """The same virtual-work data with another wall force (n_steps,) N at the load-cell end (only the end work
    changes)."""
    f = np.asarray(axial_force, dtype=float)
    n_end = f + (data.strip_force if data.ends == "clamped" and data.strip_force is not None else 0.0)
    return with_end_force(data, n_end, axial_force=f)


def force_gaps(h: Hypothesis) -> dict[str, float]:
    """``chi2`` (in the chosen hypothesis's noise units) if the force given were not the wall force: a total
    reading behind a closed cannula (the wall force is the reading + p pi r_i^2, decision 0003), or a wall force
    already corrected that was not a total reading (- p pi r_i^2); r_i the reference lumen radius."""
    mesh, data = h.data.mesh, h.data
    used = mesh.used & np.isfinite(mesh.r)
    if not used.any():
        return {}
    r_i = float(np.median(mesh.r[used])) - data.thickness
    lumen = data.pressure * np.pi * r_i**2
    out = {}
    for label, sign in (("a total reading (wall force = reading + p pi r_i^2)", 1.0),
                        ("the wall force minus the pressure on the lumen (a wall reading corrected as total)", -1.0)):
        try:
            out[label] = _chi2(h, with_force(data, data.axial_force + sign * lumen), h.fit.model, h.fit.parameters)
        except (IdentificationError, ValueError, np.linalg.LinAlgError) as exc:
            log.debug("force reading %s not tried: %s", label, exc)
    return out


def _half_width(result, name: str) -> float:
    unc = result.uncertainty
    v = result.parameters[name]
    if unc is not None:
        lo, hi = unc.interval[name]
        return float(max(v - lo, hi - v))
    return float(1.96 * result.stderr[name])


def _said(h: Hypothesis, chosen: Hypothesis) -> str:
    parts = []
    if h.ends != chosen.ends:
        parts.append(f"{h.ends} ends")
    if h.wall != chosen.wall:
        parts.append(f"{h.wall} wall")
    return " and ".join(parts) or "the same setting"


def _option(h: Hypothesis, chosen: Hypothesis) -> str:
    out = []
    if h.ends != chosen.ends:
        out.append("--ends clamped|free")
    if h.wall != chosen.wall:
        out.append("--wall thick|membrane")
    return " and ".join(out)


def _settings_reasons(result, chosen: Hypothesis, others, stated: dict) -> tuple[list, list, dict]:
    """Reasons (doubt, notes) and per-parameter doubts from the settings the user did not state."""
    doubts: list[str] = []
    notes: list[str] = []
    per: dict[str, str] = {}
    for h in others:
        delta = h.chi2 - chosen.chi2
        what = _said(h, chosen)
        unstated = [k for k in ("ends", "wall") if getattr(h, k) != getattr(chosen, k) and not stated[k]]
        if not unstated:
            continue
        if delta >= DECIDES:
            notes.append(f"{' and '.join(unstated)} not given: the data say {chosen.ends} ends, {chosen.wall} wall "
                         f"({what} leave gaps {h.noise_units:.1f} against {chosen.noise_units:.1f} noise units)")
            continue
        moved = []
        for name, v in result.parameters.items():
            diff = abs(h.fit.parameters[name] - v)
            half = _half_width(result, name)
            if not np.isfinite(half) or diff > AGREE * half:
                moved.append(name)
                per.setdefault(name, f"{' and '.join(unstated)} not given and the data cannot tell them apart: with "
                                     f"{what} {name} is {h.fit.parameters[name]:.4g} (here {v:.4g}); pass "
                                     f"{_option(h, chosen)}")
        if moved:
            doubts.append(f"{' and '.join(unstated)} not given and the data cannot tell {chosen.ends} ends, "
                          f"{chosen.wall} wall from {what} ({h.noise_units:.1f} against {chosen.noise_units:.1f} "
                          f"noise units), which move {', '.join(moved)}: pass {_option(h, chosen)}")
        else:
            notes.append(f"the data cannot tell {what} from this setting, but the parameters agree under both "
                         "within their intervals")
    return doubts, notes, per


def _law_reasons(result, chosen: Hypothesis, laws: Mapping[str, float], n_stretches: int) -> tuple[list, list]:
    doubts, notes = [], []
    better = {k: v for k, v in laws.items() if v < chosen.chi2 - DECIDES}
    if better:
        law = min(better, key=lambda k: better[k])
        doubts.append(f"assumption contradicted: the {law} law fits these data better ({np.sqrt(better[law] / chosen.dof):.1f} "
                      f"against {chosen.noise_units:.1f} noise units) than {result.model}")
    same = [k for k, v in laws.items() if abs(v - chosen.chi2) < DECIDES]
    if same and n_stretches < 2:
        notes.append(f"one axial stretch: the data cannot tell {result.model} from {', '.join(same)} (gaps within "
                     "the noise under each); steps at two or more axial stretches (e.g. 1.0, 1.1, 1.2 at each "
                     "pressure) would tell the laws apart")
    return doubts, notes


def fit_units(result, chosen: Hypothesis) -> tuple[float, str]:
    """How far the result's gaps are from their noise (1: within it), and what that noise is.

    The efficient fit's whitened gaps (``Uncertainty.model_error_factor`` of the "gls" intervals: sqrt of chi2 per
    degree of freedom over the gaps' full covariance, floored at 1) where the result has them; else the chosen
    setting's (``Hypothesis.noise_units``: the same covariance, floored for the discretisation). A per-gap spread
    ignores that every step's gaps share the
    reference's error: on data whose reference was captured several times and averaged it put 10 of 40 correct
    fits beyond 2 noise units (thick tube, one stretch, 0.17 mm), the full covariance none."""
    unc = result.uncertainty
    if unc is not None and getattr(unc, "method", "") == "gls" and np.isfinite(unc.model_error_factor):
        return float(unc.model_error_factor), "generalised least squares over their full covariance"
    return float(chosen.noise_units), "their full covariance, floored for the discretisation"


def judge(result, chosen: Hypothesis, others, *, stated: dict, laws: Mapping[str, float] | None = None,
          paper_fit=None, forces: Mapping[str, float] | None = None):
    """``result`` (the fit under ``chosen``) with ``verdict``, ``verdict_reasons``, ``parameter_verdicts``,
    ``parameter_reasons`` and ``hypotheses`` set.

    ``stated``: ``{"ends": bool, "wall": bool}``, whether the user gave them. ``laws``: ``law_gaps``;
    ``forces``: ``force_gaps`` (what the load cell measures).
    ``paper_fit``: the paper's (unweighted) fit when ``result`` was noise-weighted, to check they agree.
    """
    names = list(result.parameters)
    doubts, notes, per = _settings_reasons(result, chosen, others, stated)
    all_doubt: list[str] = []
    units, spread = fit_units(result, chosen)
    if units ** 2 > POOR_FIT:
        notes = [f"the settings not given could not be judged: no setting fits within the noise (best "
                 f"{chosen.ends} ends, {chosen.wall} wall)"] if others and not all(stated.values()) else []
        all_doubt.append(f"poor fit: the virtual-work gaps are {units:.1f}x their noise ({spread}); the "
                         f"{result.model} law or a setting does not describe these data")
    for label, chi2 in (forces or {}).items():
        if chi2 < chosen.chi2 - DECIDES:
            all_doubt.append(f"assumption contradicted: the force given fits as {label} "
                             f"({np.sqrt(chi2 / chosen.dof):.1f} against {chosen.noise_units:.1f} noise units); "
                             "check what the load cell measures (import-markers --force-is wall|total)")
    law_doubts, law_notes = _law_reasons(result, chosen, laws or {}, axial_stretches(chosen.data))
    all_doubt += law_doubts
    notes += law_notes
    if result.uncertainty is None:
        all_doubt.append("Gauss-Newton errors: the 95 % interval is not meant to cover on noisy markers; use the "
                         "default intervals (uncertainty='auto', --uncertainty auto) or the bootstrap")
    if not result.converged:
        all_doubt.append("the optimiser did not converge")
    for flag in result.flags:  # "NAME is poorly identifiable ..." that the bootstrap did not resolve either
        name = flag.split(" ")[0]
        if " is poorly identifiable" in flag and name in names:
            per.setdefault(name, f"{name} is poorly identifiable: the other parameters compensate a change of it "
                                 "within the noise, and its interval is not to be relied on"
                                 + (" (load at two or more axial stretches to constrain it)"
                                    if name == "alpha12" and axial_stretches(chosen.data) < 2 else ""))
    for flag in result.flags:  # "a, b ended on the search bounds: ..." (fit._flags)
        if " ended on the search bounds" in flag:
            for name in flag.split(" ended on")[0].split(", "):
                if name in names:
                    per.setdefault(name, f"{name} ended on the search bounds: its value is not a minimum")
    if paper_fit is not None:
        for name in names:
            half = _half_width(result, name)
            if abs(paper_fit.parameters[name] - result.parameters[name]) > 2 * half:
                per.setdefault(name, f"the noise-weighted and the paper's estimates of {name} differ by more than "
                                     "twice its half-width: the noise model does not describe these data; use "
                                     "--weighting paper")
    doubts += all_doubt
    p_verdicts = {n: "doubtful" if (all_doubt or n in per) else "trusted" for n in names}
    p_reasons = {n: per.get(n, all_doubt[0] if all_doubt else "") for n in names}
    if not doubts and any(v == "doubtful" for v in p_verdicts.values()):
        doubts.append("; ".join(sorted({p_reasons[n] for n in names if p_verdicts[n] == "doubtful"})))
    verdict = "doubtful" if doubts else "trusted"
    hyps = tuple({"ends": h.ends, "wall": h.wall, "parameters": dict(h.fit.parameters),
                  "gap_noise_units": h.noise_units, "chosen": h is chosen} for h in (chosen, *others))
    return replace(result, verdict=verdict, verdict_reasons=tuple(doubts + notes), parameter_verdicts=p_verdicts,
                   parameter_reasons=p_reasons, hypotheses=hyps)
