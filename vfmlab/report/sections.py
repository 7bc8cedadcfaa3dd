"""The report's sections after the first page: the figures a paper prints and the details (specimen, protocol,
instruments, calibration, markers, parameters, provenance). Each takes the :class:`Context` and the
:class:`~vfmlab.report.output.ReportFiles` and returns its HTML."""

from __future__ import annotations

import datetime as _dt
import html
from typing import Any

import numpy as np

from vfmlab.display import display_quantity, fixed, quantity, settings_text
from vfmlab.report import curves, figures, summary
from vfmlab.report.context import Context
from vfmlab.report.page import Raw, absent, fmt, table
from vfmlab.results import parameter_units

def specimen(ctx: Context, rep) -> str:
    s = ctx.session
    sp = s.specimen
    rows = [["specimen id", sp.specimen_id], ["reference radius of the marker surface", f"{sp.radius * 1e3:.3f} mm"],
            ["reference length", f"{sp.length * 1e3:.3f} mm"], ["reference wall thickness", f"{sp.thickness * 1e3:.3f} mm"],
            ["notes", sp.notes or "–"], ["session status", s.status], ["started", s.start_time or "–"],
            ["recorded with", f"vfmlab {s.software_version or '?'} (schema {s.schema_version})"],
            ["steps captured", f"{s.n_steps} ({int(ctx.steps['active'].sum())} active)"]]
    warnings = [e["message"] for e in s.events() if e["kind"] == "warning"]  # plausibility, decision 0007
    rows += [["input warnings", w] for w in warnings] + [["damaged (left out)", d] for d in ctx.damaged]
    return table(["property", "value"], rows)


def protocol(ctx: Context, rep) -> str:
    s = ctx.session
    out = []
    text = s.protocol_text
    if text.strip():
        out.append(f"<p>Protocol file as run (SHA-256 <code>{html.escape(s.protocol_sha256)}</code>):</p>")
        out.append(f"<pre>{html.escape(text)}</pre>")
    else:
        out.append(absent("No protocol file is stored (e.g. a session imported from marker data)."))
    if s.n_steps:
        log_ = s.log("pressure")
        fig = figures.protocol_steps(ctx.steps, log_ if len(log_["value"]) > 1 else None)
        out.append(rep.figure(fig, "protocol", "Pressure and axial stretch of each captured step, and the "
                                               "continuous pressure log."))
    else:
        out.append(absent("No step was captured."))
    events = s.events()
    if events:
        rows = [[_dt.datetime.fromtimestamp(e["time"], _dt.UTC).strftime("%Y-%m-%d %H:%M:%S"), e["kind"],
                 e["message"]] for e in events[:50]]
        out.append("<p>Events (operator notes, pauses, faults):</p>" + table(["time (UTC)", "kind", "message"], rows))
    return "".join(out)


def instruments(ctx: Context, rep) -> str:
    s = ctx.session
    rows = []
    for role, info in s.instruments.items():
        settings = settings_text(info["settings"]) if info["settings"] else "–"
        rows.append([role, info["identity"] or "–", settings])
    out = [table(["instrument", "identity", "settings read back"], rows)]
    out.append(f"<p>The load cell measures the <b>{html.escape(s.load_cell_measures)}</b> force "
               "(<i>wall</i>: force carried by the wall; <i>total</i>: reading behind a pressurised cannula).</p>")
    cams = s.cameras
    if cams:
        out.append(table(["camera", "model", "image (px)", "pixel type"],
                          [[c.name, c.model, f"{c.width} × {c.height}", c.dtype] for c in cams]))
    else:
        out.append(absent("No camera is recorded in this session."))
    return "".join(out)


