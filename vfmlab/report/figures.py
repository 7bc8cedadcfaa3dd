"""Report figures: each function returns a matplotlib ``Figure`` (Agg, no pyplot state) or None.

Inputs are SI; axes are labelled in the units a reader expects (mm, kPa, mmHg, %, mJ).
Figures are created with :class:`matplotlib.figure.Figure` directly, so building them is safe
in worker threads and never opens a window.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from matplotlib import colormaps
from matplotlib.cm import ScalarMappable
from matplotlib.colors import ListedColormap, Normalize, TwoSlopeNorm
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator, ScalarFormatter
from matplotlib.tri import Triangulation

from vfmlab.display import fixed
from vfmlab.fields import SurfaceFields

MMHG = 133.322387415
_RC = {"font.size": 10, "axes.titlesize": 10, "axes.labelsize": 10, "legend.fontsize": 8}
MAX_MAP_PANELS = 16


def _figure(width: float, height: float) -> Figure:
    fig = Figure(figsize=(width, height), dpi=110, layout="constrained")
    return fig


def _step_label(pressure: float, stretch: float) -> str:
    return f"{fixed(pressure / MMHG, 0)} mmHg, λz {stretch:.3f}"


def calibration_rms(camera_names: Sequence[str], rms: np.ndarray, per_view: np.ndarray | None = None) -> Figure:
    """Bar chart of the reprojection RMS error (px) per camera; per-view errors as dots if given.

    ``per_view`` (n_cams, n_views) px, NaN where the camera did not see the board.
    """
    fig = _figure(max(4.5, 0.6 * len(camera_names) + 2.5), 3.2)
    ax = fig.add_subplot()
    x = np.arange(len(camera_names))
    ax.bar(x, rms, color="tab:blue", alpha=0.8, label="camera RMS")
    top = float(np.nanmax(rms)) if np.isfinite(rms).any() else 1.0
    pv = None if per_view is None else np.asarray(per_view, float)
    if pv is not None and pv.ndim == 2 and pv.shape[0] == len(x) and np.isfinite(pv).any():
        jitter = np.linspace(-0.25, 0.25, pv.shape[1]) if pv.shape[1] > 1 else np.zeros(1)
        xx = x[:, None] + jitter[None, :]
        ax.plot(xx[np.isfinite(pv)], pv[np.isfinite(pv)], ".", color="k", ms=3, label="per board view")
        top = max(top, float(np.nanmax(pv)))
        ax.legend(loc="upper right")
    for xi, v in zip(x, rms):
        ax.annotate(f"{v:.2f}", (xi, v), ha="center", va="bottom", fontsize=8, xytext=(0, 2),
                    textcoords="offset points")
    ax.set_xticks(x, [str(c) for c in camera_names], rotation=45 if len(x) > 8 else 0)
    ax.set_xlabel("camera")
    ax.set_ylabel("reprojection RMS error (px)")
    ax.set_title("Calibration quality")
    ax.set_ylim(0, max(top * 1.25, 1e-3))
    ax.grid(axis="y", alpha=0.3)
    return fig


def protocol_steps(steps: Mapping[str, np.ndarray], log: Mapping[str, np.ndarray] | None = None) -> Figure:
    """Pressure (mmHg) and axial stretch per captured step; the continuous pressure log if present."""
    fig = _figure(7.0, 3.2 if not log else 5.2)
    n = len(steps["pressure"])
    axes = fig.subplots(2 if log else 1, 1, squeeze=False)[:, 0]
    ax = axes[0]
    k = np.arange(n)
    active = steps.get("active", np.ones(n, bool))
    ax.plot(k[active], steps["pressure"][active] / MMHG, "o-", color="tab:red", label="measured pressure")
    ax.plot(k, steps["target_pressure"] / MMHG, "_", ms=12, color="k", label="target")
    if (~active).any():
        ax.plot(k[~active], steps["pressure"][~active] / MMHG, "x", color="grey", label="superseded (retaken)")
    ax.set_xlabel("step")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_ylabel("pressure (mmHg)")
    ax2 = ax.twinx()
    ax2.plot(k, steps["stretch"], "s--", color="tab:blue", ms=4, label="axial stretch")
    ax2.set_ylabel("axial stretch λz (–)", color="tab:blue")
    handles = ax.get_legend_handles_labels()
    handles2 = ax2.get_legend_handles_labels()
    ax.legend(handles[0] + handles2[0], handles[1] + handles2[1], loc="upper left")
    ax.set_title("Protocol as run: captured steps")
    if log:
        t = log["t_wall"] - log["t_wall"][0]
        axes[1].plot(t, log["value"] / MMHG, color="tab:red", lw=1)
        axes[1].set_xlabel("time since first sample (s)")
        axes[1].set_ylabel("pressure (mmHg)")
        axes[1].set_title("Continuous pressure log")
        axes[1].grid(alpha=0.3)
    return fig


def markers_per_step(visible: np.ndarray, pressure: np.ndarray) -> Figure:
    """Markers reconstructed per step and how completely each marker is tracked."""
    n_steps, n_markers = visible.shape
    fig = _figure(9.0, 3.4)
    ax1, ax2 = fig.subplots(1, 2, width_ratios=[1, 1.4])
    ax1.bar(np.arange(n_steps), visible.sum(axis=1), color="tab:green")
    ax1.axhline(n_markers, color="k", lw=0.8, ls="--", label=f"all {n_markers} markers")
    ax1.set_xlabel("step")
    ax1.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax1.set_ylabel("markers reconstructed")
    ax1.set_title("Markers per step")
    ax1.legend(loc="lower right")
    frac = visible.mean(axis=0) * 100
    ax2.hist(frac, bins=np.linspace(0, 100, 21), color="tab:purple")
    ax2.set_xlabel("steps in which the marker is tracked (%)")
    ax2.set_ylabel("number of markers")
    complete = int(visible.all(axis=0).sum())
    ax2.set_title(f"Tracking completeness: {complete}/{n_markers} markers in every step")
    return fig


def mesh_3d(fields: SurfaceFields) -> Figure:
    """3-D view of the surface mesh (the side facing the viewer) in the reference and the last step,
    coloured by E11 in the last step; slivers (:func:`well_shaped`) are left out, so the seam shows no spikes."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    fig = _figure(9.0, 4.6)
    keep = well_shaped(fields)
    tri = fields.mesh.triangles[keep]
    last = len(fields.positions) - 1
    e11 = fields.kin["E11"][last][keep] * 100
    norm = Normalize(*_limits(e11))
    cmap = colormaps["viridis"]
    for i, (step, title) in enumerate(((0, "Reference (step 0)"), (last, f"Step {last}: "
                                       f"{_step_label(fields.pressure[last], fields.stretch[last])}"))):
        ax = fig.add_subplot(1, 2, i + 1, projection="3d")
        x = fields.positions[step] * 1e3
        verts = x[tri]
        ok = np.all(np.isfinite(verts), axis=(1, 2))
        # the far wall (its inside, seen over the near rim) first in grey, then the near wall on top of it: with
        # the draw order fixed, matplotlib's depth sort cannot mix the walls, and the rim shows no spikes
        elev, azim = np.radians(25.0), np.radians(-60.0)
        view = np.array([np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)])
        normal = np.cross(verts[:, 1] - verts[:, 0], verts[:, 2] - verts[:, 0])
        centre_xy = np.nanmean(x[:, :2], axis=0)
        outward = np.sign(np.einsum("ij,ij->i", normal[:, :2], verts.mean(axis=1)[:, :2] - centre_xy))
        near = (normal @ view) * outward > 0
        colors = cmap(norm(np.nan_to_num(e11))) if step else np.tile([0.75, 0.75, 0.8, 1.0], (len(tri), 1))
        ax.computed_zorder = False
        ax.add_collection3d(Poly3DCollection(verts[ok & ~near], facecolors=(0.88, 0.88, 0.9, 1.0), edgecolors="0.6",
                                             linewidths=0.1, zorder=1, rasterized=True))
        ax.add_collection3d(Poly3DCollection(verts[ok & near], facecolors=colors[ok & near], edgecolors="k",
                                             linewidths=0.15, zorder=2, rasterized=True))
        pts = x[np.isfinite(x).all(axis=1)]
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        centre, half = (lo + hi) / 2, (hi - lo).max() / 2
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_zlim(centre[2] - half, centre[2] + half)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev=25.0, azim=-60.0)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.set_zlabel("z (mm)")
        ax.set_title(title)
    fig.colorbar(ScalarMappable(norm, cmap), ax=fig.axes, shrink=0.7, label="E11 circumferential strain (%)")
    return fig


