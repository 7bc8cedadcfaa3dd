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
    )
)
