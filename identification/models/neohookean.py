"""Incompressible neo-Hookean membrane (baseline).

    W = mu / 2 (I1 - 3),   I1 = C11 + C22 + C33,   C33 = 1 / det of the in-plane C

Parameter: mu [Pa].
"""

from __future__ import annotations

from ._base import Model, register

__all__ = ["NEOHOOKEAN"]


def energy(c11, c22, c12, c33, *, mu):
    return 0.5 * mu * (c11 + c22 + c33 - 3.0)


NEOHOOKEAN = register(
    Model(
        name="neohookean",
        parameter_names=("mu",),
        units=("Pa",),
        energy=energy,
        initial_guess={"mu": 10e3},
        positive=(True,),
        linear=(True,),
        description="neo-Hookean (isotropic baseline)",
    )
)
