"""Assemble the HTML report of a session: sections of text, tables and embedded PNG figures."""

from __future__ import annotations

import base64
import datetime as _dt
import html
import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.errors import InputError
from acquisition.session import DamagedSessionError, Session, open_session
from vfmlab import __version__
from vfmlab.display import display_quantity, fixed, num, quantity, settings_text
from vfmlab.fields import FieldsError, SurfaceFields, compute_fields, stress_strain_curves
from vfmlab.report import figures, profile
from vfmlab.results import parameter_units

log = logging.getLogger(__name__)

__all__ = ["build_report", "ReportError", "SECTION_FAILED"]

#: Marker text placed in a section whose drawing raised an unexpected error (tests look for it).
SECTION_FAILED = "This section could not be drawn"

_CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',Helvetica,Arial,sans-serif;max-width:1100px;margin:2em auto;
padding:0 1em;color:#222;line-height:1.45}
h1{border-bottom:2px solid #345;padding-bottom:.2em}h2{margin-top:2em;border-bottom:1px solid #ccc;color:#234}
table{border-collapse:collapse;margin:.6em 0;font-size:.92em}th,td{border:1px solid #ccc;padding:.25em .6em;
text-align:left;vertical-align:top}th{background:#eef2f6}td.num{text-align:right;font-variant-numeric:tabular-nums}
figure{margin:1em 0}figure img{max-width:100%;height:auto;border:1px solid #eee}figcaption{font-size:.9em;color:#555}
pre{background:#f6f8fa;padding:.8em;overflow-x:auto;font-size:.85em;border:1px solid #e1e4e8}
.absent{color:#777;font-style:italic}.failed{color:#a00}.flag{color:#a60;font-weight:bold}
nav ul{columns:2;font-size:.92em}
"""


class ReportError(InputError):
    """The report cannot be written: the session cannot be read (exit code 2, decision 0007)."""


@dataclass
class _Report:
    out_dir: Path
    strain_scale: str = "shared"  # colour scale of the surface maps: "shared" by all steps or "per-step"
    sections: list[tuple[str, str, str]] = field(default_factory=list)  # (anchor, title, body html)
    figures: list[Path] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)

    def figure(self, fig, name: str, caption: str) -> str:
        """Save ``fig`` as PNG in out_dir and return an <figure> with the PNG embedded as base64."""
        path = self.out_dir / f"fig{len(self.figures) + 1:02d}_{name}.png"
        fig.savefig(path, dpi=110)
        self.figures.append(path)
        data = base64.b64encode(path.read_bytes()).decode("ascii")
        return (f'<figure><img alt="{html.escape(caption)}" src="data:image/png;base64,{data}">'
                f"<figcaption>Figure {len(self.figures)}. {html.escape(caption)} "
                f"(<code>{html.escape(path.name)}</code>)</figcaption></figure>")


def _absent(sentence: str) -> str:
    return f'<p class="absent">{html.escape(sentence)}</p>'


def _table(header: list[str], rows: list[list[Any]], numeric: set[int] = frozenset()) -> str:
    out = ["<table><tr>" + "".join(f"<th>{html.escape(str(h))}</th>" for h in header) + "</tr>"]
    for row in rows:
        cells = []
        for j, v in enumerate(row):
            cls = ' class="num"' if j in numeric else ""
            cells.append(f"<td{cls}>{v if isinstance(v, _Raw) else html.escape(str(v))}</td>")
        out.append("<tr>" + "".join(cells) + "</tr>")
    return "".join(out) + "</table>"


class _Raw(str):
    """Already-escaped HTML for a table cell."""


_SCALE_WORDS = {True: "one colour scale shared by all steps: colours compare across steps",
                False: "one colour scale per step: colours compare within a step only (see each colour bar)"}
_SCALE_WORDS_BY_NAME = {"shared": True, "per-step": False}


def _fmt(value: float, digits: int = 4) -> str:
    return num(value, digits)


class _Context:
    """What the sections read: the open session, its latest results and the computed surface fields."""

    def __init__(self, session: Session):
        self.session = session
        self.steps = session.steps
        self.damaged: list[str] = []
        self.markers = self._read(lambda: session.latest("markers"))
        self.calibration = self._read(lambda: session.latest("calibration"))
        self.idents = [r for r in (self._read(lambda n=n: session.result(n)) for n in session.results("identification"))
                       if r is not None]
        latest: dict[str, dict] = {}
        for r in self.idents:  # newest result per (model, wall)
            latest[(str(r["attrs"].get("model", "?")), str(r["attrs"].get("wall", "")))] = r
        self.latest_idents = list(latest.values())
        self.fields: SurfaceFields | None = None
        self.fields_error: str | None = None
        if self.markers is not None:
            try:
                self.fields = compute_fields(self.markers, self.steps, self.latest_idents)
            except (FieldsError, ValueError, np.linalg.LinAlgError) as exc:
                self.fields_error = str(exc)
                log.warning("surface fields unavailable: %s", exc)

    def _read(self, read: Callable[[], Any]) -> Any:
        """A result, or None (and the reason logged and kept in ``damaged``) when it is damaged."""
        try:
            return read()
        except DamagedSessionError as exc:
            log.warning("%s", exc)
            self.damaged.append(str(exc))
            return None

    def no_fields(self) -> str:
        if self.markers is None:
            return _absent("No marker reconstruction is stored in this session (run 'vfmlab reconstruct' or "
                           "'vfmlab import-markers'), so there are no surface fields to show.")
        return _absent(f"The surface fields could not be computed from {self.markers['name']}: {self.fields_error}")


# -- sections --------------------------------------------------------------------------------

def _sec_specimen(ctx: _Context, rep: _Report) -> str:
    s = ctx.session
    sp = s.specimen
    rows = [["specimen id", sp.specimen_id], ["reference radius of the marker surface", f"{sp.radius * 1e3:.3f} mm"],
            ["reference length", f"{sp.length * 1e3:.3f} mm"], ["reference wall thickness", f"{sp.thickness * 1e3:.3f} mm"],
            ["notes", sp.notes or "–"], ["session status", s.status], ["started", s.start_time or "–"],
            ["recorded with", f"vfmlab {s.software_version or '?'} (schema {s.schema_version})"],
            ["steps captured", f"{s.n_steps} ({int(ctx.steps['active'].sum())} active)"]]
    warnings = [e["message"] for e in s.events() if e["kind"] == "warning"]  # plausibility, decision 0007
    rows += [["input warnings", w] for w in warnings] + [["damaged (left out)", d] for d in ctx.damaged]
    return _table(["property", "value"], rows)


def _sec_protocol(ctx: _Context, rep: _Report) -> str:
    s = ctx.session
    out = []
    text = s.protocol_text
    if text.strip():
        out.append(f"<p>Protocol file as run (SHA-256 <code>{html.escape(s.protocol_sha256)}</code>):</p>")
        out.append(f"<pre>{html.escape(text)}</pre>")
    else:
        out.append(_absent("No protocol file is stored (e.g. a session imported from marker data)."))
    if s.n_steps:
        log_ = s.log("pressure")
        fig = figures.protocol_steps(ctx.steps, log_ if len(log_["value"]) > 1 else None)
        out.append(rep.figure(fig, "protocol", "Pressure and axial stretch of each captured step, and the "
                                               "continuous pressure log."))
    else:
        out.append(_absent("No step was captured."))
    events = s.events()
    if events:
        rows = [[_dt.datetime.fromtimestamp(e["time"], _dt.UTC).strftime("%Y-%m-%d %H:%M:%S"), e["kind"],
                 e["message"]] for e in events[:50]]
        out.append("<p>Events (operator notes, pauses, faults):</p>" + _table(["time (UTC)", "kind", "message"], rows))
    return "".join(out)


def _sec_instruments(ctx: _Context, rep: _Report) -> str:
    s = ctx.session
    rows = []
    for role, info in s.instruments.items():
        settings = settings_text(info["settings"]) if info["settings"] else "–"
        rows.append([role, info["identity"] or "–", settings])
    out = [_table(["instrument", "identity", "settings read back"], rows)]
    out.append(f"<p>The load cell measures the <b>{html.escape(s.load_cell_measures)}</b> force "
               "(<i>wall</i>: force carried by the wall; <i>total</i>: reading behind a pressurised cannula).</p>")
    cams = s.cameras
    if cams:
        out.append(_table(["camera", "model", "image (px)", "pixel type"],
                          [[c.name, c.model, f"{c.width} × {c.height}", c.dtype] for c in cams]))
    else:
        out.append(_absent("No camera is recorded in this session."))
    return "".join(out)


def _sec_calibration(ctx: _Context, rep: _Report) -> str:
    cal = ctx.calibration
    if cal is None:
        return _absent("No camera calibration is stored in this session (run 'vfmlab calibrate').")
    a = cal["arrays"]
    if "rms" not in a:
        return _absent(f"{cal['name']} holds no reprojection errors ('rms').")
    names = [str(n) for n in a.get("camera_names", [f"camera {i}" for i in range(len(a["rms"]))])]
    rms = np.asarray(a["rms"], float)
    out = [f"<p>Result <code>{html.escape(cal['name'])}</code> ({html.escape(str(cal['attrs'].get('date', '')))}), "
           f"{len(names)} cameras; reprojection RMS error {np.nanmin(rms):.3f}–{np.nanmax(rms):.3f} px "
           f"(mean {np.nanmean(rms):.3f} px).</p>"]
    at = cal["attrs"]
    extra = []
    if "rms_total" in at:
        extra.append(f"overall {_fmt(float(at['rms_total']), 3)} px")
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


def _sec_markers(ctx: _Context, rep: _Report) -> str:
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


def _sec_strain(ctx: _Context, rep: _Report) -> str:
    f = ctx.fields
    if f is None:
        return ctx.no_fields()
    if len(f.positions) < 2:
        return _absent("Only the reference step is reconstructed: there is no deformation to map.")
    out = [f"<p>Green–Lagrange strains per triangle relative to step 0, drawn on the unrolled reference surface "
           f"(R θ, z). Computed by {html.escape(f.sources['strain'])}.</p>"]
    shown = figures.map_steps(len(f.positions))
    if len(shown) < len(f.positions) - 1:
        out.append(f"<p>{len(shown)} of {len(f.positions) - 1} loaded steps are shown.</p>")
    shared = rep.strain_scale == "shared"
    out.append(f"<p>Colour scale: {_SCALE_WORDS[shared]}.</p>")
    for comp, name in (("E11", "circumferential"), ("E22", "axial")):
        fig = figures.surface_maps(f, f.kin[comp], title=f"{comp}: {name} strain", label=f"{comp} (%)", scale=100,
                                    min_span=0.05, shared=shared)
        out.append(rep.figure(fig, f"strain_{comp}", f"{name.capitalize()} Green–Lagrange strain {comp} at each step "
                                                     f"(paper Fig. 3); {_SCALE_WORDS[shared].split(':')[0]}."))
    return "".join(out)


def _sec_stress(ctx: _Context, rep: _Report) -> str:
    f = ctx.fields
    if f is None:
        return ctx.no_fields()
    if not ctx.latest_idents:
        return _absent("No identification is stored in this session (run 'vfmlab identify'), so there are no "
                       "model stresses to map.")
    if not f.stress:
        return _absent("The identified models' stresses could not be evaluated (the identification package's "
                       "constitutive models are not available for these results).")
    shared = rep.strain_scale == "shared"
    out = ["<p>Cauchy stresses of each identified model evaluated on the measured strains (paper Fig. 4). "
           f"Colour scale: {_SCALE_WORDS[shared]}.</p>"]
    for name, st in f.stress.items():
        for comp, label in (("s11", "circumferential σθθ"), ("s22", "axial σzz")):
            fig = figures.surface_maps(f, st[comp], title=f"{name} ({st['model']}): {label}",
                                       label=f"{label.split()[1]} (kPa)", scale=1e-3, min_span=0.1, shared=shared)
            out.append(rep.figure(fig, f"stress_{name}_{comp}", f"{label} from {name} ({st['model']}); "
                                                                 f"{_SCALE_WORDS[shared].split(':')[0]}."))
    return "".join(out)


def _sec_virtual_work(ctx: _Context, rep: _Report) -> str:
    if not ctx.latest_idents:
        return _absent("No identification is stored in this session, so there is no virtual work to compare.")
    fig = figures.virtual_work(ctx.latest_idents, ctx.steps["pressure"])
    if fig is None:
        return _absent("The stored identifications hold no internal/external virtual work arrays ('ivw', 'evw').")
    return rep.figure(fig, "virtual_work", "Internal (identified parameters) and external virtual work per step for "
                                           "each virtual field and model (paper Figs. 5–6).")


def _curves(ctx: _Context) -> dict[str, Any]:
    if getattr(ctx, "_curves_cache", None) is None:
        ctx._curves_cache = stress_strain_curves(ctx.fields, ctx.fields.force, ctx.session.specimen.thickness,
                                                 ctx.session.load_cell_measures, ctx.latest_idents)
    return ctx._curves_cache


def _sec_pressure_radius(ctx: _Context, rep: _Report) -> str:
    f = ctx.fields
    if f is None:
        return ctx.no_fields()
    r = _curves(ctx)["radius"]
    out = [rep.figure(figures.pressure_radius(f.pressure, r, f.stretch), "pressure_radius",
                      "Pressure against the mean radius of the mid-span markers (middle 20 % of the marked length).")]
    out.append(_table(["step", "pressure (mmHg)", "λz", "mid-span radius (mm)"],
                      [[k, fixed(p / figures.MMHG, 1), f"{s:.3f}", _fmt(ri * 1e3, 5)]
                       for k, (p, s, ri) in enumerate(zip(f.pressure, f.stretch, r))], numeric={0, 1, 2, 3}))
    return "".join(out)


def _sec_stress_strain(ctx: _Context, rep: _Report) -> str:
    f = ctx.fields
    if f is None:
        return ctx.no_fields()
    c = _curves(ctx)
    total = ctx.session.load_cell_measures == "total"
    out = ["<p>Laplace-law estimates (global equilibrium of a thin incompressible tube): σθθ = p r / h and "
           "σzz = N / (2π r h), with r the mean mid-span radius, h = H / (λθ λz) the current thickness and N the "
           f"wall force ({'load-cell reading + p π r_i²' if total else 'load-cell reading'}). "
           f"Computed by {html.escape(c['source'])}.</p>"]
    if not c["models"]:
        out.append(_absent("No identified model is available; only the Laplace-law estimates are shown."))
    out.append(rep.figure(figures.stress_strain({"E11": c["E11"], "E22": c["E22"]}, c, c["models"], f.stretch),
                          "stress_strain", "Mean mid-span stress against strain: identified models evaluated along "
                                           "the measured path (the measured circumferential and axial strains of "
                                           "each step) against the Laplace-law estimates (paper Fig. 8)."))
    return "".join(out)


def _ident_rows(ctx: _Context) -> list[dict[str, Any]]:
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


def _sec_parameters(ctx: _Context, rep: _Report) -> str:
    if not ctx.idents:
        return _absent("No identification is stored in this session (run 'vfmlab identify').")
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
        out.append(f"<p>Settings: <code>{html.escape(settings) or '–'}</code>; cost {_fmt(row['cost'])}; "
                   f"{'converged' if row['converged'] else '<b>did not converge</b>'}; vfmlab "
                   f"{html.escape(str(r['attrs'].get('version', '?')))}, {html.escape(str(r['attrs'].get('date', '')))}.</p>")
        tab = []
        for i, (n, si_unit) in enumerate(zip(names, parameter_units(row["model"], names))):
            rel = stderr[i] / abs(values[i]) * 100 if values[i] else np.nan
            shown, unit = display_quantity(values[i], si_unit)  # SI inside, kPa / degrees on the page
            err, _ = display_quantity(stderr[i], si_unit)
            unit = unit or "–"
            if isinstance(flags, dict):
                flag = flags.get(n, "")
            else:  # plain-words flags: those about this parameter, shortened to their first clause
                flag = "; ".join(str(f).split(":")[0] for f in (flags or []) if str(f).startswith(f"{n} "))
            tab.append([n, _fmt(shown), _fmt(err, 2), _fmt(rel, 2), unit,
                        _Raw(f'<span class="flag">{html.escape(str(flag))}</span>') if flag else ""])
        out.append(_table(["parameter", "value", "std. error", "rel. error (%)", "unit", "identifiability"], tab,
                          numeric={1, 2, 3}))
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


def _sec_comparison(ctx: _Context, rep: _Report) -> str:
    rows = _ident_rows(ctx)
    if len(rows) < 2:
        return _absent("Fewer than two identifications are stored, so there is nothing to compare.")
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
        tab.append([row["name"], row["model"], row["wall"], _fmt(row["cost"]), "yes" if row["converged"] else "no"]
                   + [quantity(vals[n], units[n]) if n in vals else "" for n in all_names])
    best = min((r for r in rows if r["cost"] is not None), key=lambda r: r["cost"], default=None)
    out = [_table(["result", "model", "wall", "cost", "converged"] + all_names, tab, numeric=set(range(3, 5 + len(all_names))))]
    if best is not None:
        out.append(f"<p>Lowest cost: <b>{html.escape(best['name'])}</b> ({html.escape(best['model'])}). Costs are "
                   "comparable between models only when they use the same virtual fields and normalisation.</p>")
    fig = figures.model_costs(rows)
    if fig is not None:
        out.append(rep.figure(fig, "model_costs", "Final cost of each identification."))
    return "".join(out)


def _sec_provenance(ctx: _Context, rep: _Report) -> str:
    s = ctx.session
    rows = []
    for name in s.results():
        r = s.result(name)
        rows.append([name, r["kind"], str(r["attrs"].get("date", "")), str(r["attrs"].get("version", "")),
                     settings_text(r["parameters"])])
    out = [_table(["result", "kind", "date", "vfmlab version", "settings"], rows) if rows else
           _absent("No derived result is stored.")]
    if ctx.fields is not None:
        out.append("<p>Computed for this report by: " + "; ".join(
            f"{html.escape(k)}: {html.escape(v)}" for k, v in ctx.fields.sources.items()) + ".</p>")
    return "".join(out)


_SECTIONS: list[tuple[str, str, Callable[[_Context, _Report], str]]] = [
    ("specimen", "Specimen", _sec_specimen),
    ("protocol", "Protocol", _sec_protocol),
    ("instruments", "Instruments", _sec_instruments),
    ("calibration", "Calibration quality", _sec_calibration),
    ("markers", "Marker reconstruction", _sec_markers),
    ("strain", "Strain maps", _sec_strain),
    ("regional", "Parameters along the axis", lambda ctx, rep: profile.section(ctx, rep)),
    ("stress", "Stress maps", _sec_stress),
    ("virtual-work", "Internal vs external virtual work", _sec_virtual_work),
    ("pressure-radius", "Pressure–radius at mid-span", _sec_pressure_radius),
    ("stress-strain", "Stress–strain curves", _sec_stress_strain),
    ("parameters", "Identified parameters", _sec_parameters),
    ("comparison", "Model comparison", _sec_comparison),
    ("provenance", "Provenance", _sec_provenance),
]


def build_report(session_path: str | Path, out_dir: str | Path | None = None, *, strain_scale: str = "shared") -> Path:
    """Write ``report.html`` (self-contained: figures embedded as PNG) and the figure PNGs into ``out_dir``.

    Parameters
    ----------
    session_path : path of the session file.
    out_dir : output directory (created; its parent must exist); default ``<session stem>_report`` next to the
        session.
    strain_scale : "shared" (one colour scale for all steps of a surface map) or "per-step".

    Returns
    -------
    Path of the HTML file.

    Raises
    ------
    ReportError
        When the session cannot be opened or the output directory cannot be written.
    """
    from acquisition.session import SessionError

    session_path = Path(session_path)
    out = Path(out_dir) if out_dir is not None else session_path.with_name(session_path.stem + "_report")
    try:
        out.mkdir(exist_ok=True)  # the CLI checked that its parent exists
    except OSError as exc:
        raise OSError(exc.errno, f"cannot create the report directory: {exc.strerror}", str(out)) from None
    try:
        session = open_session(session_path)
    except SessionError as exc:
        raise ReportError(str(exc)) from None
    if strain_scale not in _SCALE_WORDS_BY_NAME:
        raise ReportError(f"strain_scale must be one of {', '.join(_SCALE_WORDS_BY_NAME)}; got {strain_scale!r}")
    rep = _Report(out, strain_scale=strain_scale)
    with session:
        t0 = time.perf_counter()
        ctx = _Context(session)
        rep.timings["fields"] = time.perf_counter() - t0
        import matplotlib

        with matplotlib.rc_context(figures._RC):
            for anchor, title, fn in _SECTIONS:
                t = time.perf_counter()
                try:
                    body = fn(ctx, rep)
                except Exception as exc:  # one broken section must not cost the whole report
                    log.warning("report section %r failed: %s: %s", title, type(exc).__name__, exc)
                    log.debug("report section %r failed", title, exc_info=exc)
                    body = f'<p class="failed">{SECTION_FAILED}: {html.escape(type(exc).__name__)}: ' \
                           f"{html.escape(str(exc))}</p>"
                rep.sections.append((anchor, title, body))
                rep.timings[anchor] = time.perf_counter() - t
        specimen = session.specimen.specimen_id
        page = _page(specimen, session_path, rep)
    path = out / "report.html"
    part = out / "report.html.part"  # a Ctrl-C or a full disk mid-write leaves no half page under the real name
    part.write_text(page, encoding="utf-8")
    os.replace(part, path)
    log.info("report %s: %d figures, %.1f s", path, len(rep.figures), sum(rep.timings.values()))
    return path


def _page(specimen: str, session_path: Path, rep: _Report) -> str:
    now = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    nav = "".join(f'<li><a href="#{a}">{html.escape(t)}</a></li>' for a, t, _ in rep.sections)
    body = "".join(f'<section id="{a}"><h2>{html.escape(t)}</h2>{b}</section>' for a, t, b in rep.sections)
    return (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>vfmlab report: {html.escape(specimen)}</title><style>{_CSS}</style></head><body>"
            f"<h1>Inflation/extension test report: {html.escape(specimen)}</h1>"
            f"<p>Session <code>{html.escape(str(session_path))}</code>; report written {now} by vfmlab "
            f"{html.escape(__version__)}.</p><nav><ul>{nav}</ul></nav>{body}</body></html>")
