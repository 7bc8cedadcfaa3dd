"""Heterogeneous ground truth: axisymmetric membrane tube clamped on two cannulae, solved as a boundary-value problem.

Model
-----
Reference: membrane cylinder of radius R (the marker surface), thickness H, length L0, material coordinate
Z in [-L0/2, L0/2]. Deformed meridian r(Z), z(Z); a = dr/dZ, b = dz/dZ. Principal stretches
lam_theta = r / R (circumferential) and lam_s = sqrt(a^2 + b^2) (meridional); tensions per unit deformed length
T_theta = sigma_theta h, T_s = sigma_s h, h = H / (lam_theta lam_s), sigma from ``rig_sim.materials``. With the
pressure p acting on the membrane (outward normal n = (b, -a) / lam_s in (r, z)), equilibrium of a ring reads

    d/dZ (r T_s b / lam_s) = p r a                      (axial)
    d/dZ (r T_s a / lam_s) = lam_s T_theta - p r b      (radial)

and r T_s / lam_s = R H S_s, with S_s = sigma_s / lam_s^2 the meridional 2nd Piola-Kirchhoff stress. Expanding the
derivatives gives a linear 2x2 system for (r'', z'') with matrix S_s I + (dS_s/dlam_s / lam_s) v v^T, v = (a, b),
inverted in closed form (Sherman-Morrison); it is regular while the meridian is in tension (S_s > 0) and stable
(d(lam_s S_s)/dlam_s > 0). Partial derivatives of S_s come from complex-step differentiation of the closed-form law.
Boundary conditions (both ends clamped on cannulae of radius ``clamp_radius``, overall stretch lam imposed,
symmetric about the origin of the rig frame): r(+-L0/2) = clamp_radius, z(+-L0/2) = +-lam L0/2.
Solved with ``scipy.integrate.solve_bvp`` in variables scaled by R, with continuation in pressure from the previous
solution (increments halved on failure).

Axial forces
------------
The wall axial force through the section at Z is N(Z) = 2 pi r T_s cos(psi) = 2 pi R H S_s b. Axial equilibrium of
the tube between two sections gives N(Z) - p pi r(Z)^2 = const = the transducer force (reading of a load cell behind
a closed cannula of seal radius = clamp radius). So N is *not* constant along a clamped tube: it is largest where the
tube bulges. ``end_wall_force`` is N at the cannulae (Z = +-L0/2).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from typing import Mapping

import numpy as np
from scipy.integrate import solve_bvp
from scipy.interpolate import CubicHermiteSpline

from .materials import check_params, get_law
from .tube import MechanicsError

log = logging.getLogger(__name__)

__all__ = ["ClampedSolution", "solve_clamped"]

_H_CS = 1e-30  # complex-step size


@dataclass(frozen=True)
class ClampedSolution:
    """One converged clamped-tube state.

    Attributes
    ----------
    pressure : float, Pa
    stretch : float
        Overall axial stretch L / L0.
    clamp_radius : float, m
        Radius of the tube at both cannulae.
    radius, thickness, length : float, m
        Reference R, H, L0.
    Z : ndarray, shape (m,), m
        Final BVP mesh (reference axial coordinate).
    y : ndarray, shape (4, m)
        r [m], z [m], dr/dZ, dz/dZ on the mesh.
    yp : ndarray, shape (4, m)
        d/dZ of y (dr/dZ, dz/dZ [1]; d2r/dZ2, d2z/dZ2 [1/m]).
    end_wall_force : float, N
        Wall axial force at the cannulae (mean of both ends; they agree to the BVP tolerance).
    transducer_force : float, N
        N(Z) - p pi r(Z)^2, constant along the tube (mean over the mesh).
    end_meridional_tension : float, N/m
        T_s at the cannulae.
    end_slope : float, rad
        Angle psi of the meridian with the axis at Z = +L0/2 (negative when the tube narrows towards the cannula).
    max_rms_residual : float
        Largest relative collocation residual reported by solve_bvp.
    min_dzdZ : float
        Smallest dz/dZ on the mesh; <= 0 means the meridian turns back on itself next to a cannula (the membrane
        folds over the cannula: a membrane-model artefact, see docs/validation/mechanics.md).
    solve_time : float, s
        Wall time of this solve (including any pressure sub-steps).
    model : str
    params : dict
        SI parameters (the reference values; local values are ``stress_scale(Z)`` times the stress-like ones).
    stress_scale : callable or None
        Local stress multiplier m(Z) of the solve (None: homogeneous tube).
    """

    pressure: float
    stretch: float
    clamp_radius: float
    radius: float
    thickness: float
    length: float
    Z: np.ndarray
    y: np.ndarray
    yp: np.ndarray
    end_wall_force: float
    transducer_force: float
    end_meridional_tension: float
    end_slope: float
    max_rms_residual: float
    min_dzdZ: float
    solve_time: float
    model: str
    params: dict
    stress_scale: object = None

    def evaluate(self, Z) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Profile (r, z, dr/dZ, dz/dZ) at reference Z (n,) m, from the BVP's own C1 cubic interpolant."""
        sp = CubicHermiteSpline(self.Z, self.y, self.yp, axis=1)
        v = sp(np.asarray(Z, dtype=float))
        return v[0], v[1], v[2], v[3]

    def wall_force(self, Z) -> np.ndarray:
        """Wall axial force N(Z) = 2 pi R H S_s dz/dZ [N] at reference Z (n,)."""
        r, _, a, b = self.evaluate(Z)
        return _wall_force((get_law(self.model), self.params), r, a, b, self.radius, self.thickness,
                           _scale_at(self.stress_scale, np.asarray(Z, dtype=float)))


