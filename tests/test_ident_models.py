"""Constitutive models: complex-step stresses against closed forms, zero stress at identity."""

import numpy as np
import pytest

from identification.models import available_models, cauchy_stress, get_model, pk2_stress, strain_energy
from rig_sim.homogeneous_tube import PAPER


def _random_C(n, seed=0):
    rng = np.random.default_rng(seed)
    F = np.eye(2) + rng.uniform(-0.2, 0.4, (n, 2, 2)) * np.array([[1, 0.3], [0.3, 1]])
    return np.swapaxes(F, -1, -2) @ F


def _analytic(model, C, p):
    c33 = 1.0 / np.linalg.det(C)
    Cinv = np.linalg.inv(C)
    iso = np.eye(2) - c33[:, None, None] * Cinv
    I1 = C[:, 0, 0] + C[:, 1, 1] + c33
    if model == "fung":
        E = 0.5 * (C - np.eye(2))
        Q = p["alpha11"] * E[:, 0, 0] ** 2 + p["alpha22"] * E[:, 1, 1] ** 2 + p["alpha12"] * E[:, 0, 0] * E[:, 1, 1]
        S = np.zeros_like(C)
        S[:, 0, 0] = 0.5 * p["beta"] * np.exp(Q) * (2 * p["alpha11"] * E[:, 0, 0] + p["alpha12"] * E[:, 1, 1])
        S[:, 1, 1] = 0.5 * p["beta"] * np.exp(Q) * (2 * p["alpha22"] * E[:, 1, 1] + p["alpha12"] * E[:, 0, 0])
        return S
    if model == "delfino":
        return (p["beta"] * p["alpha"] * np.exp(p["alpha"] * (I1 - 3)))[:, None, None] * iso
    if model == "neohookean":
        return p["mu"] * iso
    if model == "hgo":
        S = p["c"] * iso
        for sign in (1, -1):
            a = np.array([np.cos(p["phi"]), sign * np.sin(p["phi"])])
            I4 = np.einsum("i,nij,j->n", a, C, a)
            g = np.where(I4 > 1, 2 * p["k1"] * (I4 - 1) * np.exp(p["k2"] * (I4 - 1) ** 2), 0.0)
            S = S + g[:, None, None] * np.outer(a, a)
        return S
    raise AssertionError(model)


@pytest.mark.parametrize("model", ["fung", "delfino", "hgo", "neohookean"])
def test_automatic_stress_matches_closed_form(model):
    C = _random_C(200)
    S = pk2_stress(model, C, PAPER[model])
    ref = _analytic(model, C, PAPER[model])
    assert np.allclose(S, ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())
    assert np.allclose(S, np.swapaxes(S, -1, -2))


@pytest.mark.parametrize("model", ["fung", "delfino", "hgo", "neohookean"])
def test_zero_stress_and_energy_at_identity(model):
    I = np.broadcast_to(np.eye(2), (3, 2, 2))
    assert np.abs(pk2_stress(model, I, PAPER[model])).max() < 1e-9
    assert np.abs(strain_energy(model, I, PAPER[model])).max() < 1e-12


@pytest.mark.parametrize("model", ["fung", "delfino", "hgo", "neohookean"])
def test_agrees_with_independent_simulator_laws(model):
    """rig_sim implements the same laws independently (stretch form); Cauchy stresses must agree."""
    from rig_sim.mechanics import membrane_cauchy

    lt, lz = np.meshgrid(np.linspace(0.9, 1.5, 7), np.linspace(0.95, 1.3, 5))
    F = np.zeros(lt.shape + (2, 2))
    F[..., 0, 0], F[..., 1, 1] = lt, lz
    sig = cauchy_stress(model, F, PAPER[model])
    s1, s2 = membrane_cauchy(model, PAPER[model], lt, lz)
    scale = max(np.abs(s1).max(), np.abs(s2).max())
    assert np.allclose(sig[..., 0, 0], s1, rtol=1e-9, atol=1e-9 * scale)
    assert np.allclose(sig[..., 1, 1], s2, rtol=1e-9, atol=1e-9 * scale)


def test_registry_and_parameter_validation():
    assert available_models() == ["delfino", "fung", "hgo", "neohookean"]
    with pytest.raises(ValueError, match="model must be one of"):
        get_model("ogden")
    with pytest.raises(ValueError, match="missing \\['alpha12'\\]"):
        pk2_stress("fung", np.eye(2), {"beta": 1.0, "alpha11": 1.0, "alpha22": 1.0})