def calibration(ctx: Context, rep) -> str:
    cal = ctx.calibration
    if cal is None:
        return absent("No camera calibration is stored in this session (run 'vfmlab calibrate').")
    a = cal["arrays"]
    if "rms" not in a:
        return absent(f"{cal['name']} holds no reprojection errors ('rms').")
    names = [str(n) for n in a.get("camera_names", [f"camera {i}" for i in range(len(a["rms"]))])]
    rms = np.asarray(a["rms"], float)
    out = [f"<p>Result <code>{html.escape(cal['name'])}</code> ({html.escape(str(cal['attrs'].get('date', '')))}), "
           f"{len(names)} cameras; reprojection RMS error {np.nanmin(rms):.3f}–{np.nanmax(rms):.3f} px "
           f"(mean {np.nanmean(rms):.3f} px).</p>"]
    at = cal["attrs"]
    extra = []
    if "rms_total" in at:
        extra.append(f"overall {fmt(float(at['rms_total']), 3)} px")
    if "n_observations" in at:
        extra.append(f"{int(at['n_observations'])} corner observations")
    if "n_outliers" in at:
        extra.append(f"{int(at['n_outliers'])} outliers rejected")
    if "converged" in at:
        extra.append("converged" if bool(at["converged"]) else "<b>did not converge</b>")
    if extra:
        out.append(f"<p>Bundle adjustment: {', '.join(extra)}.</p>")
    out.append(rep.figure(figures.calibration_rms(names, rms, a.get("rms_per_view")), "calibration_rms",
                          "Reprojection RMS error of the calibration-board corners per camera (bars) and per "
                          "board view (dots)."))
    return "".join(out)


def markers(ctx: Context, rep) -> str:
    m = ctx.markers
    if m is None:
        return ctx.no_fields()
    a = m["arrays"]
    pos = np.asarray(a["positions"], float)
    visible = np.asarray(a.get("visible", np.isfinite(pos).all(axis=2)), bool)
    out = [f"<p>Result <code>{html.escape(m['name'])}</code>: {pos.shape[1]} markers tracked over {pos.shape[0]} "
           f"steps; {visible.mean() * 100:.1f} % of marker-steps reconstructed.</p>"]
    unc = np.asarray(a.get("uncertainty", []), float)
    if unc.size and np.isfinite(unc).any():
        out.append(f"<p>Median reconstruction uncertainty {np.nanmedian(unc) * 1e3:.4f} mm "
                   f"(95th percentile {np.nanpercentile(unc, 95) * 1e3:.4f} mm).</p>")
    rows = np.asarray(a.get("step_index", np.arange(len(pos))), int)
    pressure = ctx.steps["pressure"][np.clip(rows, 0, max(len(ctx.steps["pressure"]) - 1, 0))]
    out.append(rep.figure(figures.markers_per_step(visible, pressure), "markers",
                          "Markers reconstructed per step and tracking completeness."))
    if ctx.fields is None:
        out.append(ctx.no_fields())
    else:
        f = ctx.fields
        out.append(f"<p>Surface mesh: {len(f.mesh.triangles)} triangles on the reference markers "
                   f"(mean reference radius {f.mesh.radius * 1e3:.3f} mm; built by {html.escape(f.mesh.source)}).</p>")
        out.append(rep.figure(figures.mesh_3d(f), "mesh3d", "The marker mesh in the reference configuration and in "
                                                            "the last step, coloured by circumferential strain."))
    return "".join(out)



def virtual_work(ctx: Context, rep) -> str:
    if not ctx.latest_idents:
        return absent("No identification is stored in this session, so there is no virtual work to compare.")
    fig = figures.virtual_work(ctx.latest_idents, ctx.steps["pressure"])
    if fig is None:
        return absent("The stored identifications hold no internal/external virtual work arrays ('ivw', 'evw').")
    return rep.figure(fig, "virtual_work", "Internal (identified parameters) and external virtual work per step for "
                                           f"each virtual field and model ({curves.PAPER}, Figs. 5–6).")



def _ident_rows(ctx: Context) -> list[dict[str, Any]]:
    rows = []
    for r in ctx.idents:
        at = r["attrs"]
        cost = at.get("cost")
        try:
            cost = float(cost)
        except (TypeError, ValueError):
            cost = None
        rows.append({"name": r["name"], "model": str(at.get("model", "?")), "wall": str(at.get("wall", "")),
                     "cost": cost, "converged": bool(at.get("converged", False)), "result": r})
    return rows


