"""Closed-form data for the identification tests and benchmarks: homogeneous inflation/extension of a membrane
tube (moved from tests/ident_synth.py). For each step the circumferential and axial stretches are
chosen; the pressure and wall axial force follow from the Laplace law with the model's stresses.
"""

from __future__ import annotations

import numpy as np

from identification import pk2_stress

PAPER = {
    "fung": {"beta": 5e3, "alpha11": 14.5, "alpha22": 7.0, "alpha12": 0.1},
    "delfino": {"beta": 1.5e3, "alpha": 4.6},
    "hgo": {"c": 0.4e3, "k1": 8.7e3, "k2": 5.4, "phi": np.deg2rad(27.0)},
    "neohookean": {"mu": 200e3},
}
R0, L0, E0 = 10e-3, 35e-3, 1.3e-3


def cauchy_hoop_axial(model, params, lam_t, lam_z):
    lam_t, lam_z = np.broadcast_arrays(np.asarray(lam_t, float), np.asarray(lam_z, float))
    C = np.zeros(lam_t.shape + (2, 2))
    C[..., 0, 0] = lam_t**2
    C[..., 1, 1] = lam_z**2
    S = pk2_stress(model, C, params)
    return S[..., 0, 0] * lam_t**2, S[..., 1, 1] * lam_z**2


def markers(n=300, seed=0, radius=R0, length=L0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-np.pi, np.pi, n), rng.uniform(-length / 2, length / 2, n)


def homogeneous(model, params, lam_t, lam_z, *, n=300, seed=0, thickness=E0):
    """Positions (n_steps, n, 3), pressure (n_steps,), wall axial force (n_steps,).

    Step 0 must be (1, 1). Pressure from Laplace (p = sigma_tt h / r), force = sigma_zz 2 pi r h.
    """
    lam_t = np.asarray(lam_t, float)
    lam_z = np.broadcast_to(np.asarray(lam_z, float), lam_t.shape)
    s_t, s_z = cauchy_hoop_axial(model, params, lam_t, lam_z)
    h = thickness / (lam_t * lam_z)
    r = R0 * lam_t
    p = s_t * h / r
    f = s_z * 2 * np.pi * r * h
    th, z = markers(n, seed)
    pos = np.stack([np.column_stack([ri * np.cos(th), ri * np.sin(th), z * lz]) for ri, lz in zip(r, lam_z)])
    return pos, p, f


def lam_t_for_pressures(model, params, pressures, lam_z, thickness=E0):
    """Hoop stretch at each pressure (bisection on the Laplace law), shape like pressures."""
    pressures = np.asarray(pressures, float)
    lo = np.full(pressures.shape, 0.7)
    hi = np.full(pressures.shape, 3.0)
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        s_t, _ = cauchy_hoop_axial(model, params, mid, lam_z)
        pm = s_t * thickness / (mid * lam_z) / (R0 * mid)
        lo = np.where(pm < pressures, mid, lo)
        hi = np.where(pm < pressures, hi, mid)
    return 0.5 * (lo + hi)
