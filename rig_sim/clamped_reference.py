"""Independent clamped-tube ground truth for the identification tests and benchmarks
(moved from tests/ident_clamped_synth.py).

An axisymmetric membrane tube tied on two cannulae of its reference radius R at Z = +-L/2, axial
stretch imposed, pressurised. With the meridional stress resultant Q = R H S_s (r', z') (S_s the
meridional 2nd Piola-Kirchhoff stress), equilibrium of a ring reads

    d/dZ Q_z = p r r'   ->  2 pi Q_z - p pi r^2 = F_T (constant)
    d/dZ Q_r = H (r/R) S_theta - p r z'

Solved with ``solve_bvp`` on the half tube (symmetry: z(0) = 0, Q_r(0) = 0; clamp: r(L/2) = R,
z(L/2) = lambda L/2) with the constant F_T as unknown parameter, continuation in pressure. Stresses come from
``rig_sim.materials.membrane_cauchy`` (an implementation independent of ``identification``).
Returns the wall force at the clamps, N = F_T + p pi R^2.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_bvp

from rig_sim.mechanics import membrane_cauchy

from rig_sim.homogeneous_tube import E0, L0, R0, markers


def _stresses(model, params, lt, ls):
    st, ss = membrane_cauchy(model, params, lt, ls)
    return st / lt**2, ss / ls**2  # S_theta, S_s


def _lam_s(model, params, lt, target, guess):
    """Solve R H S_s(lt, ls) ls = target for ls, elementwise (Newton, complex-step slope)."""
    ls = np.array(guess, dtype=float)
    for _ in range(60):
        h = 1e-20
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            _, sc = membrane_cauchy(model, params, lt + 0j, ls + 1j * h)
            g = R0 * E0 * sc / (ls + 1j * h)  # = R H S_s ls
        step = (g.real - target) / (g.imag / h)
        ls = np.clip(ls - step, 0.3 * ls, 3.0 * ls)
        if np.all(np.abs(step) < 1e-14 * ls):
            break
    return ls


def _solve(model, params, p, stretch, guess=None):
    """solve_bvp on Z in [0, L/2] for y = (r, z, Q_r) with the unknown parameter F_T."""
    half = 0.5 * L0

    def rhs(Z, y, par):
        r, z, qa = y
        FT = par[0]
        lt = r / R0
        qb = (FT + p * np.pi * r * r) / (2 * np.pi)
        q = np.hypot(qa, qb)
        ls = _lam_s(model, params, lt, q, np.full_like(r, stretch))
        a, b = ls * qa / q, ls * qb / q
        s_t, _ = _stresses(model, params, lt, ls)
        return np.vstack([a, b, E0 * lt * s_t - p * r * b])

    def bc(ya, yb, par):
        return np.array([ya[1], ya[2], (yb[0] - R0) / R0, (yb[1] - stretch * half) / half])

    if guess is None:
        Zg = np.linspace(0.0, half, 201)
        yg = np.vstack([np.full_like(Zg, R0), stretch * Zg, np.zeros_like(Zg)])
        _, sz = membrane_cauchy(model, params, 1.0, stretch)
        par = [float(sz) * 2 * np.pi * R0 * E0 / stretch]
    else:
        Zg, yg, par = guess
    sol = solve_bvp(rhs, bc, Zg, yg, p=par, tol=1e-8, max_nodes=100000)
    if not sol.success:
        raise RuntimeError(f"clamped tube BVP failed at p={p}: {sol.message}")
    return sol, sol.p[0] + p * np.pi * R0**2


def clamped_tube(model, params, pressures, *, stretch=1.1, n=300, seed=0, margin=4e-3):
    """Positions (n_steps, n, 3), pressure (n_steps,), wall force at the clamps (n_steps,); step 0 = reference."""
    theta, Z = markers(n, seed, length=L0 - 2 * margin)
    pos = [np.column_stack([R0 * np.cos(theta), R0 * np.sin(theta), Z])]
    force = [0.0]
    guess = None
    for p in pressures:  # continuation in pressure from the previous solution
        for sub in ([0.5, 1.0] if guess is not None else [1.0]):
            sol, N = _solve(model, params, float(p) * sub if sub < 1 else float(p), stretch, guess)
            Zg = np.linspace(0.0, 0.5 * L0, 401)
            guess = (Zg, sol.sol(Zg), sol.p)  # resampled: nodes do not pile up along the continuation
        y = sol.sol(np.abs(Z))
        r, z = y[0], np.sign(Z) * y[1]
        pos.append(np.column_stack([r * np.cos(theta), r * np.sin(theta), z]))
        force.append(N)
    return np.stack(pos), np.concatenate([[0.0], np.asarray(pressures, float)]), np.array(force)
