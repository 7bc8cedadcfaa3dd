"""Delfino (Demiray) isotropic exponential model (Avril et al. 2010, eq. 2).

    W = beta / 2 * (exp(alpha (I1 - 3)) - 1),   I1 = C11 + C22 + C33

incompressible, plane stress (C33 = 1 / det of the in-plane C). Parameters: beta [Pa], alpha [1].
"""

from __future__ import annotations

import numpy as np

from ._base import Model, register

__all__ = ["DELFINO"]


def energy(c11, c22, c12, c33, *, beta, alpha):
    return 0.5 * beta * (np.exp(alpha * (c11 + c22 + c33 - 3.0)) - 1.0)


DELFINO = register(
    Model(
        name="delfino",
        parameter_names=("beta", "alpha"),
        units=("Pa", "1"),
        energy=energy,
        initial_guess={"beta": 10e3, "alpha": 1.0},
        positive=(True, True),
        linear=(True, False),
        description="Delfino/Demiray isotropic exponential",
    )
)
