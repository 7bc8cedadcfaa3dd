"""The report's strain and stress maps (Avril, Badel & Duprey 2010, Figs. 3 and 4).

A field whose spatial pattern is lost in its noise (a homogeneous specimen) is not worth 16 panels of one colour:
:func:`uniformity` fits a smooth pattern (quadratic in z, two harmonics in θ) to each step's per-triangle values and
compares the pattern's spread with the residual (the noise). Fields whose pattern stays within their noise are drawn
together in one summary figure (median and 5–95 % spread per step); the others as maps on the unrolled surface.
Stress maps of a doubtful or poorly fitting model carry a caveat (:func:`vfmlab.report.summary.caveat`).
"""

from __future__ import annotations

import html
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from matplotlib.figure import Figure

from vfmlab.report import curves, figures, summary
from vfmlab.report.page import absent

__all__ = ["Field", "SCALE_WORDS", "stress_section", "strain_section", "uniformity"]

SCALE_WORDS = {True: "one colour scale shared by all steps: colours compare across steps",
               False: "one colour scale per step: colours compare within a step only (see each colour bar)"}


@dataclass(frozen=True)
class Field:
    """One mapped quantity: ``values`` (n_steps, n_triangles) SI, shown × ``scale`` in ``unit``."""

    key: str
    title: str
    values: np.ndarray
    scale: float
    unit: str
    min_span: float
    caption: str
    caveat: str | None = None


def _basis(fields) -> np.ndarray:
    """(n_triangles, 7) smooth functions of the reference triangle centroids: 1, z, z², cos θ, sin θ, cos 2θ, sin 2θ."""
    mesh = fields.mesh
    tri = mesh.triangles
    theta = np.angle(np.exp(1j * mesh.s[tri] / mesh.radius).mean(axis=1))
    z = np.nanmean(mesh.z[tri], axis=1)
    zn = (z - np.nanmean(z)) / max(float(np.nanmax(np.abs(z - np.nanmean(z)))), 1e-12)
    return np.column_stack([np.ones_like(z), zn, zn**2, np.cos(theta), np.sin(theta), np.cos(2 * theta),
                            np.sin(2 * theta)])


def uniformity(fields, values: np.ndarray, steps: np.ndarray, floor: float) -> tuple[bool, float, float]:
    """(uniform, largest pattern spread, its step's noise) of ``values`` (n_steps, n_triangles) over ``steps``.

    Uniform when, at every step, the standard deviation of the fitted smooth pattern is at most the standard
    deviation of the residual or ``floor`` (a spread too small to matter, in the units of ``values``).
    """
    basis = _basis(fields)
    uniform, worst = True, (0.0, 0.0)
    for k in steps:
        v = np.asarray(values[k], float)
        ok = np.isfinite(v) & np.isfinite(basis).all(axis=1)
        if ok.sum() <= basis.shape[1] + 2:
            continue
        coef, *_ = np.linalg.lstsq(basis[ok], v[ok], rcond=None)
        trend = basis[ok] @ coef
        signal, noise = float(np.std(trend)), float(np.std(v[ok] - trend))
        if signal > worst[0]:
            worst = (signal, noise)
        uniform &= signal <= max(noise, floor)
    return uniform, worst[0], worst[1]


