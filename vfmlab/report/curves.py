"""The report's global curves: each identified model against the measured pressure–radius and force–pressure curves,
and the stress along the measured path (Avril, Badel & Duprey 2010, Appendices A and B, Fig. 8).

``fit_curves`` turns the mean mid-span curves of :func:`vfmlab.fields.stress_strain_curves` into what each model
predicts at the measured deformation of every step: the pressure that balances its hoop stress (Laplace law,
p = σθθ e / r) and the load-cell reading that balances its axial stress (N = 2π r e σzz, less the cannula's p π r_i²
when the load cell reads the total force). The figure functions draw them; each also returns the data it plots.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from matplotlib.figure import Figure

__all__ = ["PAPER", "fit_curves", "groups", "fit_quality", "force_pressure", "pressure_radius", "stress_strain"]

MMHG = 133.322387415
#: How the captions cite the method's paper.
PAPER = "Avril, Badel & Duprey 2010"


def fit_curves(curves: Mapping[str, Any], pressure: np.ndarray, force: np.ndarray) -> dict[str, Any]:
    """Measured and model curves along the measured path, SI.

    ``curves``: the dict of :func:`vfmlab.fields.stress_strain_curves`; ``pressure``, ``force`` (n_steps,) the
    measured pressure (Pa) and load-cell reading (N). Returns ``radius_m``, ``pressure_Pa``, ``force_N``,
    ``stretch`` (measured λz = L/L0 between the end rows), ``sigma_zz_Pa`` (Laplace estimate) (n_steps,) and
    ``models`` {label: {"result", "model", "pressure_Pa", "force_N", "sigma_tt_Pa", "sigma_zz_Pa"}}.
    """
    r, e = np.asarray(curves["radius"], float), np.asarray(curves["thickness"], float)
    correction = np.asarray(curves["wall_force"], float) - np.asarray(force, float)  # 0, or p π r_i² (total)
    models = {}
    for label, st in curves["models"].items():
        s11, s22 = np.asarray(st["s11"], float), np.asarray(st["s22"], float)
        models[label] = {"result": st.get("result", label), "model": st.get("model", ""),
                         "pressure_Pa": s11 * e / r, "force_N": 2 * np.pi * r * e * s22 - correction,
                         "sigma_tt_Pa": s11, "sigma_zz_Pa": s22}
    return {"radius_m": r, "pressure_Pa": np.asarray(pressure, float), "force_N": np.asarray(force, float),
            "stretch": np.sqrt(1.0 + 2.0 * np.asarray(curves["E22"], float)), "E11": np.asarray(curves["E11"], float),
            "sigma_tt_Pa": np.asarray(curves["s11"], float), "sigma_zz_Pa": np.asarray(curves["s22"], float),
            "models": models}


def fit_quality(fits: Mapping[str, Any], label: str) -> dict[str, float]:
    """RMS misfit of one model's pressure (Pa) and load-cell force (N) over the loaded steps, and each relative to
    the measured range (``pressure_rel``, ``force_rel``)."""
    m = fits["models"][label]
    loaded = np.arange(len(fits["pressure_Pa"])) > 0
    out = {}
    for key, short in (("pressure_Pa", "pressure"), ("force_N", "force")):
        diff = (m[key] - fits[key])[loaded]
        diff = diff[np.isfinite(diff)]
        rms = float(np.sqrt(np.mean(diff**2))) if diff.size else float("nan")
        span = float(np.ptp(fits[key][np.isfinite(fits[key])])) if np.isfinite(fits[key]).any() else 0.0
        out[short] = rms
        out[f"{short}_rel"] = rms / span if span > 0 else float("nan")
    return out


def groups(values: np.ndarray, digits: int = 3) -> list[tuple[float, np.ndarray]]:
    """(level, step indices in loading order) per distinct rounded value."""
    rounded = np.round(np.asarray(values, float), digits)
    return [(float(v), np.flatnonzero(rounded == v)) for v in np.unique(rounded[np.isfinite(rounded)])]


def _kpa_to_mmhg(kpa: Any) -> np.ndarray:
    return np.asarray(kpa, float) * 1e3 / MMHG


def _mmhg_to_kpa(mmhg: Any) -> np.ndarray:
    return np.asarray(mmhg, float) * MMHG / 1e3


def _figure(width: float, height: float) -> Figure:
    return Figure(figsize=(width, height), dpi=110, layout="constrained")


def pressure_radius(fits: Mapping[str, Any], stretch: np.ndarray) -> tuple[Figure, dict[str, Any]]:
    """Measured pressure (kPa; mmHg on the right) against the mid-span radius (mm), one series per imposed axial
    stretch, and each model's pressure at the measured deformation (lines)."""
    fig = _figure(5.0, 3.8)
    ax = fig.add_subplot()
    r, p = fits["radius_m"] * 1e3, fits["pressure_Pa"] / 1e3
    for g, (lam, sel) in enumerate(groups(stretch)):
        ax.plot(r[sel], p[sel], "os^vD"[g % 5], color="k", mfc="none", label=f"measured, λz {lam:.3f}")
        for j, (label, m) in enumerate(fits["models"].items()):
            ax.plot(r[sel], m["pressure_Pa"][sel] / 1e3, "-", color=f"C{j}", lw=1.5,
                    label=label if g == 0 else None)
    ax.set_xlabel("mid-span radius (mm)")
    ax.set_ylabel("pressure (kPa)")
    ax.secondary_yaxis("right", functions=(_kpa_to_mmhg, _mmhg_to_kpa)).set_ylabel("pressure (mmHg)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title("Pressure–radius: measured and each model")
    data = {"radius_m": fits["radius_m"], "pressure_measured_Pa": fits["pressure_Pa"], "stretch_imposed": stretch,
            "models": {k: {"result": m["result"], "pressure_Pa": m["pressure_Pa"]} for k, m in fits["models"].items()}}
    return fig, data


def force_pressure(fits: Mapping[str, Any], stretch: np.ndarray, load_cell_measures: str) -> tuple[Figure, dict]:
    """Load-cell axial force (N) against pressure (mmHg), measured (markers) and each model (lines), one series
    per imposed axial stretch."""
    fig = _figure(5.0, 3.8)
    ax = fig.add_subplot()
    p, f = fits["pressure_Pa"] / MMHG, fits["force_N"]
    for g, (lam, sel) in enumerate(groups(stretch)):
        ax.plot(p[sel], f[sel], "os^vD"[g % 5], color="k", mfc="none", label=f"measured, λz {lam:.3f}")
        for j, (label, m) in enumerate(fits["models"].items()):
            ax.plot(p[sel], m["force_N"][sel], "-", color=f"C{j}", lw=1.5, label=label if g == 0 else None)
    ax.set_xlabel("pressure (mmHg)")
    ax.set_ylabel(f"axial force, load cell ({load_cell_measures}) (N)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title("Axial force–pressure: measured and each model")
    data = {"pressure_Pa": fits["pressure_Pa"], "force_measured_N": f, "stretch_imposed": stretch,
            "load_cell_measures": load_cell_measures,
            "models": {k: {"result": m["result"], "force_N": m["force_N"]} for k, m in fits["models"].items()}}
    return fig, data


def stress_strain(fits: Mapping[str, Any], stretch: np.ndarray, target_pressure: np.ndarray) -> tuple[Figure, dict]:
    """(a) mean hoop stress against E11 (paper Fig. 8a); (b) mean axial stress against the measured axial stretch,
    one series per pressure level (the tensile test of Appendix B, Fig. 8b); (c) mean axial stress against pressure,
    one series per imposed stretch. Laplace-law estimates as markers, each model along the measured path as lines."""
    fig = _figure(12.0, 3.9)
    axes = fig.subplots(1, 3)
    lam, p = fits["stretch"], fits["pressure_Pa"] / MMHG
    panels = (
        (axes[0], fits["E11"] * 100, "sigma_tt_Pa", groups(stretch), "λz {:.3f}", "circumferential strain E11 (%)",
         "hoop stress σθθ (kPa)", "(a) circumferential"),
        (axes[1], lam, "sigma_zz_Pa", groups(np.asarray(target_pressure) / MMHG, 0), "{:.0f} mmHg",
         "measured axial stretch λz = L/L0 (–)", "axial stress σzz (kPa)", "(b) axial stress–stretch"),
        (axes[2], p, "sigma_zz_Pa", groups(stretch), "λz {:.3f}", "pressure (mmHg)", "axial stress σzz (kPa)",
         "(c) axial stress–pressure"))
    for ax, x, key, series, fmt, xlabel, ylabel, title in panels:
        for g, (level, sel) in enumerate(series):
            ax.plot(x[sel], fits[key][sel] / 1e3, "os^vD"[g % 5], color="k", mfc="none",
                    label=f"Laplace law, {fmt.format(level)}")
            for j, (label, m) in enumerate(fits["models"].items()):
                ax.plot(x[sel], m[key][sel] / 1e3, "-", color=f"C{j}", marker=".",
                        label=label if g == len(series) - 1 else None)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.set_title(title)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6)
    fig.suptitle("Mean mid-span stress along the measured path: identified models vs Laplace-law estimates")
    data = {"E11": fits["E11"], "stretch_measured": lam, "stretch_imposed": stretch, "pressure_Pa": fits["pressure_Pa"],
            "sigma_tt_laplace_Pa": fits["sigma_tt_Pa"], "sigma_zz_laplace_Pa": fits["sigma_zz_Pa"],
            "models": {k: {"result": m["result"], "sigma_tt_Pa": m["sigma_tt_Pa"], "sigma_zz_Pa": m["sigma_zz_Pa"]}
                       for k, m in fits["models"].items()}}
    return fig, data