def _meridional_pk2(law, params, lt, ls):
    s1, s2 = law.cauchy(lt, ls, **params)
    return s1, s2 / (ls * ls)


def _wall_force(law_params, r, a, b, radius, thickness, scale=1.0):
    law, params = law_params
    ls = np.hypot(a, b)
    _, ss = _meridional_pk2(law, params, r / radius, ls)
    return 2.0 * np.pi * radius * thickness * scale * ss * b


def _scale_at(stress_scale, Z) -> np.ndarray | float:
    """Local stress multiplier m(Z) (1 for a homogeneous tube), validated positive and finite."""
    if stress_scale is None:
        return 1.0
    m = np.asarray(stress_scale(np.asarray(Z, dtype=float)), dtype=float)
    if m.shape != np.shape(Z) or not np.all(np.isfinite(m) & (m > 0)):
        raise ValueError(f"stress_scale must map Z (shape {np.shape(Z)}) to positive finite multipliers of the "
                         f"same shape; got shape {m.shape}, range [{np.nanmin(m):.3g}, {np.nanmax(m):.3g}]")
    return m


def _invert_meridional(law, params, lt, g, n_iter: int = 60):
    """Solve lam_s S_s(lt, lam_s) = g for lam_s (vectorised: 12 bisections, then safeguarded Newton with a
    complex-step derivative).

    lam_s S_s = sigma_s / lam_s increases with lam_s for every law here while the meridian is in tension.
    """
    lo = np.full(lt.shape, 0.3)
    hi = np.full(lt.shape, 4.0)
    # bisection first (Newton from far away crawls down the exponential laws), then safeguarded Newton
    for _ in range(12):
        mid = 0.5 * (lo + hi)
        with np.errstate(over="ignore", invalid="ignore"):
            above = law.cauchy(lt, mid, **params)[1] / mid > g
        hi = np.where(above, mid, hi)
        lo = np.where(above, lo, mid)
    x = 0.5 * (lo + hi)
    active = np.ones(lt.shape, dtype=bool)
    for _ in range(n_iter):
        xc = x[active] + 1j * _H_CS
        fc = law.cauchy(lt[active] + 0j, xc, **params)[1] / xc
        f = np.real(fc) - g[active]
        df = np.imag(fc) / _H_CS
        lo_a = np.where(f < 0, x[active], lo[active])
        hi_a = np.where(f > 0, x[active], hi[active])
        xn = x[active] - f / np.where(df > 0, df, np.inf)
        bad = ~((xn >= lo_a) & (xn <= hi_a)) | ~np.isfinite(xn)
        xn = np.where(bad, 0.5 * (lo_a + hi_a), xn)
        conv = (np.abs(xn - x[active]) <= 4e-16 * x[active]) | (f == 0)
        lo[active], hi[active], x[active] = lo_a, hi_a, xn
        idx = np.flatnonzero(active)
        active[idx[conv]] = False
        if not active.any():
            break
    return x