def _parameter_row(n: str, si_unit: str, value: float, stderr: float, interval: tuple[float, float], flags: Any,
                   verdict: summary.Verdict) -> list[Any]:
    rel = stderr / abs(value) * 100 if value else np.nan
    shown, unit = display_quantity(value, si_unit)  # SI inside, kPa / degrees on the page
    err, _ = display_quantity(stderr, si_unit)
    lo, _ = display_quantity(interval[0], si_unit)
    hi, _ = display_quantity(interval[1], si_unit)
    if isinstance(flags, dict):
        flag = flags.get(n, "")
    else:  # plain-words flags: those about this parameter, shortened to their first clause
        flag = "; ".join(str(f).split(":")[0] for f in (flags or []) if str(f).startswith(f"{n} "))
    why = verdict.parameter_reasons.get(n, "")
    return [n, fmt(shown), fmt(err, 2), fmt(rel, 2), f"{fmt(lo, 3)} to {fmt(hi, 3)}", unit or "–",
            verdict.parameters.get(n, summary.NO_VERDICT) + (f" ({why})" if why else ""),
            Raw(f'<span class="flag">{html.escape(str(flag))}</span>') if flag else ""]


def parameters(ctx: Context, rep) -> str:
    if not ctx.idents:
        return absent("No identification is stored in this session (run 'vfmlab identify').")
    out = []
    for row in _ident_rows(ctx):
        r = row["result"]
        a = r["arrays"]
        names = [str(n) for n in a.get("parameter_names", [])]
        values = np.asarray(a.get("parameters", []), float)
        stderr = np.asarray(a.get("stderr", np.full(len(values), np.nan)), float)
        flags = r["attrs"].get("flags", {}) or {}
        settings = settings_text(r["parameters"])
        out.append(f"<h3>{html.escape(r['name'])}: {html.escape(row['model'])} ({html.escape(row['wall'])})</h3>")
        out.append(f"<p>Settings: <code>{html.escape(settings) or '–'}</code>; cost {fmt(row['cost'])}; "
                   f"{'converged' if row['converged'] else '<b>did not converge</b>'}; vfmlab "
                   f"{html.escape(str(r['attrs'].get('version', '?')))}, {html.escape(str(r['attrs'].get('date', '')))}.</p>")
        verdict = summary.read_verdict(r["attrs"])
        _, _, low, high, source = summary.intervals(r)
        out.append(f"<p>Verdict: <b>{html.escape(verdict.overall)}</b>"
                   + (f" ({html.escape('; '.join(verdict.reasons))})" if verdict.reasons else "") + ".</p>")
        tab = [_parameter_row(n, si_unit, values[i], stderr[i], (low[i], high[i]), flags, verdict)
               for i, (n, si_unit) in enumerate(zip(names, parameter_units(row["model"], names)))]
        out.append(table(["parameter", "value", "std. error", "rel. error (%)", f"95 % interval ({source})", "unit",
                          "verdict", "identifiability"], tab, numeric={1, 2, 3, 4}))
        if isinstance(flags, dict):
            notes = [f"{k}: {v}" for k, v in flags.items() if k not in names]
        elif isinstance(flags, str):
            notes = [flags] if flags else []
        else:
            notes = [str(v) for v in flags]
        if notes:
            out.append("<p>Identifiability and fit warnings:</p><ul>" + "".join(
                f'<li class="flag">{html.escape(n)}</li>' for n in notes) + "</ul>")
        elif not flags:
            out.append("<p>No identifiability or fit warning.</p>")
        if len(names) > 1:
            fig = figures.correlation_matrix(r)
            if fig is not None:
                out.append(rep.figure(fig, f"correlation_{r['name']}", f"Parameter correlations of {r['name']}."))
    return "".join(out)


