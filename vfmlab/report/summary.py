"""The report's first page: the answer. Each model's parameters with their 95 % intervals and verdicts side by side,
and the fits against the measured pressure–radius and force–pressure curves.

Verdicts are the stored attributes of an identification result (``verdict``, ``verdict_reasons``,
``parameter_verdicts``, ``parameter_reasons``); results written before verdicts existed show "—".
"""

from __future__ import annotations

import html
import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vfmlab.display import display_quantity, num
from vfmlab.report import curves
from vfmlab.results import parameter_units
from vfmlab.stages.reachable import achieved_half_width

__all__ = ["Verdict", "caveat", "intervals", "read_verdict", "section"]

NO_VERDICT = "—"
_Z95 = 1.959963984540054
#: A model whose pressure or force misfit exceeds this fraction of the measured range fits poorly.
POOR_FIT = 0.25


@dataclass(frozen=True)
class Verdict:
    """The stored verdict of one identification (``overall`` "trusted" | "doubtful", or "—" when not stored)."""

    overall: str = NO_VERDICT
    reasons: list[str] = field(default_factory=list)
    parameters: dict[str, str] = field(default_factory=dict)
    parameter_reasons: dict[str, str] = field(default_factory=dict)


def _decoded(value: Any, kind: type) -> Any:
    if isinstance(value, str) and value[:1] in "[{":
        try:
            value = json.loads(value)
        except ValueError:
            return kind()
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if kind is list and isinstance(value, str):
        return [value] if value else []
    return value if isinstance(value, kind) else kind()


def read_verdict(attrs: Mapping[str, Any]) -> Verdict:
    """The verdict attributes of a result (JSON strings or decoded), or an empty Verdict for older results."""
    overall = attrs.get("verdict")
    return Verdict(overall=str(overall) if overall else NO_VERDICT,
                   reasons=[str(r) for r in _decoded(attrs.get("verdict_reasons", []), list)],
                   parameters={str(k): str(v) for k, v in _decoded(attrs.get("parameter_verdicts", {}), dict).items()},
                   parameter_reasons={str(k): str(v)
                                      for k, v in _decoded(attrs.get("parameter_reasons", {}), dict).items()})


def intervals(result: Mapping[str, Any]) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray, str]:
    """(names, values, low, high, source) of a result's parameters (SI): the stored 95 % interval (the
    bootstrap's or the efficient fit's covariance's, as its ``uncertainty`` attribute says), else value ± 1.96
    standard errors."""
    a = result["arrays"]
    names = [str(n) for n in np.atleast_1d(a.get("parameter_names", []))]
    values = np.asarray(a.get("parameters", []), float)
    if "interval_low" in a and "interval_high" in a:
        how = str(result.get("attrs", {}).get("uncertainty", ""))
        source = "generalised least squares" if how.startswith("generalised least-squares") else "bootstrap"
        return names, values, np.asarray(a["interval_low"], float), np.asarray(a["interval_high"], float), source
    err = np.asarray(a.get("stderr", np.full(len(values), np.nan)), float)
    return names, values, values - _Z95 * err, values + _Z95 * err, "±1.96 s.e."


def caveat(result: Mapping[str, Any], quality: Mapping[str, float] | None = None) -> str | None:
    """Why stresses computed with this result's parameters should be read with care, or None."""
    at = result["attrs"]
    v = read_verdict(at)
    name = f"{result['name']} ({at.get('model', '?')})"
    if v.overall == "doubtful":
        why = "; ".join(v.reasons) or "see its verdict"
        return f"Caution: the identification {name} is doubtful ({why}); its stresses are indicative only."
    if not bool(at.get("converged", True)):
        return f"Caution: the identification {name} did not converge; its stresses are indicative only."
    for key, curve in (("pressure", "pressure–radius"), ("force", "force–pressure")):
        if quality and quality.get(f"{key}_rel", 0) > POOR_FIT:
            return (f"Caution: {name} fits the measured {curve} curve poorly (RMS misfit "
                    f"{quality[f'{key}_rel'] * 100:.0f} % of the measured {key} range); its stresses are indicative "
                    "only.")
    return None


def _reach(achieved: float, reach: Any, name: str) -> str:
    """"±a % achieved / ±r % reachable" of one parameter (the reachable one "n/a" with its reason as a tooltip)."""
    got = f"±{num(achieved, 3)} %" if np.isfinite(achieved) else NO_VERDICT
    if reach is not None and reach.available and name in reach.half_width:
        can = f"±{num(reach.half_width[name], 3)} %"
        why = reach.describe()
    else:
        can, why = "n/a", reach.describe() if reach is not None else "reachable n/a"
    return (f'<br><span class="reach" data-param="{html.escape(name)}" title="{html.escape(why)}">{got} achieved / '
            f'{can} reachable</span>')


def _cell(result: Mapping[str, Any], verdict: Verdict, name: str, reach: Any = None) -> str:
    names, values, lo, hi, _ = intervals(result)
    if name not in names:
        return ""
    i = names.index(name)
    unit = parameter_units(str(result["attrs"].get("model", "")), names)[i]
    shown, u = display_quantity(values[i], unit)
    low, _ = display_quantity(lo[i], unit)
    high, _ = display_quantity(hi[i], unit)
    pv = verdict.parameters.get(name, NO_VERDICT)
    why = verdict.parameter_reasons.get(name, "")
    title = f' title="{html.escape(why)}"' if why else ""
    return (f'<span class="value" data-of="{html.escape(result["name"])}" data-param="{html.escape(name)}" '
            f'data-value="{float(values[i])!r}">{num(shown, 4)}</span> '
            f'{html.escape(u or "")}<br><span class="interval">[{num(low, 3)}, {num(high, 3)}]</span>'
            f'{_reach(float(achieved_half_width(values[i:i + 1], lo[i:i + 1], hi[i:i + 1])[0]), reach, name)}<br>'
            f'<span class="verdict {html.escape(pv)}"{title}>{html.escape(pv)}</span>')