def _make_problem(law, params, p_hat, rc_hat, half_len_hat, s0, stress_scale=None, radius=1.0):
    """First-order system in xi = Z/R: y = (r/R, z/R, q_z/s0, q_r/s0), q_z = S_s dz/dZ, q_r = S_s dr/dZ [Pa].

    p_hat = p R / (H s0); s0 [Pa] scales the stresses so that all unknowns are O(1). ``stress_scale`` (callable of
    Z [m], or None) multiplies the law's stresses pointwise: the ring equilibrium holds with the local law.
    """

    def state(x, y):
        r, _, qz, qr = y
        m = _scale_at(stress_scale, x * radius)
        gh = np.sqrt(qz * qz + qr * qr)
        ls = _invert_meridional(law, params, r, np.broadcast_to(gh * s0 / m, r.shape))
        return r, qz, qr, gh, ls, m

    def fun(x, y):
        r, qz, qr, gh, ls, m = state(x, y)
        a, b = ls * qr / gh, ls * qz / gh  # dr/dZ, dz/dZ
        f_t = m * law.cauchy(r, ls, **params)[0] / (r * s0)  # lam_s T_theta / (H s0)
        return np.vstack([a, b, p_hat * r * a, f_t - p_hat * r * b])

    def fun_jac(x, y):
        r, qz, qr, gh, ls, m = state(x, y)
        a, b = ls * qr / gh, ls * qz / gh
        h = _H_CS
        cr = law.cauchy(r + 1j * h, ls + 0j, **params)  # d/dr of (sigma_t, sigma_s)
        cl = law.cauchy(r + 0j, ls + 1j * h, **params)  # d/dlam_s
        st, ss = m * np.real(cr[0]), m * np.real(cr[1])
        st_r, ss_r = m * np.imag(cr[0]) / h, m * np.imag(cr[1]) / h
        st_l, ss_l = m * np.imag(cl[0]) / h, m * np.imag(cl[1]) / h
        # phi = sigma_s / lam_s = g defines lam_s(r, g)
        phi_r, phi_l = ss_r / ls, ss_l / ls - ss / (ls * ls)
        lam_r = -phi_r / phi_l
        lam_qz, lam_qr = s0 * qz / (gh * phi_l), s0 * qr / (gh * phi_l)
        g3 = gh**3
        a_r, b_r = lam_r * qr / gh, lam_r * qz / gh
        a_qz = lam_qz * qr / gh - ls * qr * qz / g3
        a_qr = lam_qr * qr / gh + ls / gh - ls * qr * qr / g3
        b_qz = lam_qz * qz / gh + ls / gh - ls * qz * qz / g3
        b_qr = lam_qr * qz / gh - ls * qz * qr / g3
        f_r = st_r / (r * s0) - st / (r * r * s0)
        f_l = st_l / (r * s0)
        z0 = np.zeros_like(r)
        jac = np.array([
            [a_r, z0, a_qz, a_qr],
            [b_r, z0, b_qz, b_qr],
            [p_hat * (a + r * a_r), z0, p_hat * r * a_qz, p_hat * r * a_qr],
            [f_r + f_l * lam_r - p_hat * (b + r * b_r), z0, f_l * lam_qz - p_hat * r * b_qz,
             f_l * lam_qr - p_hat * r * b_qr],
        ])
        return jac

    def bc(ya, yb):
        return np.array([ya[0] - rc_hat, yb[0] - rc_hat, ya[1] + half_len_hat, yb[1] - half_len_hat])

    bc_a = np.zeros((4, 4))
    bc_b = np.zeros((4, 4))
    bc_a[0, 0] = bc_a[2, 1] = 1.0
    bc_b[1, 0] = bc_b[3, 1] = 1.0

    def bc_jac(ya, yb):
        return bc_a, bc_b

    return fun, bc, fun_jac, bc_jac


