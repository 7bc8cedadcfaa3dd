"""Exact derivatives of the identification's hot path: hyper-dual AD, closed forms, batched axis refit."""

import numpy as np
import pytest

from identification import internal_virtual_work, prepare
from identification.kinematics import align_steps
from identification.mesh import build_mesh, fit_axis
from identification.models import get_model
from identification.step_axes import refit_axes
from identification.vfm import virtual_work_basis
from rig_sim.homogeneous_tube import E0, PAPER, homogeneous

# away from the paper values, with an active and an inactive HGO fibre family in some triangles
OTHER = {"fung": {"beta": 3e3, "alpha11": 2.0, "alpha22": 9.0, "alpha12": -1.5},
         "delfino": {"beta": 2e3, "alpha": 2.5},
         "hgo": {"c": 1e3, "k1": 4e3, "k2": 1.5, "phi": 0.9},
         "neohookean": {"mu": 5e4}}


@pytest.fixture(scope="module")
def noisy_data():
    """A tube whose strains vary from triangle to triangle (noise) on two wall forms."""
    lt = np.array([1.0, 1.05, 1.1, 1.15])
    lz = np.array([1.0, 1.1, 1.1, 1.1])
    pos, p, f = homogeneous("fung", PAPER["fung"], lt, lz, n=120)
    pos = pos + np.random.default_rng(4).normal(0.0, 0.05e-3, pos.shape)
    return {wall: prepare(pos, p, f, thickness=E0, ends="free", wall=wall, reject_outliers=False)
            for wall in ("membrane", "thick")}


def _split(model, params):
    m = get_model(model)
    lin = [n for n, flag in zip(m.parameter_names, m.linear) if flag]
    nl = [n for n, flag in zip(m.parameter_names, m.linear) if not flag]
    return lin, nl


@pytest.mark.parametrize("wall", ["membrane", "thick"])
@pytest.mark.parametrize("model", ["fung", "delfino", "hgo", "neohookean"])
@pytest.mark.parametrize("values", ["paper", "other"])
def test_basis_and_derivatives_match_the_stress_path(noisy_data, wall, model, values):
    data = noisy_data[wall]
    params = (PAPER if values == "paper" else OTHER)[model]
    lin, nl = _split(model, params)
    A, dA = virtual_work_basis(data, model, params)
    ivw = internal_virtual_work(data, model, params)
    assert np.allclose(np.tensordot([params[n] for n in lin], A, 1), ivw, rtol=1e-10, atol=1e-12 * np.abs(ivw).max())
    for j, name in enumerate(nl):  # central differences of the plain IVW (truncation ~h^2)
        h = 1e-5 * max(abs(params[name]), 1.0)
        up, down = dict(params, **{name: params[name] + h}), dict(params, **{name: params[name] - h})
        fd = (internal_virtual_work(data, model, up) - internal_virtual_work(data, model, down)) / (2 * h)
        exact = np.tensordot([params[n] for n in lin], dA[:, j], 1)
        assert np.allclose(exact, fd, rtol=1e-5, atol=1e-7 * np.abs(fd).max()), name


@pytest.mark.parametrize("wall", ["membrane", "thick"])
@pytest.mark.parametrize("model", ["fung", "hgo"])
def test_closed_form_work_equals_the_shared_ad(noisy_data, wall, model):
    assert get_model(model).work is not None
    data = noisy_data[wall]
    for params in (PAPER[model], OTHER[model]):
        A1, dA1 = virtual_work_basis(data, model, params, closed_form=True)
        A2, dA2 = virtual_work_basis(data, model, params, closed_form=False)
        assert np.allclose(A1, A2, rtol=1e-12, atol=1e-14 * np.abs(A2).max())
        assert np.allclose(dA1, dA2, rtol=1e-12, atol=1e-14 * np.abs(dA2).max())


@pytest.mark.parametrize("noise", [0.0, 0.1e-3])
def test_batched_axis_refit_equals_fit_axis(noise):
    lt = np.array([1.0, 1.1, 1.2])
    lz = np.array([1.0, 1.05, 1.1])
    pos, _, _ = homogeneous("fung", PAPER["fung"], lt, lz, n=150)
    pos = pos + np.random.default_rng(2).normal(0.0, noise, pos.shape)
    pos[1, :10] = np.nan
    mesh = build_mesh(pos[0])
    aligned, _, _ = align_steps(pos, pos[0])
    observed = np.all(np.isfinite(aligned), axis=-1) & mesh.used
    batched = refit_axes(aligned, observed, mesh.axis)
    for step, axis in zip(aligned, batched):
        ref = fit_axis(step[np.all(np.isfinite(step), axis=1) & mesh.used], initial=mesh.axis)
        assert np.allclose(axis.basis, ref.basis, atol=1e-9)
        assert np.allclose(axis.origin, ref.origin, atol=1e-12)
        assert axis.radius == pytest.approx(ref.radius, rel=1e-8)  # least_squares stops at ftol 1e-12
        assert axis.rms == pytest.approx(ref.rms, rel=1e-6, abs=1e-15)
