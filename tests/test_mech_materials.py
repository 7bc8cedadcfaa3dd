"""rig_sim.materials: closed-form membrane stresses of the four laws."""

import math

import numpy as np
import pytest

from rig_sim.materials import (
    MODELS,
    PAPER_PARAMETERS,
    ModelError,
    membrane_cauchy,
    membrane_pk2,
    strain_energy,
)


def _stretches(seed=0, n=50):
    rng = np.random.default_rng(seed)
    return rng.uniform(0.9, 1.45, n), rng.uniform(0.95, 1.35, n)


@pytest.mark.parametrize("model", sorted(MODELS))
def test_zero_stress_at_identity(model):
    s1, s2 = membrane_cauchy(model, PAPER_PARAMETERS[model], 1.0, 1.0)
    assert s1 == 0.0 and s2 == 0.0
    assert strain_energy(model, PAPER_PARAMETERS[model], 1.0, 1.0) == 0.0


@pytest.mark.parametrize("model", sorted(MODELS))
def test_stress_is_derivative_of_energy(model):
    """sigma_i = lam_i dW_hat/dlam_i (incompressible plane stress), checked by complex-step differentiation."""
    law = MODELS[model]
    par = PAPER_PARAMETERS[model]
    l1, l2 = _stretches()
    if model == "hgo":  # keep away from the fibre switch I4 = 1 where W is only C1
        i4 = l1**2 * math.cos(par["phi"]) ** 2 + l2**2 * math.sin(par["phi"]) ** 2
        keep = np.abs(i4 - 1) > 1e-3
        l1, l2 = l1[keep], l2[keep]
    h = 1e-30
    d1 = np.imag(law.energy(l1 + 1j * h, l2 + 0j, **par)) / h
    d2 = np.imag(law.energy(l1 + 0j, l2 + 1j * h, **par)) / h
    s1, s2 = membrane_cauchy(model, par, l1, l2)
    scale = np.max(np.abs([s1, s2]))
    np.testing.assert_allclose(s1, l1 * d1, rtol=1e-12, atol=1e-12 * scale)
    np.testing.assert_allclose(s2, l2 * d2, rtol=1e-12, atol=1e-12 * scale)


def test_fung_closed_form_appendix_a():
    """With E22 = 0 the Fung law gives S11 = beta alpha11 E11 exp(alpha11 E11^2) (paper appendix A)."""
    par = PAPER_PARAMETERS["fung"]
    l1 = np.linspace(1.0, 1.4, 9)
    e11 = 0.5 * (l1**2 - 1)
    s11, s22 = membrane_pk2("fung", par, l1, 1.0)
    np.testing.assert_allclose(s11, par["beta"] * par["alpha11"] * e11 * np.exp(par["alpha11"] * e11**2), rtol=1e-13)
    np.testing.assert_allclose(s22, 0.5 * par["beta"] * par["alpha12"] * e11 * np.exp(par["alpha11"] * e11**2),
                               rtol=1e-13)


def test_delfino_equibiaxial_closed_form():
    par = PAPER_PARAMETERS["delfino"]
    lam = 1.2
    i1 = 2 * lam**2 + lam**-4
    expect = par["beta"] * par["alpha"] * math.exp(par["alpha"] * (i1 - 3)) * (lam**2 - lam**-4)
    s1, s2 = membrane_cauchy("delfino", par, lam, lam)
    assert s1 == pytest.approx(expect, rel=1e-13) and s2 == pytest.approx(expect, rel=1e-13)


def test_hgo_fibres_inactive_in_compression():
    """Where I4 <= 1 the HGO law is exactly neo-Hookean with mu = c; where I4 > 1 the fibres add stress."""
    par = PAPER_PARAMETERS["hgo"]
    c2, s2 = math.cos(par["phi"]) ** 2, math.sin(par["phi"]) ** 2
    l1, l2 = np.meshgrid(np.linspace(0.8, 1.3, 26), np.linspace(0.8, 1.3, 26))
    i4 = l1**2 * c2 + l2**2 * s2
    h1, h2 = membrane_cauchy("hgo", par, l1, l2)
    n1, n2 = membrane_cauchy("neohookean", {"mu": par["c"]}, l1, l2)
    off = i4 <= 1
    assert off.sum() > 50 and (~off).sum() > 50
    np.testing.assert_array_equal(h1[off], n1[off])
    np.testing.assert_array_equal(h2[off], n2[off])
    assert np.all(h1[~off] > n1[~off]) and np.all(h2[~off] > n2[~off])


def test_vectorised_shapes():
    l1 = np.full((3, 4), 1.1)
    s1, s2 = membrane_cauchy("fung", PAPER_PARAMETERS["fung"], l1, 1.05)
    assert s1.shape == (3, 4) and s2.shape == (3, 4)


def test_bad_parameters_named():
    with pytest.raises(ModelError, match="alpha12"):
        membrane_cauchy("fung", {"beta": 1.0, "alpha11": 1.0, "alpha22": 1.0}, 1.1, 1.1)
    with pytest.raises(ModelError, match="model must be one of"):
        membrane_cauchy("ogden", {}, 1.1, 1.1)