def solve_clamped(model: str, params: Mapping[str, float], pressures, stretch: float, *, radius: float = 10e-3,
                  thickness: float = 1.3e-3, length: float = 35e-3, clamp_radius: float | None = None,
                  n_nodes: int = 401, tol: float = 1e-8, max_halvings: int = 6,
                  max_nodes: int = 50000, n_sub: int = 3, coarse_tol: float = 1e-4,
                  stress_scale=None) -> list[ClampedSolution]:
    """Solve the clamped membrane tube at a sequence of pressures (continuation in the given order).

    Parameters
    ----------
    model, params : str, mapping
        Constitutive law and SI parameters (``rig_sim.materials``).
    pressures : array_like, shape (n,), Pa
        Pressure levels, solved in order, each starting from the previous solution (the first from p = 0).
    stretch : float
        Overall axial stretch L/L0; must exceed 1 (an unstretched membrane has no meridional tension at p = 0 and the
        problem is singular).
    radius, thickness, length : float, m
        Reference radius of the membrane (marker surface), thickness and length between the cannulae.
    clamp_radius : float, optional, m
        Radius held by the cannulae (default: ``radius``).
    n_nodes : int
        Initial number of mesh nodes (solve_bvp refines as needed, up to 20,000).
    tol : float
        solve_bvp relative residual tolerance (also used for the boundary conditions, scaled by R).
    max_halvings : int
        How many times a pressure sub-increment may be halved when a solve fails.
    max_nodes : int
        Mesh-size cap of solve_bvp.
    n_sub : int
        Continuation sub-steps per pressure increment, solved at ``coarse_tol``.
    coarse_tol : float
        Tolerance of the continuation sub-steps (the reported solution is always solved at ``tol``).
    stress_scale : callable, optional
        Axially varying material: m(Z) for reference Z (n,) m -> (n,) positive multipliers of the law's stresses
        (for Fung and Delfino a local beta = m(Z) beta; e.g. ``rig_sim.regional.AxialProfile``). Smooth profiles
        keep the collocation mesh small. Default: homogeneous.

    Returns
    -------
    list of ClampedSolution, one per pressure.

    Raises
    ------
    MechanicsError
        If a step cannot be solved even after halving the increment ``max_halvings`` times.
    """
    params = check_params(model, params)
    rc, pr = _check_setting(stretch, radius, clamp_radius, pressures)
    t0 = time.perf_counter()
    cont = _Continuation(model, params, stretch, rc, radius, thickness, length, float(np.max(pr, initial=0.0)),
                         stress_scale, dict(n_nodes=int(n_nodes), tol=tol, max_halvings=max_halvings,
                                            max_nodes=max_nodes, n_sub=n_sub, coarse_tol=coarse_tol))
    out = _solve_pressures(cont, cont.unpressurised(), pr)
    log.debug("clamped %s: %d pressures at stretch %g solved in %.3f s", model, pr.size, stretch,
              time.perf_counter() - t0)
    return out


def _check_setting(stretch: float, radius: float, clamp_radius: float | None, pressures) -> tuple[float, np.ndarray]:
    """Validated clamp radius (m) and pressures (n,) Pa of ``solve_clamped``."""
    if not stretch > 1.0:
        raise ValueError(f"stretch must exceed 1 for the clamped membrane (a slack meridian is singular); "
                         f"got {stretch!r}")
    rc = float(radius if clamp_radius is None else clamp_radius)
    if not rc > 0:
        raise ValueError(f"clamp_radius must be positive in m; got {clamp_radius!r}")
    return rc, np.atleast_1d(np.asarray(pressures, dtype=float))