def _side_by_side(ctx, qualities: Mapping[str, Mapping[str, float]]) -> str:
    results = ctx.latest_idents
    verdicts = [read_verdict(r["attrs"]) for r in results]
    reach = [ctx.reachable(r) for r in results]
    params: list[str] = []
    for r in results:
        params += [n for n in intervals(r)[0] if n not in params]
    head = "".join(f'<th data-result="{html.escape(r["name"])}">{html.escape(str(r["attrs"].get("model", "?")))}<br>'
                   f'<small>{html.escape(r["name"])}</small></th>' for r in results)
    rows = [["verdict"] + [f'<span class="verdict {html.escape(v.overall)}">{html.escape(v.overall)}</span>'
                           + (f'<br><small>{html.escape("; ".join(v.reasons))}</small>' if v.reasons else "")
                           for v in verdicts],
            ["cost"] + [num(float(r["attrs"]["cost"]), 3) if "cost" in r["attrs"] else NO_VERDICT for r in results],
            ["converged"] + ["yes" if r["attrs"].get("converged") else "<b>no</b>" for r in results]]
    for key, label, unit, k in (("pressure", "pressure misfit (RMS)", "kPa", 1e-3), ("force", "force misfit (RMS)",
                                                                                       "N", 1.0)):
        rows.append([label] + [f"{num(qualities[r['name']][key] * k, 3)} {unit}" if r["name"] in qualities else
                               NO_VERDICT for r in results])
    rows += [[html.escape(n)] + [_cell(r, v, n, c) for r, v, c in zip(results, verdicts, reach)] for n in params]
    body = "".join("<tr><th>" + row[0] + "</th>" + "".join(f'<td class="num">{c}</td>' for c in row[1:]) + "</tr>"
                   for row in rows)
    notes = "".join(f'<li>{html.escape(r["name"])}: {html.escape(c.describe())}</li>' for r, c in zip(results, reach))
    return (f'<table id="models-side-by-side"><tr><th></th>{head}</tr>{body}</table>'
            f'<ul id="reachable-notes" class="small">{notes}</ul>')


def section(ctx, rep) -> str:
    """The first section: which models were identified, how much to trust each, and how well each fits."""
    if not ctx.latest_idents:
        return ('<p class="absent">No identification is stored in this session (run \'vfmlab identify\'): the '
                "measured curves and maps follow.</p>")
    fits = ctx.fits()
    qualities = {}
    if fits is not None:
        qualities = {m["result"]: curves.fit_quality(fits, label) for label, m in fits["models"].items()}
    sources = {intervals(r)[4] for r in ctx.latest_idents}
    out = [f"<p>The newest identification of each model, side by side: value, 95 % interval "
           f"({html.escape(' or '.join(sorted(sources)))}) and verdict of each parameter; the misfits are the RMS "
           "differences between the pressure and axial force each model predicts at the measured deformation and "
           f"the measured ones. A verdict shows {NO_VERDICT} for results written before verdicts were stored. "
           "\"Achieved\" is the half-width of the 95 % interval in % of the value; \"reachable\" the half-width "
           "the Cramér-Rao bound allows this test (its steps, markers and the marker noise its data show; docs/validation/bound.md): an "
           "achieved interval well above it says the estimator, not the data, limits the result.</p>",
           _side_by_side(ctx, qualities)]
    if fits is None:
        out.append(ctx.no_fields())
        return "".join(out)
    out.append(_lead(ctx, qualities))
    stretch = ctx.fields.stretch
    fig, data = curves.pressure_radius(fits, stretch)
    pr = rep.figure(fig, "pressure_radius", "Measured pressure against the mean mid-span radius (markers) and the "
                    "pressure each model predicts at the measured deformation (lines), Laplace law "
                    f"({curves.PAPER}, Appendix A and Fig. 7).", data)
    fig, data = curves.force_pressure(fits, stretch, ctx.session.load_cell_measures)
    fp = rep.figure(fig, "force_pressure", "Measured axial force against pressure (markers) and the force each model "
                    "predicts at the measured deformation (lines): the second primary measurement of the test "
                    f"({curves.PAPER}, Appendix B).", data)
    out.append(f'<div class="row">{pr}{fp}</div>')
    return "".join(out)


def _lead(ctx, qualities: Mapping[str, Mapping[str, float]]) -> str:
    """One sentence: the model that fits both measured curves best, and whether its verdict trusts it."""
    scored = [(q["pressure_rel"] + q["force_rel"], name) for name, q in qualities.items()
              if np.isfinite(q["pressure_rel"] + q["force_rel"])]
    if not scored:
        return ""
    _, best = min(scored)
    r = next(r for r in ctx.latest_idents if r["name"] == best)
    v = read_verdict(r["attrs"])
    trust = {"trusted": "its verdict is trusted", "doubtful": "but its verdict is doubtful"}.get(
        v.overall, "no verdict is stored for it")
    return (f'<p id="lead">Best fit of the measured pressure and force: <b>{html.escape(str(r["attrs"].get("model")))}'
            f"</b> ({html.escape(best)}; pressure misfit {qualities[best]['pressure_rel'] * 100:.1f} %, force misfit "
            f"{qualities[best]['force_rel'] * 100:.1f} % of the measured range); {trust}.</p>")
