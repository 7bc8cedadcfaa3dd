"""Can the data tell that a setting is wrong? End-condition and wall-form checks in plain words.

Two kinds of evidence, each measured on simulated clamped / free / thick-walled tubes
(``docs/validation/identification.md``, "Setting checks"):

- **Radius profile near the ends.** A tube tied on cannulae keeps the cannula radius at the clamp,
  so under pressure its radius falls toward both ends of the marked region; a free (uniform) tube
  inflates evenly. ``end_taper`` measures, at the highest pressure, how much less the end bands
  of markers expanded than the middle third.
- **A virtual-work gap that the other setting closes.** ``ends_gap`` refits the same data with
  the other end condition (only the strip force ``p (A_loop - A_clamp)`` changes, so this costs
  one more fit); ``wall_gap`` refits with the other wall form. If the other setting fits the
  balance several times better, the chosen one is likely wrong.

Pure functions over arrays and ``VFMData``; no files. Units SI.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np

from .fit import identify_prepared
from .mesh import fit_axis, to_cylindrical
from .vfm import VFMData, prepare

__all__ = ["CHECK_LIMITS", "SetupCheck", "end_taper", "ends_gap", "with_ends", "wall_gap", "check_setup"]

log = logging.getLogger(__name__)

#: Thresholds of the checks (measured: docs/validation/identification.md, "Setting checks").
CHECK_LIMITS = {
    # mean end-band taper (fraction of the mid-length radial expansion) above which the ends look clamped
    "taper_clamped": 0.10,
    # ... below which the marked tube looks uniform (free ends, or clamps far from the markers)
    "taper_uniform": 0.03,
    # the other setting must shrink the RMS virtual-work gap by this factor ...
    "gap_ratio": 0.5,
    # ... from at least this RMS gap (fraction of the external work)
    "gap_min": 0.001,
}


@dataclass(frozen=True)
class SetupCheck:
    """Outcome of the setting checks.

    Attributes
    ----------
    taper : tuple of float
        (bottom, top) end-band taper (1 - end expansion / mid expansion) at the highest pressure;
        NaN when it cannot be measured.
    gap : float
        RMS normalised virtual-work gap of the fit as identified.
    gap_other_ends, gap_other_wall : float
        The same with the other end condition / wall form (NaN if not tried).
    flags : tuple of str
        Plain-words warnings.
    """

    taper: tuple
    gap: float
    gap_other_ends: float
    gap_other_wall: float
    flags: tuple


def end_taper(data: VFMData, positions: np.ndarray, band: float = 0.15) -> tuple[float, float]:
    """How much less the two end bands of markers expanded radially than the middle third.

    Parameters
    ----------
    data : VFMData
        Gives the mesh (reference axis and cylindrical coordinates) and the pressures.
    positions : ndarray, shape (n_steps, n_markers, 3)
        The marker positions ``data`` was prepared from (m); the reference is step 0.
    band : float
        Width of each end band as a fraction of the marked axial extent.

    Returns
    -------
    (bottom, top) : 1 - (median radial displacement in the band) / (median in the middle third) at
    the highest-pressure step; 0 for a uniform tube, towards 1 for a tube tied at the band's end.
    """
    mesh = data.mesh
    x = np.asarray(positions, dtype=float)
    k = int(np.argmax(np.abs(data.pressure)))
    current = x[k]
    seen = np.all(np.isfinite(current), axis=1)
    if seen.sum() < 12:
        return float("nan"), float("nan")
    axis = fit_axis(current[seen], initial=mesh.axis)  # the deformed tube's own axis (a tapered profile allowed)
    r, _, _ = to_cylindrical(current, axis)
    u = r - mesh.r
    z = mesh.z
    ok = mesh.used & np.isfinite(u) & np.isfinite(z)
    if ok.sum() < 12:
        return float("nan"), float("nan")
    lo, hi = np.min(z[ok]), np.max(z[ok])
    span = hi - lo
    mid = ok & (np.abs(z - 0.5 * (lo + hi)) <= span / 6.0)
    u_mid = np.median(u[mid]) if mid.sum() >= 3 else np.nan
    out = []
    for sel in (ok & (z <= lo + band * span), ok & (z >= hi - band * span)):
        out.append(float(1.0 - np.median(u[sel]) / u_mid) if sel.sum() >= 3 and abs(u_mid) > 0 else float("nan"))
    return out[0], out[1]


def with_ends(data: VFMData, ends: str) -> VFMData:
    """The same virtual-work data with the other end condition (only the end force changes)."""
    if ends not in ("clamped", "free"):
        raise ValueError(f"ends must be 'clamped' or 'free'; got {ends!r}")
    if data.strip_force is None:
        raise ValueError("data has no strip_force (prepared by an older identification.prepare)")
    return with_end_force(data, data.axial_force + (data.strip_force if ends == "clamped" else 0.0), ends=ends)


def with_end_force(data: VFMData, end_force: np.ndarray, **changes) -> VFMData:
    """The same virtual-work data with another force (n_steps,) N across the load-cell end: only the end work,
    the external work and its scale change (``changes``: further fields of the result, e.g. ``ends``)."""
    k = int(np.argmax(np.abs(data.end_force)))  # end_work = load_end (per field) x end force
    load_end = data.end_work[:, k] / data.end_force[k] if data.end_force[k] != 0 else np.zeros(len(data.scale))
    end_work = load_end[:, None] * np.asarray(end_force, dtype=float)[None]
    evw = data.pressure_work + end_work
    scale = np.sqrt(np.mean(evw**2, axis=1))
    return replace(data, end_force=end_force, end_work=end_work, evw=evw, scale=np.where(scale > 0, scale, data.scale),
                   **changes)


def _rms(residuals: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.asarray(residuals) ** 2)))


def ends_gap(data: VFMData, model, parameters) -> float:
    """RMS normalised gap of a fit of ``model`` with the other end condition (one more fit)."""
    other = with_ends(data, "free" if data.ends == "clamped" else "clamped")
    return _rms(identify_prepared(other, model, initial=parameters).residuals)


def wall_gap(positions, data: VFMData, model, parameters, **prepare_options) -> float:
    """RMS normalised gap of a fit of ``model`` with the other wall form (prepares the data again)."""
    other = prepare(positions, data.pressure, data.axial_force, thickness=data.thickness,
                    wall="thick" if data.wall == "membrane" else "membrane", ends=data.ends, mesh=data.mesh,
                    smoothing=data.smoothing, **prepare_options)
    return _rms(identify_prepared(other, model, initial=parameters).residuals)


def _ends_flags(data: VFMData, taper: tuple, gap: float, gap_other: float) -> list[str]:
    lim = CHECK_LIMITS
    flags = []
    t = np.nanmean(taper) if np.any(np.isfinite(taper)) else np.nan
    other = "free" if data.ends == "clamped" else "clamped"
    if data.ends == "free" and np.nanmin(taper) > lim["taper_clamped"]:
        flags.append(f"the ends look clamped: at the highest pressure the tube expanded {t:.0%} less at both ends "
                     "of the marked region than in its middle, as a tube tied on cannulae does, but the fit assumed "
                     "free ends (no pressure on an unmeasured strip); identify with --ends clamped")
    if np.isfinite(gap_other) and gap > lim["gap_min"] and gap_other < lim["gap_ratio"] * gap:
        shape = (f"; the radius profile is uniform toward the ends (taper {t:.0%})"
                 if data.ends == "clamped" and t < lim["taper_uniform"] else "")
        flags.append(f"the end conditions look wrong: assuming {other} ends closes the virtual-work gap from "
                     f"{gap:.1%} to {gap_other:.1%} of the external work{shape}; check how the specimen was held "
                     f"(--ends {other})")
    return flags


def check_setup(result, positions: np.ndarray, *, check_ends: bool = True, check_wall: bool = True,
                **prepare_options) -> SetupCheck:
    """Check the end condition and wall form of an identification against its own data.

    Parameters
    ----------
    result : IdentificationResult
        From ``identify`` (``result.data`` holds the VFMData fitted).
    positions : ndarray, shape (n_steps, n_markers, 3)
        The marker positions identified from (m).
    check_ends, check_wall : bool
        Which refits to run (each costs one more fit; the wall one also a second ``prepare``).
    prepare_options
        As given to ``identify`` (n_layers, quadrature, clamp_radius...), for the wall refit.
    """
    data: VFMData = result.data
    if data is None:
        raise ValueError("result.data is None: check_setup needs a result of identification.identify")
    gap = _rms(result.residuals)
    taper = end_taper(data, positions)
    open_gap = gap > CHECK_LIMITS["gap_min"]  # below it no refit could flag anything: skip them
    g_ends = ends_gap(data, result.model, result.parameters) if check_ends and open_gap else float("nan")
    g_wall = float("nan")
    flags = _ends_flags(data, taper, gap, g_ends)
    if check_wall and open_gap and not flags:  # a wrong end condition opens the gap too: judge the wall alone
        try:
            g_wall = wall_gap(positions, data, result.model, result.parameters, **prepare_options)
        except Exception as exc:  # noqa: BLE001 - a failing check must not fail the identification
            log.info("wall check skipped: %s", exc)
        other = "thick" if data.wall == "membrane" else "membrane"
        if np.isfinite(g_wall) and gap > CHECK_LIMITS["gap_min"] and g_wall < CHECK_LIMITS["gap_ratio"] * gap:
            what = ("the markers are on the outer surface of a thick wall and the pressure acts on the lumen"
                    if other == "thick" else "the wall behaves as a membrane with the pressure on the marker surface")
            flags.append(f"the wall form looks wrong: --wall {other} closes the virtual-work gap from {gap:.1%} to "
                         f"{g_wall:.1%} of the external work ({what}); identify with --wall {other}")
    return SetupCheck(taper=taper, gap=gap, gap_other_ends=g_ends, gap_other_wall=g_wall, flags=tuple(flags))