def well_shaped(fields: SurfaceFields, min_quality: float = 0.25, max_edge: float = 3.0) -> np.ndarray:
    """(n_triangles,) bool: triangles that are not slivers on the unrolled reference surface (cylindrical
    coordinates R θ, z; seam triangles kept whole): shape quality 4√3·area / Σ edge² (1 for an equilateral
    triangle) at least ``min_quality``, longest edge at most ``max_edge`` times the median longest edge."""
    t = unrolled_triangulation(fields)
    p = np.stack([t.x, t.y], axis=-1)[t.triangles]  # (n_tri, 3, 2) mm
    edges = np.linalg.norm(p - np.roll(p, 1, axis=1), axis=2)
    d1, d2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    area = 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    with np.errstate(invalid="ignore", divide="ignore"):
        quality = 4 * np.sqrt(3) * area / (edges**2).sum(axis=1)
    longest = edges.max(axis=1)
    ok = np.isfinite(quality) & (quality >= min_quality)
    if ok.any():
        ok &= longest <= max_edge * np.median(longest[ok])
    return ok


def _limits(values: np.ndarray, min_span: float = 0.0) -> tuple[float, float]:
    """1st-99th percentile range, widened to at least ``min_span`` and 0.2 % of the magnitude
    (so that round-off on uniform fields is not blown up into a pattern)."""
    finite = np.asarray(values)[np.isfinite(values)]
    if finite.size == 0:
        return 0.0, 1.0
    lo, hi = (float(v) for v in np.percentile(finite, [1, 99]))
    span = max(min_span, 2e-3 * max(abs(lo), abs(hi)), 1e-12)
    if hi - lo < span:
        mid = 0.5 * (lo + hi)
        lo, hi = mid - span / 2, mid + span / 2
    return lo, hi