class _Continuation:
    """The scaled BVP of one clamped tube at one stretch, and its continuation in pressure (``solve_clamped``)."""

    def __init__(self, model, params, stretch, rc, radius, thickness, length, p_max, stress_scale, settings):
        self.model, self.params, self.law = model, params, get_law(model)
        self.stretch, self.rc, self.radius, self.thickness = stretch, rc, radius, thickness
        self.length, self.stress_scale, self.settings = length, stress_scale, settings
        self.half = 0.5 * length / radius
        u = np.linspace(-1.0, 1.0, settings["n_nodes"])
        self.x0 = self.half * (0.5 * u + 0.5 * np.sin(0.5 * np.pi * u))  # denser towards the cannulae
        # stress scale [Pa]: the larger of the meridional PK2 of the straight unpressurised tube and the Laplace hoop
        # stress at the highest pressure. With it the hoop-equilibrium residual, a difference of two large terms, is
        # measured against the stress level of the test rather than against 1 (fewer spurious mesh refinements).
        self.s_straight = self._meridional(stretch)
        if not self.s_straight > 0:
            raise MechanicsError(f"clamped {model} tube: no meridional tension at stretch {stretch}")
        self.s0 = max(self.s_straight, p_max * radius / thickness)

    def _meridional(self, lam: float) -> float:
        return float(_meridional_pk2(self.law, self.params, np.array([self.rc / self.radius]), np.array([lam]))[1][0])

    def straight(self, lam: float) -> np.ndarray:
        """Initial guess: the straight tube at stretch ``lam`` on the base mesh, shape (4, n_nodes)."""
        x0 = self.x0
        return np.vstack([np.full_like(x0, self.rc / self.radius), lam * x0,
                          np.full_like(x0, self._meridional(lam) * lam / self.s_straight), np.zeros_like(x0)])

    def attempt(self, p, x, y, lam=None, tol_=None, s=None):
        """One ``solve_bvp`` at pressure ``p`` Pa from (x, y); the result, or None when it failed."""
        lam = self.stretch if lam is None else lam
        tol_ = self.settings["tol"] if tol_ is None else tol_
        s = self.s0 if s is None else s
        fun, bc, fun_jac, bc_jac = _make_problem(self.law, self.params, p * self.radius / (self.thickness * s),
                                                 self.rc / self.radius, lam * self.half, s, self.stress_scale,
                                                 self.radius)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            res = solve_bvp(fun, bc, x, y, tol=tol_, bc_tol=tol_, max_nodes=self.settings["max_nodes"],
                            fun_jac=fun_jac, bc_jac=bc_jac)
        ok = (res.status == 0 and np.all(np.isfinite(res.y)) and np.all(res.y[0] > 0)
              and np.all(np.hypot(res.y[2], res.y[3]) > 0))
        if not ok:
            log.debug("clamped %s: p=%g stretch=%g failed: %s", self.model, p, lam, res.message)
        return res if ok else None

    def on_base(self, res):
        """Previous solution resampled on the base mesh (keeps the mesh from growing step after step)."""
        y = res.sol(self.x0)
        y[2:] *= getattr(res, "stress_scale", self.s0) / self.s0
        return self.x0, y

    def advance(self, p_from, p_to, res_from, depth=0):
        """Coarse continuation p_from -> p_to in n_sub steps, then one solve at the requested tolerance."""
        st = self.settings
        res, p_cur = res_from, p_from
        for p_k in np.linspace(p_from, p_to, st["n_sub"] + 1)[1:]:
            nxt = self.attempt(p_k, *self.on_base(res), tol_=st["coarse_tol"])
            if nxt is None:
                if depth >= st["max_halvings"]:
                    raise MechanicsError(
                        f"clamped {self.model} tube: no convergence from p={p_cur:.6g} Pa to p={p_k:.6g} Pa at "
                        f"stretch {self.stretch} after {st['max_halvings']} halvings of the pressure increment")
                nxt = self.advance(p_cur, p_k, res, depth + 1)
            res, p_cur = nxt, p_k
        final = self.attempt(p_to, *self.on_base(res))
        if final is None:
            final = self.attempt(p_to, res.x, res.y)
        if final is None:
            raise MechanicsError(f"clamped {self.model} tube: no convergence at p={p_to:.6g} Pa, stretch "
                                 f"{self.stretch} with tol={st['tol']}")
        return final

    def unpressurised(self):
        """The solution at p = 0, solved with the unpressurised stress scale (much better conditioned there), by
        continuation in stretch from a small pre-stretch when the direct solve fails."""
        base = self.attempt(0.0, self.x0, self.straight(self.stretch), s=self.s_straight)
        if base is None:
            res = None
            for k, lam in enumerate(np.linspace(1.0, self.stretch, 9)[1:]):
                res = self.attempt(0.0, self.x0, self.straight(lam) if k == 0 else res.sol(self.x0), lam,
                                   s=self.s_straight)
                if res is None:
                    raise MechanicsError(f"clamped {self.model} tube: no convergence at p=0, stretch {lam:.4g}")
            base = res
        base.stress_scale = self.s_straight
        return base


