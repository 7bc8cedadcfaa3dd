"""Holzapfel-Gasser-Ogden model with two symmetric fibre families (Avril et al. 2010, eq. 4).

    W = c / 2 (I1 - 3) + k1 / (2 k2) * sum_{i=4,6} [exp(k2 (I_i - 1)^2) - 1]
    I4, I6 = C11 cos^2(phi) + C22 sin^2(phi) +/- 2 C12 sin(phi) cos(phi)

fibres at +/- phi from the circumferential direction, active in tension only (the fibre term is 0
when I_i <= 1); incompressible plane stress (C33 = 1 / det of the in-plane C).
Parameters: c [Pa], k1 [Pa], k2 [1], phi [rad].
"""

from __future__ import annotations

import numpy as np

from ._base import Model, register

__all__ = ["HGO"]


def _fibre(i, k1, k2):
    stretch = i - 1.0
    active = np.real(stretch) > 0.0
    return np.where(active, k1 / (2.0 * k2) * (np.exp(k2 * stretch * stretch) - 1.0), 0.0)


def energy(c11, c22, c12, c33, *, c, k1, k2, phi):
    cos2 = np.cos(phi) ** 2
    sin2 = np.sin(phi) ** 2
    shear = 2.0 * np.sin(phi) * np.cos(phi) * c12
    i4 = c11 * cos2 + c22 * sin2 + shear
    i6 = c11 * cos2 + c22 * sin2 - shear
    return 0.5 * c * (c11 + c22 + c33 - 3.0) + _fibre(i4, k1, k2) + _fibre(i6, k1, k2)


def work_features(c11, c22, c12, d11, d22, d12):
    """C components and their virtual-strain directions (``Model.work``): nothing to precompute."""
    return c11, c22, c12, d11, d22, d12


def work(features, *, k2, phi):
    """Virtual work of the fibre part (k1 = 1, c = 0), summed over the last axis, and its derivatives.

    For each family i (I_i = C11 cos^2 + C22 sin^2 +/- C12 sin 2 phi, s_i = I_i - 1 > 0):
    ``dW[v] = s_i exp(k2 s_i^2) dI_i[v]``; d/dk2 gives ``s_i^3 exp(.) dI_i[v]``, d/dphi
    ``(1 + 2 k2 s_i^2) exp(.) I_i,phi dI_i[v] + s_i exp(.) dI_i,phi[v]``.
    Returns ``{"k1": (work (k, ...), d_work (k, 2, ...))}``; the matrix part c goes through the AD path.
    """
    c11, c22, c12, d11, d22, d12 = features
    cs, sn = np.cos(phi) ** 2, np.sin(phi) ** 2
    s2, c2 = np.sin(2.0 * phi), np.cos(2.0 * phi)
    base, base_phi = c11 * cs + c22 * sn - 1.0, (c22 - c11) * s2
    dbase, dbase_phi = d11 * cs + d22 * sn, (d22 - d11) * s2
    total = d_k2 = d_phi = 0.0
    for sign in (1.0, -1.0):
        s = base + sign * s2 * c12  # (...)
        s_phi = base_phi + sign * 2.0 * c2 * c12
        ds = dbase + sign * s2 * d12  # (k, ...)
        ds_phi = dbase_phi + sign * 2.0 * c2 * d12
        ex = np.where(s > 0.0, np.exp(k2 * s * s), 0.0)
        g = s * ex
        total = total + g * ds
        d_k2 = d_k2 + (s * s * g) * ds
        d_phi = d_phi + ((1.0 + 2.0 * k2 * s * s) * ex * s_phi) * ds + g * ds_phi
    return {"k1": (total.sum(-1), np.stack([d_k2.sum(-1), d_phi.sum(-1)], axis=1))}


HGO = register(
    Model(
        name="hgo",
        parameter_names=("c", "k1", "k2", "phi"),
        units=("Pa", "Pa", "1", "rad"),
        energy=energy,
        initial_guess={"c": 2e3, "k1": 20e3, "k2": 1.0, "phi": np.deg2rad(40.0)},
        positive=(True, True, True, False),
        linear=(True, True, False, False),
        lower=(0.0, 0.0, 0.0, 0.0),
        upper=(np.inf, np.inf, np.inf, 0.5 * np.pi),
        description="Holzapfel-Gasser-Ogden, two fibre families at +/- phi (tension only)",
        work_features=work_features,
        work=work,
    )
)