def unrolled_triangulation(fields: SurfaceFields) -> Triangulation:
    """Triangles in unrolled reference coordinates (R theta, z) in mm; seam triangles are kept whole."""
    mesh = fields.mesh
    tri = mesh.triangles
    s = mesh.s[tri] * 1e3
    z = mesh.z[tri] * 1e3
    period = 2 * np.pi * mesh.radius * 1e3
    s = np.where(s - s[:, :1] > period / 2, s - period, s)
    s = np.where(s - s[:, :1] < -period / 2, s + period, s)
    return Triangulation(s.ravel(), z.ravel(), np.arange(s.size).reshape(-1, 3))


def map_steps(n_steps: int) -> np.ndarray:
    """Steps shown in the surface maps: every loaded step, or an even subset of at most MAX_MAP_PANELS."""
    steps = np.arange(1, n_steps)
    if len(steps) > MAX_MAP_PANELS:
        steps = steps[np.unique(np.linspace(0, len(steps) - 1, MAX_MAP_PANELS).round().astype(int))]
    return steps


def surface_maps(fields: SurfaceFields, values: np.ndarray, *, title: str, label: str, scale: float,
                 diverging: bool = False, min_span: float = 0.0, shared: bool = True) -> Figure:
    """Small multiples of a per-triangle quantity ``values`` (n_steps, n_tri) on the unrolled surface.

    ``shared``: one colour scale for every panel (1st-99th percentile over all shown steps), so that
    steps compare and noise of a fraction of a percent does not look like structure; otherwise each
    panel has its own scale (1st-99th percentile of that step, at least ``min_span`` wide), which shows
    the spatial distribution within a step. The title says which is used.
    """
    steps = map_steps(len(values))
    ncols = min(3, len(steps))
    nrows = int(np.ceil(len(steps) / ncols))
    tri = unrolled_triangulation(fields)
    aspect = (np.nanmax(tri.y) - np.nanmin(tri.y)) / max(np.nanmax(tri.x) - np.nanmin(tri.x), 1e-9)
    panel_w, cb_w = 2.9, 1.3  # inches: map, colorbar with its labels and the next map's y labels
    panel_h = panel_w * aspect
    row_h = panel_h + 0.85
    width, height = ncols * (panel_w + cb_w) + 0.7, nrows * row_h + 0.55
    # Manual layout (constrained layout costs more than drawing for these small multiples).
    fig = Figure(figsize=(width, height), dpi=110)
    v = values[steps] * scale
    common = _limits(v, min_span) if shared else None
    axes = []
    for i, (k, vk) in enumerate(zip(steps, v)):
        row, col = divmod(i, ncols)
        left = 0.7 + col * (panel_w + cb_w)
        bottom = height - 0.55 - row * row_h - 0.3 - panel_h
        ax = fig.add_axes((left / width, bottom / height, panel_w / width, panel_h / height))
        axes.append(ax)
        lo, hi = common if shared else _limits(vk, min_span)
        if diverging and lo < 0 < hi:
            norm, cmap = TwoSlopeNorm(0.0, lo, hi), colormaps["RdBu_r"]
        else:
            norm, cmap = Normalize(lo, hi), colormaps["viridis"]
        bad = ~np.isfinite(vk)
        if bad.any():
            ax.tripcolor(Triangulation(tri.x, tri.y, tri.triangles, mask=~bad), facecolors=np.zeros(len(vk)),
                         cmap=ListedColormap(["#cccccc"]), edgecolors="none")
        t = Triangulation(tri.x, tri.y, tri.triangles, mask=bad)
        ax.tripcolor(t, facecolors=np.where(bad, 0.0, vk), norm=norm, cmap=cmap, edgecolors="none")
        # y given: the title sits where matplotlib would put it (no axis above the panel), without
        # its per-draw search for overlapping tick labels (a third of the report's drawing time)
        ax.set_title(f"step {k}: {_step_label(fields.pressure[k], fields.stretch[k])}", fontsize=9, y=1.0)
        ax.set_aspect("auto")
        ax.set_xlim(np.nanmin(tri.x), np.nanmax(tri.x))
        ax.set_ylim(np.nanmin(tri.y), np.nanmax(tri.y))
        # every panel has the same axes: few ticks, labelled on the outer panels only (tick and text
        # layout is most of the drawing time of these small multiples)
        ax.xaxis.set_major_locator(MaxNLocator(4))
        ax.yaxis.set_major_locator(MaxNLocator(4))
        bottom_panel = i + ncols >= len(steps)
        ax.tick_params(labelsize=8, labelbottom=bottom_panel, labelleft=col == 0)
        if bottom_panel:
            ax.set_xlabel("R θ (mm)", fontsize=8, labelpad=1)
        if col == 0:
            ax.set_ylabel("z (mm)", fontsize=9)
        if not shared or col == ncols - 1 or i == len(steps) - 1:  # a shared scale: one colour bar per row
            cax = fig.add_axes(((left + panel_w + 0.08) / width, bottom / height, 0.1 / width, panel_h / height))
            cb = fig.colorbar(ScalarMappable(norm, cmap), cax=cax)
            cb.formatter = ScalarFormatter(useOffset=False)
            cb.update_ticks()
            cb.ax.tick_params(labelsize=7)
            cb.set_label(label, fontsize=8)
    which = "one colour scale for all steps" if shared else "colour scale per step"
    fig.suptitle(f"{title} ({which}; grey: triangle not measured)", y=1 - 0.15 / height, va="top")
    return fig