def comparison(ctx: Context, rep) -> str:
    rows = _ident_rows(ctx)
    if len(rows) < 2:
        return absent("Fewer than two identifications are stored, so there is nothing to compare.")
    all_names: list[str] = []
    for row in rows:
        for n in row["result"]["arrays"].get("parameter_names", []):
            if str(n) not in all_names:
                all_names.append(str(n))
    tab = []
    for row in rows:
        a = row["result"]["arrays"]
        vals = dict(zip([str(n) for n in a.get("parameter_names", [])], np.asarray(a.get("parameters", []), float)))
        units = dict(zip(vals, parameter_units(row["model"], list(vals))))
        tab.append([row["name"], row["model"], row["wall"], fmt(row["cost"]), "yes" if row["converged"] else "no"]
                   + [quantity(vals[n], units[n]) if n in vals else "" for n in all_names])
    best = min((r for r in rows if r["cost"] is not None), key=lambda r: r["cost"], default=None)
    out = [table(["result", "model", "wall", "cost", "converged"] + all_names, tab, numeric=set(range(3, 5 + len(all_names))))]
    if best is not None:
        out.append(f"<p>Lowest cost: <b>{html.escape(best['name'])}</b> ({html.escape(best['model'])}). Costs are "
                   "comparable between models only when they use the same virtual fields and normalisation.</p>")
    fig = figures.model_costs(rows)
    if fig is not None:
        out.append(rep.figure(fig, "model_costs", "Final cost of each identification."))
    return "".join(out)


def provenance(ctx: Context, rep) -> str:
    s = ctx.session
    rows = []
    for name in s.results():
        r = s.result(name)
        rows.append([name, r["kind"], str(r["attrs"].get("date", "")), str(r["attrs"].get("version", "")),
                     settings_text(r["parameters"])])
    out = [table(["result", "kind", "date", "vfmlab version", "settings"], rows) if rows else
           absent("No derived result is stored.")]
    if ctx.fields is not None:
        out.append("<p>Computed for this report by: " + "; ".join(
            f"{html.escape(k)}: {html.escape(v)}" for k, v in ctx.fields.sources.items()) + ".</p>")
    return "".join(out)



def pressure_radius(ctx: Context, rep) -> str:
    """The measured mid-span curves step by step (the first page draws them against each model)."""
    f = ctx.fields
    fits = ctx.fits()
    if f is None or fits is None:
        return ctx.no_fields()
    return table(["step", "pressure (mmHg)", "λz imposed", "λz measured", "mid-span radius (mm)", "axial force (N)"],
                 [[k, fixed(p / figures.MMHG, 1), f"{s:.3f}", f"{lam:.4f}", fmt(ri * 1e3, 5), fmt(n, 4)]
                  for k, (p, s, lam, ri, n) in enumerate(zip(f.pressure, f.stretch, fits["stretch"], fits["radius_m"],
                                                             fits["force_N"]))], numeric={0, 1, 2, 3, 4, 5})


def stress_strain(ctx: Context, rep) -> str:
    """Mean mid-span stress along the measured path: models against the Laplace-law estimates (paper Fig. 8)."""
    f = ctx.fields
    fits = ctx.fits()
    if f is None or fits is None:
        return ctx.no_fields()
    c = ctx.curves()
    total = ctx.session.load_cell_measures == "total"
    out = ["<p>Laplace-law estimates (global equilibrium of a thin incompressible tube): σθθ = p r / h and "
           "σzz = N / (2π r h), with r the mean mid-span radius, h = H / (λθ λz) the current thickness and N the "
           f"wall force ({'load-cell reading + p π r_i²' if total else 'load-cell reading'}). The axial strain is "
           "fixed within a block, so the axial stress is drawn against the measured stretch (one series per pressure "
           f"level) and against pressure (one series per stretch). Computed by {html.escape(c['source'])}.</p>"]
    if not c["models"]:
        out.append(absent("No identified model is available; only the Laplace-law estimates are shown."))
    fig, data = curves.stress_strain(fits, f.stretch, np.asarray(ctx.steps["target_pressure"], float)[f.steps])
    out.append(rep.figure(fig, "stress_strain", "Mean mid-span stress along the measured path: (a) hoop stress "
                          "against circumferential strain, (b) axial stress against the measured axial stretch, (c) axial "
                          "stress against pressure; identified models (lines) against the Laplace-law estimates "
                          f"(markers) ({curves.PAPER}, Appendices A–B, Fig. 8).", data))
    return "".join(out)