def summary_figure(fields, items: list[Field]) -> tuple[Figure, dict]:
    """Median and 5–95 % spatial spread of each near-uniform field against pressure, one series per stretch."""
    n = len(items)
    ncols = min(n, 3)
    fig = Figure(figsize=(max(4.2 * ncols, 6.0), 3.3 * int(np.ceil(n / ncols))), dpi=110, layout="constrained")
    axes = np.atleast_1d(fig.subplots(int(np.ceil(n / ncols)), ncols, squeeze=False)).ravel()
    p = fields.pressure / curves.MMHG
    data: dict = {"pressure_Pa": fields.pressure, "stretch_imposed": fields.stretch, "fields": {}}
    for ax, it in zip(axes, items):
        with np.errstate(all="ignore"):
            q = np.nanpercentile(it.values, [5, 50, 95], axis=1) * it.scale
        for g, (lam, sel) in enumerate(curves.groups(fields.stretch)):
            ax.errorbar(p[sel], q[1][sel], yerr=[q[1][sel] - q[0][sel], q[2][sel] - q[1][sel]], fmt="os^vD"[g % 5] + "-",
                        color=f"C{g}", ms=4, capsize=2, label=f"λz {lam:.3f}")
        ax.set_xlabel("pressure (mmHg)")
        ax.set_ylabel(it.unit)
        ax.set_title(it.title, fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
        data["fields"][it.key] = {"median": q[1] / it.scale, "p05": q[0] / it.scale, "p95": q[2] / it.scale}
    for ax in axes[n:]:
        ax.set_visible(False)
    fig.suptitle("Near-uniform fields: median over the surface, 5–95 % spread as bars")
    return fig, data


def _draw(ctx, rep, items: list[Field], what: str) -> list[str]:
    f = ctx.fields
    shared = rep.strain_scale == "shared"
    steps = figures.map_steps(len(f.positions))
    flat: list[tuple[Field, float, float]] = []
    maps: list[tuple[Field, float, float]] = []
    for it in items:
        uniform, signal, noise = uniformity(f, it.values, steps, it.min_span / it.scale / 2)
        (flat if uniform else maps).append((it, signal, noise))
    out = []
    if flat:
        words = "; ".join(f"{html.escape(it.title)}: pattern {signal * it.scale:.2g} vs noise {noise * it.scale:.2g} "
                          f"{html.escape(it.unit)}" for it, signal, noise in flat)
        out.append(f"<p>These {what} are uniform within their noise (the standard deviation of a smooth pattern "
                   f"fitted over the surface is below that of the residual), so one summary replaces their maps: "
                   f"{words}.</p>")
        fig, data = summary_figure(f, [it for it, _, _ in flat])
        cav = " ".join(it.caveat for it, _, _ in flat if it.caveat) or None
        out.append(rep.figure(fig, f"{what.split()[0]}_summary", f"Median and 5–95 % spread over the surface of the "
                              f"near-uniform {what} at each step ({curves.PAPER}, Figs. 3–4 in summary).", data,
                              caveat=cav))
    if maps:
        out.append(f"<p>Colour scale: {SCALE_WORDS[shared]}.</p>")
    for it, _, _ in maps:
        fig = figures.surface_maps(f, it.values, title=it.title, label=it.unit, scale=it.scale,
                                   min_span=it.min_span, shared=shared)
        out.append(rep.figure(fig, it.key, f"{it.caption}; {SCALE_WORDS[shared].split(':')[0]}.", caveat=it.caveat))
    return out


def strain_section(ctx, rep) -> str:
    """Green–Lagrange strain maps (or their summary) of the surface."""
    f = ctx.fields
    if f is None:
        return ctx.no_fields()
    if len(f.positions) < 2:
        return absent("Only the reference step is reconstructed: there is no deformation to map.")
    out = [f"<p>Green–Lagrange strains per triangle relative to step 0, drawn on the unrolled reference surface "
           f"(R θ, z). Computed by {html.escape(f.sources['strain'])}.</p>"]
    shown = figures.map_steps(len(f.positions))
    if len(shown) < len(f.positions) - 1:
        out.append(f"<p>{len(shown)} of {len(f.positions) - 1} loaded steps are shown.</p>")
    items = [Field(f"strain_{c}", f"{c}: {name} strain", f.kin[c], 100.0, f"{c} (%)", 0.05,
                   f"{name.capitalize()} Green–Lagrange strain {c} at each step ({curves.PAPER}, Fig. 3)")
             for c, name in (("E11", "circumferential"), ("E22", "axial"))]
    return "".join(out + _draw(ctx, rep, items, "strains"))


def _qualities(ctx) -> Mapping[str, Mapping[str, float]]:
    fits = ctx.fits()
    if fits is None:
        return {}
    return {m["result"]: curves.fit_quality(fits, label) for label, m in fits["models"].items()}


def stress_section(ctx, rep) -> str:
    """Each identified model's Cauchy stress maps (or their summary), with a caveat for doubtful models."""
    f = ctx.fields
    if f is None:
        return ctx.no_fields()
    if not ctx.latest_idents:
        return absent("No identification is stored in this session (run 'vfmlab identify'), so there are no "
                      "model stresses to map.")
    if not f.stress:
        return absent("The identified models' stresses could not be evaluated (the identification package's "
                      "constitutive models are not available for these results).")
    results = {r["name"]: r for r in ctx.latest_idents}
    qualities = _qualities(ctx)
    items = []
    for name, st in f.stress.items():
        cav = summary.caveat(results[name], qualities.get(name)) if name in results else None
        for comp, label in (("s11", "circumferential σθθ"), ("s22", "axial σzz")):
            items.append(Field(f"stress_{name}_{comp}", f"{name} ({st['model']}): {label}", st[comp], 1e-3,
                               f"{label.split()[1]} (kPa)", 0.1,
                               f"{label} from {name} ({st['model']}) ({curves.PAPER}, Fig. 4)", cav))
    out = ["<p>Cauchy stresses of each identified model evaluated on the measured strains "
           f"({curves.PAPER}, Fig. 4).</p>"]
    return "".join(out + _draw(ctx, rep, items, "stresses"))
