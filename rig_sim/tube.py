"""Homogeneous inflation/extension of a cylindrical artery: thin membrane (Laplace law) and thick incompressible wall.

Geometry and conventions
------------------------
``radius`` R is the reference radius of the surface that carries the markers, the *outer* surface of the wall;
``thickness`` H is the reference wall thickness. ``lam_z`` is the axial stretch, ``lam_theta`` the circumferential
stretch of the marker surface.

* Membrane form (the paper's): the wall is a membrane of radius r = lam_theta R at the marker surface, thickness
  h = H / (lam_theta lam_z); the pressure acts on that surface. Laplace: ``p r = sigma_tt h``.
* Thick form: incompressible cylinder with reference radii R_i = R - H (lumen) and R_o = R (markers); pressure p on the
  lumen, traction-free outer surface. Radial equilibrium d(sigma_rr)/dr = (sigma_tt - sigma_rr) / r integrated through
  the wall with Gauss-Legendre quadrature.

Axial forces (tension positive, N)
----------------------------------
* ``wall force`` N: resultant of the axial stress over the wall cross-section, N = int sigma_zz dA. Membrane:
  N = sigma_zz 2 pi r h. This is what the paper's eq. 8 / appendix B (eq. 15, S22 = F / (2 pi R e)) call the axial
  load F: the force the wall itself carries.
* ``transducer force``: what a load cell behind a *closed*, pressurised cannula reads. Its free body (cannula and
  everything up to the load cell) is pulled by the wall (N, towards the specimen) and pushed away by the pressure on
  the sealed lumen area: F_T = N - p pi a^2, with a the lumen radius at the cannula (membrane: a = r; thick: a = r_i).
  Equivalently N = F_T + p pi a^2 (the classic "closed-end" relation). ``transducer_force`` converts.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np
from scipy.optimize import brentq

from .materials import check_params, membrane_cauchy

log = logging.getLogger(__name__)

__all__ = [
    "MechanicsError",
    "MembraneState",
    "ThickState",
    "membrane_pressure",
    "membrane_wall_force",
    "inflate_membrane",
    "thick_tube_state",
    "inflate_thick",
    "midwall_membrane_state",
    "transducer_force",
    "wall_force_from_transducer",
]


class MechanicsError(RuntimeError):
    """A mechanics problem has no (stable) solution, e.g. a pressure beyond the inflation limit point."""


def _check_geometry(radius: float, thickness: float) -> None:
    if not (radius > 0 and math.isfinite(radius)):
        raise ValueError(f"radius must be a positive length in m; got {radius!r}")
    if not (0 < thickness < radius):
        raise ValueError(f"thickness must be in (0, radius={radius!r}) m; got {thickness!r}")


def transducer_force(wall_force, pressure, lumen_radius):
    """Load-cell reading behind a closed pressurised cannula: ``F_T = N - p pi a^2`` [N] (arrays broadcast)."""
    return np.asarray(wall_force) - np.asarray(pressure) * np.pi * np.asarray(lumen_radius) ** 2


def wall_force_from_transducer(transducer, pressure, lumen_radius):
    """Inverse of ``transducer_force``: ``N = F_T + p pi a^2`` [N]."""
    return np.asarray(transducer) + np.asarray(pressure) * np.pi * np.asarray(lumen_radius) ** 2


# ---------------------------------------------------------------------------------------------------------- membrane
def membrane_pressure(model, params, lam_theta, lam_z, *, radius, thickness):
    """Pressure [Pa] that holds a homogeneous membrane tube at (lam_theta, lam_z): ``p = sigma_tt h / r``.

    ``r = lam_theta radius``, ``h = thickness / (lam_theta lam_z)``; arrays broadcast.
    """
    lt = np.asarray(lam_theta, dtype=float)
    lz = np.asarray(lam_z, dtype=float)
    stt, _ = membrane_cauchy(model, params, lt, lz)
    return stt * thickness / (lt * lt * lz * radius)


def membrane_wall_force(model, params, lam_theta, lam_z, *, radius, thickness):
    """Wall axial force [N] of a homogeneous membrane tube: ``N = sigma_zz 2 pi r h = sigma_zz 2 pi R H / lam_z``."""
    lt = np.asarray(lam_theta, dtype=float)
    lz = np.asarray(lam_z, dtype=float)
    _, szz = membrane_cauchy(model, params, lt, lz)
    return szz * 2.0 * np.pi * radius * thickness / lz


def _first_root(fun, target: float, lo: float = 0.2, hi: float = 6.0, n: int = 400) -> float:
    """Smallest x in [lo, hi] with fun(x) = target on the first upward crossing (stable branch).

    fun must be vectorised. Raises MechanicsError if fun never reaches target (limit point exceeded).
    """
    x = np.geomspace(lo, hi, n)
    with np.errstate(over="ignore", invalid="ignore"):  # exponential laws overflow at absurd stretches
        g = fun(x) - target
    if not np.all(np.isfinite(g)):
        bad = ~np.isfinite(g)
        g[bad] = np.inf  # overflowing exponentials are "very large"
    if g[0] > 0:
        raise MechanicsError(f"no solution above stretch {lo}: residual {g[0]:.3g} > 0 at the lower bound")
    up = np.nonzero((g[:-1] <= 0) & (g[1:] > 0))[0]
    if up.size == 0:
        raise MechanicsError(
            f"target {target:.6g} is never reached for stretches in [{lo}, {hi}] (max {np.max(g) + target:.6g}): "
            "the pressure exceeds the inflation limit point of this model"
        )
    i = int(up[0])
    if g[i] == 0:
        return float(x[i])
    f = lambda s: float(fun(np.array([s]))[0] - target)  # noqa: E731
    return float(brentq(f, x[i], x[i + 1], xtol=1e-15, rtol=1e-15, maxiter=200))


@dataclass(frozen=True)
class MembraneState:
    """Homogeneous membrane tube state, arrays of shape (n,) (one per pressure).

    Attributes
    ----------
    pressure : ndarray, Pa
    lam_theta, lam_z : ndarray
        Circumferential and axial stretch.
    radius, thickness : ndarray, m
        Deformed radius r = lam_theta R and thickness h = H / (lam_theta lam_z).
    sigma_tt, sigma_zz : ndarray, Pa
        Cauchy stresses.
    wall_force : ndarray, N
        sigma_zz 2 pi r h (force carried by the wall).
    transducer_force : ndarray, N
        wall_force - p pi r^2 (closed pressurised cannula, pressure acting on the membrane surface).
    """

    pressure: np.ndarray
    lam_theta: np.ndarray
    lam_z: np.ndarray
    radius: np.ndarray
    thickness: np.ndarray
    sigma_tt: np.ndarray
    sigma_zz: np.ndarray
    wall_force: np.ndarray
    transducer_force: np.ndarray


def inflate_membrane(model: str, params: Mapping[str, float], pressure, lam_z: float, *, radius: float,
                     thickness: float) -> MembraneState:
    """Solve the Laplace law ``p r = sigma_tt h`` for lam_theta at each pressure (stable branch, brentq).

    Parameters
    ----------
    model, params : str, mapping
        Constitutive law and its SI parameters (``rig_sim.materials``).
    pressure : array_like, shape (n,) or scalar, Pa
        Transmural pressure(s).
    lam_z : float
        Axial stretch.
    radius, thickness : float, m
        Reference radius of the membrane (marker) surface and reference thickness.

    Returns
    -------
    MembraneState
        Arrays of shape (n,).
    """
    params = check_params(model, params)
    _check_geometry(radius, thickness)
    p = np.atleast_1d(np.asarray(pressure, dtype=float))
    lam_z = float(lam_z)
    fun = lambda lt: membrane_pressure(model, params, lt, lam_z, radius=radius, thickness=thickness)  # noqa: E731
    lt = np.array([_first_root(fun, float(pi)) for pi in p])
    stt, szz = membrane_cauchy(model, params, lt, lam_z)
    r = lt * radius
    h = thickness / (lt * lam_z)
    n = szz * 2.0 * np.pi * r * h
    return MembraneState(p, lt, np.full_like(lt, lam_z), r, h, stt, szz, n, transducer_force(n, p, r))


# ---------------------------------------------------------------------------------------------------------- thick
@dataclass(frozen=True)
class ThickState:
    """Homogeneous thick-wall tube state, arrays of shape (n,).

    Attributes
    ----------
    pressure : ndarray, Pa
        Lumen pressure.
    lam_outer, lam_z : ndarray
        Circumferential stretch of the outer (marker) surface, axial stretch.
    outer_radius, inner_radius, midwall_radius : ndarray, m
        Deformed radii (mid-wall = the material surface at reference radius R - H/2).
    wall_force : ndarray, N
        2 pi int sigma_zz r dr over the wall.
    transducer_force : ndarray, N
        wall_force - p pi r_i^2.
    mean_sigma_rr : ndarray, Pa
        Thickness-average of the radial stress (between -p and 0).
    """

    pressure: np.ndarray
    lam_outer: np.ndarray
    lam_z: np.ndarray
    outer_radius: np.ndarray
    inner_radius: np.ndarray
    midwall_radius: np.ndarray
    wall_force: np.ndarray
    transducer_force: np.ndarray
    mean_sigma_rr: np.ndarray


def _thick_integrals(model, params, lam_outer, lam_z, radius, thickness, n_quad):
    """p, N, r_i, r_o, mean sigma_rr for outer stretches lam_outer (n,); Gauss-Legendre in the reference radius."""
    lo = np.atleast_1d(np.asarray(lam_outer, dtype=float))
    ro_ref, ri_ref = radius, radius - thickness
    ro = lo * ro_ref
    ri2 = ro * ro - (ro_ref**2 - ri_ref**2) / lam_z
    if np.any(ri2 <= 0):
        raise MechanicsError("the lumen closes: outer stretch too small for this axial stretch")
    xg, wg = np.polynomial.legendre.leggauss(n_quad)
    rho = 0.5 * (ro_ref + ri_ref) + 0.5 * thickness * xg  # (q,) reference radii
    w = 0.5 * thickness * wg
    r2 = ri2[:, None] + (rho[None, :] ** 2 - ri_ref**2) / lam_z  # (n, q) deformed radius^2
    r = np.sqrt(r2)
    lt = r / rho[None, :]
    stt, szz = membrane_cauchy(model, params, lt, lam_z)  # = sigma_tt - sigma_rr, sigma_zz - sigma_rr
    # dr/r = rho drho / (lam_z r^2);  r dr = rho drho / lam_z
    p = np.sum(stt * rho / (lam_z * r2) * w, axis=1)
    # sigma_rr(r) = -int_r^ro (stt/r') dr'; int sigma_rr r dr = p ri^2/2 - 1/2 int stt r dr
    n_force = np.pi * np.sum((2.0 * szz - stt) * rho / lam_z * w, axis=1) + p * np.pi * ri2
    area = np.pi * (ro * ro - ri2)
    mean_srr = (np.pi * (p * ri2 - np.sum(stt * rho / lam_z * w, axis=1))) / area
    return p, n_force, np.sqrt(ri2), ro, mean_srr


def thick_tube_state(model: str, params: Mapping[str, float], lam_outer, lam_z: float, *, radius: float,
                     thickness: float, n_quad: int = 24) -> ThickState:
    """Thick-wall state for given outer-surface (marker) stretch(es): lumen pressure and wall force.

    Parameters
    ----------
    lam_outer : array_like, shape (n,)
        Circumferential stretch of the outer surface r_o / R.
    lam_z : float
        Axial stretch.
    radius, thickness : float, m
        Reference outer radius R (markers) and wall thickness H; lumen radius R - H.
    n_quad : int
        Gauss-Legendre points through the wall (24 gives ~1e-14 relative accuracy here).
    """
    params = check_params(model, params)
    _check_geometry(radius, thickness)
    lam_z = float(lam_z)
    lo = np.atleast_1d(np.asarray(lam_outer, dtype=float))
    p, n_force, ri, ro, msrr = _thick_integrals(model, params, lo, lam_z, radius, thickness, n_quad)
    rm = np.sqrt(ro * ro - (radius**2 - (radius - 0.5 * thickness) ** 2) / lam_z)
    return ThickState(p, lo, np.full_like(lo, lam_z), ro, ri, rm, n_force, transducer_force(n_force, p, ri), msrr)


def inflate_thick(model: str, params: Mapping[str, float], pressure, lam_z: float, *, radius: float,
                  thickness: float, n_quad: int = 24) -> ThickState:
    """Solve the thick-wall tube for the outer stretch at each lumen pressure (stable branch).

    Same arguments and result as ``thick_tube_state``, with ``pressure`` (n,) Pa instead of the outer stretch.
    """
    params = check_params(model, params)
    _check_geometry(radius, thickness)
    lam_z = float(lam_z)
    p = np.atleast_1d(np.asarray(pressure, dtype=float))
    # the lumen must stay open: lam_outer^2 > (1 - (1 - H/R)^2) / lam_z
    lo_min = math.sqrt((1.0 - (1.0 - thickness / radius) ** 2) / lam_z) * 1.0001
    fun = lambda lo: _thick_integrals(model, params, lo, lam_z, radius, thickness, n_quad)[0]  # noqa: E731
    lo = np.array([_first_root(fun, float(pi), lo=max(lo_min, 0.6)) for pi in p])
    return thick_tube_state(model, params, lo, lam_z, radius=radius, thickness=thickness, n_quad=n_quad)


def midwall_membrane_state(model: str, params: Mapping[str, float], lam_outer, lam_z: float, *, radius: float,
                           thickness: float) -> MembraneState:
    """Thin-membrane prediction placed at mid-wall, for given *outer-surface* stretches (for bias studies).

    The mid-wall material surface (reference radius R_m = R - H/2) is located from the outer stretch by
    incompressibility, ``r_m^2 = r_o^2 - (R^2 - R_m^2) / lam_z``; the membrane law is then applied there with the
    full thickness H: ``p = sigma_tt h / r_m``, ``N = sigma_zz 2 pi r_m h``. Pressure is taken on the mid-wall surface
    (transducer force uses r_m).
    """
    params = check_params(model, params)
    _check_geometry(radius, thickness)
    lam_z = float(lam_z)
    lo = np.atleast_1d(np.asarray(lam_outer, dtype=float))
    rm_ref = radius - 0.5 * thickness
    rm = np.sqrt((lo * radius) ** 2 - (radius**2 - rm_ref**2) / lam_z)
    lt = rm / rm_ref
    p = membrane_pressure(model, params, lt, lam_z, radius=rm_ref, thickness=thickness)
    stt, szz = membrane_cauchy(model, params, lt, lam_z)
    h = thickness / (lt * lam_z)
    n = szz * 2.0 * np.pi * rm * h
    return MembraneState(p, lt, np.full_like(lt, lam_z), rm, h, stt, szz, n, transducer_force(n, p, rm))
