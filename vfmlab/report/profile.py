"""Report figure and section of a "regional" result: parameter profiles along the axis beside the strain.

``profile_figure`` draws each regional parameter against the axial position Z (mm) with its 95 % interval and the
homogeneous fit as a line, beside the circumferential strain of the last step along the same Z; ``section`` is the
report section ("Parameters along the axis", placed after the strain maps).
"""

from __future__ import annotations

import html
from collections.abc import Mapping
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from vfmlab.display import num

__all__ = ["profile_figure", "section"]


def _names(a: Mapping[str, Any], key: str) -> list[str]:
    return [str(v) for v in np.atleast_1d(a[key])] if key in a else []


def _strain_along_axis(result: Mapping[str, Any], fields) -> tuple[np.ndarray, np.ndarray] | None:
    """(Z (n_triangles,) m in the result's axial coordinate, E11 at the last step (n_triangles,)), or None."""
    a = result["arrays"]
    if fields is None or len(fields.positions) < 2 or "axis_direction" not in a or "band_centres_world" not in a:
        return None
    direction = np.asarray(a["axis_direction"], float)
    origin = np.asarray(a["band_centres_world"], float)[0] - float(np.asarray(a["band_centres"])[0]) * direction
    centroid = np.nanmean(fields.positions[0][fields.mesh.triangles], axis=1)
    return (centroid - origin) @ direction, np.asarray(fields.kin["E11"][-1], float)


def _draw_parameter(ax, a: Mapping[str, Any], units: Mapping[str, str], name: str, kind: str) -> None:
    edges = np.asarray(a["band_edges"], float) * 1e3
    centres = np.asarray(a["band_centres"], float) * 1e3
    k = 1e-3 if units.get(name) == "Pa" else 1.0
    unit = "kPa" if units.get(name) == "Pa" else units.get(name, "")
    v = np.asarray(a[name], float) * k
    lo = np.asarray(a.get(f"{name}_interval_low", v / k), float) * k
    hi = np.asarray(a.get(f"{name}_interval_high", v / k), float) * k
    if kind == "bands":
        ax.stairs(hi, edges, baseline=lo, fill=True, color="C0", alpha=0.25, label="95 % interval")
        ax.stairs(v, edges, baseline=None, color="C0", lw=2, label=f"{name} per band")
    else:
        ax.fill_between(centres, lo, hi, color="C0", alpha=0.25, label="95 % interval")
        ax.plot(centres, v, color="C0", lw=2, label=f"{name} profile")
    differs = np.asarray(a.get("differs", np.zeros(v.size)), bool)
    if differs.any():
        ax.plot(centres[differs], v[differs], "v", color="C3", ms=8, label="differs from the median band")
    hom = dict(zip(_names(a, "homogeneous_names"), np.atleast_1d(a.get("homogeneous_parameters", []))))
    if name in hom:
        ax.axhline(float(hom[name]) * k, color="0.3", ls="--", lw=1.2,
                   label=f"homogeneous fit {num(float(hom[name]) * k, 4)} {unit}")
    ax.set_title(f"{name} along the axis")
    ax.set_xlabel("axial position Z (mm, towards the load cell)")
    ax.set_ylabel(f"{name} ({unit})" if unit and unit != "1" else name)
    ax.legend(loc="best")


