"""2-D Fung model (Avril et al. 2010, eq. 3).

    W = beta / 2 * (exp(Q) - 1),   Q = alpha11 E11^2 + alpha22 E22^2 + alpha12 E11 E22

with E = (C - I) / 2 in the local frame (1 circumferential, 2 axial). A 2-D membrane law: W does not
depend on E33, so the plane-stress multiplier vanishes and S = dW/dE.
Parameters: beta [Pa], alpha11, alpha22, alpha12 [1].
"""

from __future__ import annotations

import numpy as np

from ._base import Model, register

__all__ = ["FUNG"]


def energy(c11, c22, c12, c33, *, beta, alpha11, alpha22, alpha12):
    e11 = 0.5 * (c11 - 1.0)
    e22 = 0.5 * (c22 - 1.0)
    q = alpha11 * e11 * e11 + alpha22 * e22 * e22 + alpha12 * e11 * e22
    return 0.5 * beta * (np.exp(q) - 1.0)


def work_features(c11, c22, c12, d11, d22, d12):
    """Parameter-independent arrays of the closed-form virtual work (``Model.work``).

    C components of shape ``(...)``; ``d..`` the virtual-strain directions of the C components,
    shape ``(k, ...)`` (``_base.seed_virtual_strains``). Returns the features
    phi = (E11^2, E22^2, E11 E22) and their derivatives psi along each direction.
    """
    e11, e22 = 0.5 * (c11 - 1.0), 0.5 * (c22 - 1.0)
    de11, de22 = 0.5 * d11, 0.5 * d22
    phi = np.stack([e11 * e11, e22 * e22, e11 * e22])  # (3, ...)
    psi = np.stack([2.0 * e11 * de11, 2.0 * e22 * de22, de11 * e22 + e11 * de22])  # (3, k, ...)
    return phi, psi


def work(features, *, alpha11, alpha22, alpha12):
    """Virtual work of W with beta = 1, summed over the last axis, and its derivatives by the alphas.

    ``dW[v] = 1/2 exp(Q) dQ[v]`` with ``Q = a . phi``, ``dQ[v] = a . psi``; returns
    ``{"beta": (work (k, ...), d_work (k, 3, ...))}`` (the exact derivative of the AD path).
    """
    phi, psi = features
    a = np.array([alpha11, alpha22, alpha12])
    half_exp = 0.5 * np.exp(a[0] * phi[0] + a[1] * phi[1] + a[2] * phi[2])  # (...)
    weighted = half_exp * (a[0] * psi[0] + a[1] * psi[1] + a[2] * psi[2])  # (k, ...)
    d_work = (np.einsum("j...p,k...p->kj...", phi, weighted)
              + np.einsum("...p,jk...p->kj...", half_exp, psi))
    return {"beta": (weighted.sum(-1), d_work)}


FUNG = register(
    Model(
        name="fung",
        parameter_names=("beta", "alpha11", "alpha22", "alpha12"),
        units=("Pa", "1", "1", "1"),
        energy=energy,
        # The paper's footnote (Fung 1993): beta = 29 kPa, alpha11 = 2.5, alpha22 = 0.5, alpha12 = 0.17.
        initial_guess={"beta": 29e3, "alpha11": 2.5, "alpha22": 0.5, "alpha12": 0.17},
        positive=(True, True, True, False),
        linear=(True, False, False, False),
        lower=(0.0, 0.0, 0.0, -50.0),
        upper=(np.inf, np.inf, np.inf, 50.0),
        description="2-D Fung exponential (anisotropic)",
        work_features=work_features,
        work=work,
    )
)
