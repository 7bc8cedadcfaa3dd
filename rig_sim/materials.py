"""Exact membrane constitutive laws of the artery wall, in principal stretches (ground truth of the simulator).

Written independently of ``identification/`` so that the simulator is an independent check of it.

Conventions
-----------
Direction 1 is circumferential (theta), direction 2 is axial/meridional (z), direction 3 is through the thickness.
The tube is axisymmetric and untwisted, so (1, 2, 3) are principal directions and every quantity is a function of
the in-plane principal stretches ``lam1`` (circumferential) and ``lam2`` (axial) alone; ``lam3 = 1 / (lam1 lam2)``
(incompressibility). Plane stress (sigma_33 = 0) fixes the Lagrange multiplier of the 3-D laws, which gives

    sigma_i = lam_i * dW_hat/dlam_i,   W_hat(lam1, lam2) = W(lam1, lam2, 1 / (lam1 lam2)),   i = 1, 2,

and the second Piola-Kirchhoff stress S_i = sigma_i / lam_i**2 (J = 1). For the 3-D laws (Delfino, HGO, neo-Hookean)
the same closed form is the stress *difference* sigma_i - sigma_33 in a thick wall, which is how ``tube.py`` uses it.

The stress functions accept complex input (complex-step differentiation in ``clamped.py``); fibre activation tests
the real part only. Parameters are SI: stresses in Pa, angles in rad, exponents dimensionless.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Mapping

import numpy as np

__all__ = [
    "MembraneLaw",
    "MODELS",
    "PAPER_PARAMETERS",
    "ModelError",
    "get_law",
    "check_params",
    "membrane_cauchy",
    "membrane_pk2",
    "strain_energy",
]


class ModelError(ValueError):
    """Unknown constitutive model or bad parameter set."""


@dataclass(frozen=True)
class MembraneLaw:
    """One incompressible plane-stress membrane law.

    Attributes
    ----------
    name : str
        Registry key ("fung", "delfino", "hgo", "neohookean").
    parameter_names : tuple of str
        Names of the keyword parameters, in the paper's order (SI).
    cauchy : callable
        ``cauchy(lam1, lam2, **params) -> (sigma11, sigma22)``, Cauchy stresses [Pa], broadcasting.
    energy : callable
        ``energy(lam1, lam2, **params) -> W`` [J/m^3] per unit reference volume, incompressibility built in.
    """

    name: str
    parameter_names: tuple[str, ...]
    cauchy: Callable
    energy: Callable


# --------------------------------------------------------------------------------------------------------------------
# 2-D Fung (paper eq. 3): W = beta/2 (exp(Q) - 1), Q = a11 E11^2 + a22 E22^2 + a12 E11 E22, E Green-Lagrange.
# A 2-D law: S_ii = dW/dE_ii, sigma_ii = lam_i^2 S_ii (J = 1, W independent of E33 so the multiplier vanishes).
# --------------------------------------------------------------------------------------------------------------------
def _fung_q(lam1, lam2, alpha11, alpha22, alpha12):
    e11 = 0.5 * (lam1 * lam1 - 1.0)
    e22 = 0.5 * (lam2 * lam2 - 1.0)
    return e11, e22, alpha11 * e11 * e11 + alpha22 * e22 * e22 + alpha12 * e11 * e22


def _fung_energy(lam1, lam2, *, beta, alpha11, alpha22, alpha12):
    _, _, q = _fung_q(lam1, lam2, alpha11, alpha22, alpha12)
    return 0.5 * beta * (np.exp(q) - 1.0)


def _fung_cauchy(lam1, lam2, *, beta, alpha11, alpha22, alpha12):
    e11, e22, q = _fung_q(lam1, lam2, alpha11, alpha22, alpha12)
    g = 0.5 * beta * np.exp(q)
    s11 = g * (2.0 * alpha11 * e11 + alpha12 * e22)
    s22 = g * (2.0 * alpha22 * e22 + alpha12 * e11)
    return lam1 * lam1 * s11, lam2 * lam2 * s22


# --------------------------------------------------------------------------------------------------------------------
# Delfino / Demiray (paper eq. 2): W = beta/2 (exp(alpha (I1 - 3)) - 1), I1 = lam1^2 + lam2^2 + lam3^2.
# sigma_i = 2 W_1 (lam_i^2 - lam3^2) with W_1 = beta alpha / 2 exp(alpha (I1 - 3)).
# --------------------------------------------------------------------------------------------------------------------
def _i1(lam1, lam2):
    lam3 = 1.0 / (lam1 * lam2)
    return lam1 * lam1 + lam2 * lam2 + lam3 * lam3, lam3 * lam3


def _delfino_energy(lam1, lam2, *, beta, alpha):
    i1, _ = _i1(lam1, lam2)
    return 0.5 * beta * (np.exp(alpha * (i1 - 3.0)) - 1.0)


def _delfino_cauchy(lam1, lam2, *, beta, alpha):
    i1, l33 = _i1(lam1, lam2)
    two_w1 = beta * alpha * np.exp(alpha * (i1 - 3.0))
    return two_w1 * (lam1 * lam1 - l33), two_w1 * (lam2 * lam2 - l33)


# --------------------------------------------------------------------------------------------------------------------
# Holzapfel-Gasser-Ogden (paper eq. 4), two symmetric fibre families at +-phi from the circumferential direction:
#   W = c/2 (I1 - 3) + k1/(2 k2) sum_{i=4,6} [exp(k2 (I_i - 1)^2) - 1],   I4 = I6 = lam1^2 cos^2 phi + lam2^2 sin^2 phi.
# The paper prints c/2 (I1 - 1); that is a typo (the energy must vanish at I1 = 3 and the stress does not depend on the
# constant anyway). Fibres bear load in tension only: their terms are dropped where I4 <= 1.
# sigma_1 = c (lam1^2 - lam3^2) + 4 W4 lam1^2 cos^2 phi,  sigma_2 = c (lam2^2 - lam3^2) + 4 W4 lam2^2 sin^2 phi,
# W4 = k1 (I4 - 1) exp(k2 (I4 - 1)^2)  (the in-plane shear of the two families cancels).
# --------------------------------------------------------------------------------------------------------------------
def _hgo_i4(lam1, lam2, phi):
    c2 = math.cos(phi) ** 2
    s2 = math.sin(phi) ** 2
    return lam1 * lam1 * c2 + lam2 * lam2 * s2, c2, s2


def _hgo_energy(lam1, lam2, *, c, k1, k2, phi):
    i1, _ = _i1(lam1, lam2)
    i4, _, _ = _hgo_i4(lam1, lam2, phi)
    active = np.real(i4) > 1.0
    fibre = np.where(active, k1 / k2 * (np.exp(k2 * (i4 - 1.0) ** 2) - 1.0), 0.0)  # two families
    return 0.5 * c * (i1 - 3.0) + fibre


def _hgo_cauchy(lam1, lam2, *, c, k1, k2, phi):
    _, l33 = _i1(lam1, lam2)
    i4, c2, s2 = _hgo_i4(lam1, lam2, phi)
    active = np.real(i4) > 1.0
    w4 = np.where(active, k1 * (i4 - 1.0) * np.exp(k2 * (i4 - 1.0) ** 2), 0.0)
    s1 = c * (lam1 * lam1 - l33) + 4.0 * w4 * lam1 * lam1 * c2
    s2_ = c * (lam2 * lam2 - l33) + 4.0 * w4 * lam2 * lam2 * s2
    return s1, s2_


# --------------------------------------------------------------------------------------------------------------------
# neo-Hookean: W = mu/2 (I1 - 3); sigma_i = mu (lam_i^2 - lam3^2).
# --------------------------------------------------------------------------------------------------------------------
def _neo_energy(lam1, lam2, *, mu):
    i1, _ = _i1(lam1, lam2)
    return 0.5 * mu * (i1 - 3.0)


def _neo_cauchy(lam1, lam2, *, mu):
    _, l33 = _i1(lam1, lam2)
    return mu * (lam1 * lam1 - l33), mu * (lam2 * lam2 - l33)


MODELS: dict[str, MembraneLaw] = {
    "fung": MembraneLaw("fung", ("beta", "alpha11", "alpha22", "alpha12"), _fung_cauchy, _fung_energy),
    "delfino": MembraneLaw("delfino", ("beta", "alpha"), _delfino_cauchy, _delfino_energy),
    "hgo": MembraneLaw("hgo", ("c", "k1", "k2", "phi"), _hgo_cauchy, _hgo_energy),
    "neohookean": MembraneLaw("neohookean", ("mu",), _neo_cauchy, _neo_energy),
}

#: Table 1 of Avril, Badel & Duprey (2010) in SI. The paper gives no neo-Hookean value; mu = 300 kPa is chosen so that
#: the H/R = 0.13 membrane stays well below its inflation limit point (p_max = mu H / (R lam_z)) at 150 mmHg and
#: lam_z = 1.2 (lam_theta ~ 1.2 there). A mu of ~20 kPa would burst (limit point at ~2.4 kPa = 18 mmHg).
PAPER_PARAMETERS: dict[str, dict[str, float]] = {
    "fung": {"beta": 5.0e3, "alpha11": 14.5, "alpha22": 7.0, "alpha12": 0.1},
    "delfino": {"beta": 1.5e3, "alpha": 4.6},
    "hgo": {"c": 0.4e3, "k1": 8.7e3, "k2": 5.4, "phi": math.radians(27.0)},
    "neohookean": {"mu": 300.0e3},
}


def get_law(model: str) -> MembraneLaw:
    """Return the registered law called ``model`` (one of ``MODELS``)."""
    try:
        return MODELS[model]
    except (KeyError, TypeError):
        raise ModelError(f"model must be one of {sorted(MODELS)}; got {model!r}") from None


def check_params(model: str, params: Mapping[str, float]) -> dict[str, float]:
    """Validate a parameter mapping for ``model`` and return it as a plain dict of floats.

    Raises
    ------
    ModelError
        If a name is missing or unknown, or a value is not finite.
    """
    law = get_law(model)
    names = set(law.parameter_names)
    given = set(params)
    if given != names:
        raise ModelError(
            f"params for model {model!r} must have exactly the keys {list(law.parameter_names)}; "
            f"missing {sorted(names - given)}, unexpected {sorted(given - names)}"
        )
    out = {}
    for k in law.parameter_names:
        v = float(params[k])
        if not math.isfinite(v):
            raise ModelError(f"params[{k!r}] must be finite; got {params[k]!r}")
        out[k] = v
    return out


def membrane_cauchy(model: str, params: Mapping[str, float], lam_theta, lam_z):
    """Cauchy stresses of the incompressible plane-stress membrane.

    Parameters
    ----------
    model : str
        "fung", "delfino", "hgo" or "neohookean".
    params : mapping
        Model parameters in SI (see ``MODELS[model].parameter_names``).
    lam_theta, lam_z : array_like
        Circumferential and axial principal stretches, broadcast together (any shape).

    Returns
    -------
    sigma_tt, sigma_zz : ndarray
        Circumferential and axial Cauchy stress [Pa], broadcast shape.
    """
    law = get_law(model)
    p = check_params(model, params)
    lt = np.asarray(lam_theta)
    lz = np.asarray(lam_z)
    if not np.iscomplexobj(lt):
        lt = lt.astype(float)
    if not np.iscomplexobj(lz):
        lz = lz.astype(float)
    s1, s2 = law.cauchy(lt, lz, **p)
    return np.asarray(s1) + 0.0 * lz, np.asarray(s2) + 0.0 * lt


def membrane_pk2(model: str, params: Mapping[str, float], lam_theta, lam_z):
    """Second Piola-Kirchhoff stresses S11 (circumferential), S22 (axial) [Pa]; ``S_i = sigma_i / lam_i**2``."""
    s1, s2 = membrane_cauchy(model, params, lam_theta, lam_z)
    return s1 / np.asarray(lam_theta) ** 2, s2 / np.asarray(lam_z) ** 2


def strain_energy(model: str, params: Mapping[str, float], lam_theta, lam_z):
    """Strain energy per unit reference volume [J/m^3] with incompressibility built in (W_hat of the module doc)."""
    law = get_law(model)
    p = check_params(model, params)
    return np.asarray(law.energy(np.asarray(lam_theta, dtype=float), np.asarray(lam_z, dtype=float), **p))