def virtual_work(idents: Sequence[Mapping[str, Any]], pressure: np.ndarray) -> Figure | None:
    """Internal vs external virtual work per step, one panel per identification, one colour per virtual field."""
    panels = [r for r in idents if "ivw" in r["arrays"] and "evw" in r["arrays"]]
    if not panels:
        return None
    fig = _figure(min(4.2 * len(panels), 13), 3.6)
    axes = np.atleast_1d(fig.subplots(1, len(panels), squeeze=False)).ravel()
    for ax, r in zip(axes, panels):
        ivw, evw, names = _vw_arrays(r)
        unit = str(r.get("units", {}).get("ivw", "J"))
        peak = float(np.nanmax(np.abs(np.concatenate([ivw.ravel(), evw.ravel()])))) if ivw.size else 1.0
        factor, prefix = (1e3, "m") if unit == "J" and 0 < peak < 1 else (1.0, "")
        k = np.arange(ivw.shape[1])
        for j in range(ivw.shape[0]):
            color = f"C{j}"
            ax.plot(k, ivw[j] * factor, "o-", color=color, label=f"{names[j]}: internal")
            ax.plot(k, evw[j] * factor, "s--", mfc="none", color=color, label=f"{names[j]}: external")
        ax.set_xlabel("step")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_ylabel(f"virtual work ({prefix}{unit})")
        ax.set_title(f"{r['name']}: {r['attrs'].get('model', '?')}")
        ax.grid(alpha=0.3)
        ax.legend()
    fig.suptitle("Internal vs external virtual work (identified parameters)")
    return fig