def _solve_pressures(cont: _Continuation, base, pr: np.ndarray) -> list[ClampedSolution]:
    """Continuation through the pressures ``pr`` (n,) Pa from the unpressurised ``base``; packaged solutions."""
    out = []
    p_prev, res = 0.0, base
    t_prev = time.perf_counter()
    for p in pr:
        res = base if p == 0.0 and p_prev == 0.0 else cont.advance(p_prev, float(p), res)
        now = time.perf_counter()
        sol = _package(res, cont.model, (cont.law, cont.params, cont.stress_scale), float(p), cont.stretch, cont.rc,
                       cont.radius, cont.thickness, cont.length, now - t_prev, getattr(res, "stress_scale", cont.s0))
        if sol.min_dzdZ <= 0:
            log.warning("clamped %s tube at p=%.6g Pa, stretch %g: the membrane folds back next to the cannulae "
                        "(min dz/dZ = %.3g); the end regions are not physical for a real artery", cont.model, p,
                        cont.stretch, sol.min_dzdZ)
        out.append(sol)
        t_prev = now
        p_prev = float(p)
    return out


def _package(res, model, material, p, stretch, rc, radius, thickness, length, dt, s0) -> ClampedSolution:
    law, params, stress_scale = material
    x = res.x
    r, z, qz, qr = res.y
    qz = qz * s0
    a, b = res.yp[0], res.yp[1]  # dr/dZ, dz/dZ (dimensionless)
    fun = _make_problem(law, params, p * radius / (thickness * s0), rc / radius, 0.0, s0, stress_scale, radius)[0]
    eps = 1e-7 * (x[-1] - x[0])
    # second derivatives (1/m) for the Hermite data of the slopes: centred differences of the exact slope map
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        ap, bp = (np.asarray(fun(x + d * eps, res.y + d * res.yp * eps)[0:2]) for d in (1.0, -1.0))
    curv = (ap - bp) / (2 * eps) / radius
    y = np.vstack([r * radius, z * radius, a, b])
    yp = np.vstack([a, b, curv])
    n_wall = 2.0 * np.pi * radius * thickness * qz
    ft = n_wall - p * math.pi * (r * radius) ** 2
    ls_end = math.hypot(a[-1], b[-1])
    m_end = float(np.asarray(_scale_at(stress_scale, np.array([x[-1] * radius]))).reshape(-1)[0])
    s_s = m_end * float(law.cauchy(np.array([r[-1]]), np.array([ls_end]), **params)[1][0])
    t_s_end = s_s * thickness / (r[-1] * ls_end)
    return ClampedSolution(
        pressure=p, stretch=float(stretch), clamp_radius=rc, radius=radius, thickness=thickness, length=length,
        Z=x * radius, y=y, yp=yp, end_wall_force=float(0.5 * (n_wall[0] + n_wall[-1])),
        transducer_force=float(np.mean(ft)), end_meridional_tension=t_s_end,
        end_slope=float(math.atan2(a[-1], b[-1])), max_rms_residual=float(np.max(res.rms_residuals)),
        min_dzdZ=float(np.min(b)), solve_time=float(dt), model=model, params=dict(params), stress_scale=stress_scale,
    )