def profile_figure(result: Mapping[str, Any], fields=None) -> Figure | None:
    """Each regional parameter of a stored "regional" result against Z with its 95 % interval and the homogeneous
    fit, beside the last step's circumferential strain E11 along Z when ``fields`` (``SurfaceFields``) are given."""
    a, units = result["arrays"], result.get("units", {})
    names = [n for n in _names(a, "regional_names") if n in a]
    if not names or "band_edges" not in a:
        return None
    strain = _strain_along_axis(result, fields)
    ncols = 1 + (strain is not None)
    fig = Figure(figsize=(5.2 * ncols, 3.6 * len(names)), dpi=110, layout="constrained")
    axes = fig.subplots(len(names), ncols, squeeze=False)
    kind = str(result.get("attrs", {}).get("profile_kind", "bands"))
    for i, name in enumerate(names):
        _draw_parameter(axes[i, 0], a, units, name, kind)
        if strain is not None:
            z, e11 = strain
            ok = np.isfinite(z) & np.isfinite(e11)
            ax = axes[i, 1]
            ax.plot(z[ok] * 1e3, e11[ok] * 100, ".", ms=2, color="0.55", label="triangles")
            edges = np.asarray(a["band_edges"], float)
            cell = np.clip(np.searchsorted(edges, z[ok], side="right") - 1, 0, len(edges) - 2)
            med = [np.median(e11[ok][cell == c]) * 100 if np.any(cell == c) else np.nan for c in range(len(edges) - 1)]
            ax.stairs(med, edges * 1e3, baseline=None, color="C1", lw=2, label="median per band")
            ax.set_xlim(axes[i, 0].get_xlim())
            ax.set_xlabel("axial position Z (mm)")
            ax.set_ylabel("E11 at the last step (%)")
            ax.set_title("circumferential strain along the axis")
            ax.legend(loc="best")
    return fig


def _rows(result: Mapping[str, Any]) -> list[str]:
    a, units = result["arrays"], result.get("units", {})
    rows = []
    for n in _names(a, "regional_names"):
        k, unit = (1e-3, "kPa") if units.get(n) == "Pa" else (1.0, units.get(n, ""))
        v = np.asarray(a[n], float)
        lo = np.asarray(a.get(f"{n}_interval_low", v), float)
        hi = np.asarray(a.get(f"{n}_interval_high", v), float)
        differs = np.asarray(a.get("differs", np.zeros(v.size)), bool)
        for b in range(v.size):
            mark = " (differs)" if differs[b] else ""
            rows.append(f"<tr><td>{html.escape(n)}</td><td class=\"num\">{a['band_edges'][b] * 1e3:.1f} to "
                        f"{a['band_edges'][b + 1] * 1e3:.1f} mm</td><td class=\"num\">{num(v[b] * k, 4)} {unit}</td>"
                        f"<td class=\"num\">{num(lo[b] * k, 3)} to {num(hi[b] * k, 3)} {unit}</td>"
                        f"<td>{mark.strip(' ()') or '–'}</td></tr>")
    return rows


def section(ctx, rep) -> str:
    """The report section of the session's latest "regional" result (or a sentence saying there is none)."""
    session = ctx.session
    if not session.results("regional"):
        return ('<p class="absent">No regional identification is stored in this session (run '
                "'vfmlab identify SESSION --regions auto'), so there is no parameter profile along the axis.</p>")
    result = session.latest("regional")
    attrs = result.get("attrs", {})
    fig = profile_figure(result, ctx.fields)
    if fig is None:
        return f'<p class="absent">{html.escape(result["name"])} holds no parameter profile.</p>'
    kind = str(attrs.get("profile_kind", "bands"))
    what = "per axial band" if kind == "bands" else "as a smooth (Legendre) profile of its logarithm"
    errors = ("a parametric bootstrap (re-simulated marker noise)" if attrs.get("uncertainty") == "bootstrap"
              else "Gauss–Newton (too narrow on noisy markers)")
    out = [f"<p>{html.escape(result['name'])}: {html.escape(str(attrs.get('model', '')))} parameters identified "
           f"{what}, 95 % intervals from {errors}; the dashed line is the homogeneous fit of the same data. Z is the "
           "reference axial coordinate from the mean marker position, towards the load cell.</p>",
           rep.figure(fig, "regional_profile", "Parameter profile along the axis with its 95 % interval and the "
                                               "homogeneous fit, beside the circumferential strain along the axis."),
           "<table><tr><th>parameter</th><th>from–to</th><th>value</th><th>95 % interval</th><th>differs</th></tr>"
           + "".join(_rows(result)) + "</table>"]
    flags = [str(f) for f in np.atleast_1d(attrs.get("flags", []))]
    out += [f'<p class="flag">{html.escape(f)}</p>' for f in flags]
    return "".join(out)