def _vw_arrays(result: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """ivw, evw as (n_fields, n_steps) J, and the field names."""
    a = result["arrays"]
    ivw, evw = np.atleast_2d(np.asarray(a["ivw"], float)), np.atleast_2d(np.asarray(a["evw"], float))
    names = [str(n) for n in a.get("field_names", result["attrs"].get("field_names", a.get("virtual_fields", [])))]
    if names and ivw.shape[0] != len(names) and ivw.shape[1] == len(names):
        ivw, evw = ivw.T, evw.T
    if len(names) != ivw.shape[0]:
        names = [f"field {j + 1}" for j in range(ivw.shape[0])]
    return ivw, evw, names


def correlation_matrix(result: Mapping[str, Any]) -> Figure | None:
    """Heat map of the parameter correlation matrix of one identification."""
    a = result["arrays"]
    if "correlation" not in a:
        return None
    corr = np.asarray(a["correlation"], float)
    names = [str(n) for n in a.get("parameter_names", [f"p{i}" for i in range(len(corr))])]
    fig = _figure(1.0 + 0.75 * len(names) + 1.2, 0.75 * len(names) + 1.2)
    ax = fig.add_subplot()
    im = ax.imshow(corr, cmap="RdBu_r", vmin=-1, vmax=1)
    ax.set_xticks(range(len(names)), names, rotation=45)
    ax.set_yticks(range(len(names)), names)
    for i in range(len(names)):
        for j in range(len(names)):
            ax.text(j, i, f"{corr[i, j]:.2f}", ha="center", va="center", fontsize=8,
                    color="white" if abs(corr[i, j]) > 0.6 else "black")
    fig.colorbar(im, ax=ax, label="correlation (–)")
    ax.set_title(f"{result['name']} ({result['attrs'].get('model', '?')})")
    return fig


def model_costs(rows: Sequence[Mapping[str, Any]]) -> Figure | None:
    """Bar chart of the final cost of each identification."""
    rows = [r for r in rows if r.get("cost") is not None and np.isfinite(r["cost"])]
    if not rows:
        return None
    fig = _figure(max(4.0, 1.1 * len(rows) + 1.5), 3.2)
    ax = fig.add_subplot()
    labels = [f"{r['model']}\n{r['name']}" for r in rows]
    costs = [r["cost"] for r in rows]
    colors = ["tab:green" if r.get("converged") else "tab:red" for r in rows]
    ax.bar(range(len(rows)), costs, color=colors)
    ax.set_xticks(range(len(rows)), labels, fontsize=8)
    ax.set_ylabel("final cost (–)")
    if max(costs) / max(min(costs), 1e-300) > 100:
        ax.set_yscale("log")
    ax.set_title("Model comparison: cost (green = converged)")
    ax.grid(axis="y", alpha=0.3)
    return fig
