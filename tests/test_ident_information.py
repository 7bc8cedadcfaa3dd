"""The Cramér-Rao bound of the homogeneous-tube measurement (issue 24): forward model, bound, ML fit, ``design``.

Reference figures: docs/validation/bound.md and the independent computation it cites (seed paper's protocol,
R = 10 mm, H = 1.3 mm, 300 markers over 35 mm, 8 levels 0-150 mmHg, 0.17 mm, loads 0.1 % of reading).
"""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest
from click.testing import CliRunner

from identification.design import PAPER_TABLE1, DesignSpecimen, design, suggest_steps
from identification.information import TubeExperiment, cramer_rao_bound, geometry_layout, information_matrix
from identification.models import get_model
from identification.tube_fit import fit_tube, simulate_observations
from identification.tube_forward import (
    MeasurementNoise,
    TubeGeometry,
    TubeSteps,
    marker_positions,
    solve_lam_theta,
    tube_loads,
    uniform_markers,
)
from rig_sim.mechanics import PAPER_PARAMETERS, PAPER_PRESSURES, inflate_membrane, inflate_thick
from vfmlab.cli import cli

R, H, L = 10e-3, 1.3e-3, 35e-3


def _experiment(stretches=(1.1,), n=300, sigma=0.17e-3, wall="membrane", noise=None, per="step"):
    theta, z = uniform_markers(n, L)
    steps = TubeSteps.from_blocks([(s, PAPER_PRESSURES) for s in stretches])
    return TubeExperiment(TubeGeometry(R, H, wall=wall), steps, theta, z, noise or MeasurementNoise(sigma), per)


def test_table1_defaults_are_the_simulators():
    assert PAPER_TABLE1 == PAPER_PARAMETERS


@pytest.mark.parametrize("model", ["fung", "delfino", "hgo"])
@pytest.mark.parametrize("wall", ["membrane", "thick"])
def test_forward_model_is_the_simulators_closed_form_tube(model, wall):
    par = PAPER_PARAMETERS[model]
    steps = TubeSteps.from_blocks([(1.1, PAPER_PRESSURES)])
    if wall == "membrane":
        ref = inflate_membrane(model, par, PAPER_PRESSURES, 1.1, radius=R, thickness=H)
        lam = ref.lam_theta
    else:
        ref = inflate_thick(model, par, PAPER_PRESSURES, 1.1, radius=R, thickness=H)
        lam = ref.lam_outer
    lt = solve_lam_theta(model, par, steps, TubeGeometry(R, H, wall=wall))
    np.testing.assert_allclose(lt, lam, rtol=1e-12)
    for reads, expected in (("wall", ref.wall_force), ("total", ref.transducer_force)):
        p, f = tube_loads(model, par, lt, steps.stretch, TubeGeometry(R, H, wall=wall, force_measures=reads,
                                                                      n_quad=24))
        np.testing.assert_allclose(p, PAPER_PRESSURES, rtol=1e-10, atol=1e-8)
        np.testing.assert_allclose(f, expected, rtol=1e-10, atol=1e-12)


# The independent computation's figures (std, % of value). Ours agree within 2 %, except alpha22 with three
# stretches (3.4 %); 5 % is the tolerance the issue asks for.
REFERENCE = [
    ("fung", (1.1,), {"beta": 2.75, "alpha11": 1.24, "alpha22": 2.92, "alpha12": 72.0}),
    ("delfino", (1.1,), {"beta": 1.61, "alpha": 0.51}),
    ("hgo", (1.1,), {"c": 14.5, "k1": 2.26, "k2": 1.28, "phi": 0.13}),
    ("fung", (1.05, 1.1, 1.15), {"beta": 1.04, "alpha11": 0.63, "alpha22": 0.89, "alpha12": 22.0}),
]


@pytest.mark.parametrize("model,stretches,expected", REFERENCE)
def test_bound_agrees_with_the_independent_computation(model, stretches, expected):
    b = cramer_rao_bound(model, PAPER_PARAMETERS[model], _experiment(stretches))
    assert not b.singular and b.warning == ""
    for p, ref in expected.items():
        assert b.std_percent[p] == pytest.approx(ref, rel=0.05), p
    assert b.half_width_percent()["beta" if "beta" in expected else "c"] == pytest.approx(
        1.96 * b.std_percent["beta" if "beta" in expected else "c"], rel=1e-3)


def test_bound_lower_noise_and_per_block_stretch():
    """0.05 mm and one stretch unknown per block, as the independent computation (within 3 %)."""
    fung = PAPER_PARAMETERS["fung"]
    b = cramer_rao_bound("fung", fung, _experiment(sigma=0.05e-3))
    assert [b.std_percent[p] for p in ("beta", "alpha11", "alpha22")] == pytest.approx([0.88, 0.40, 0.97], rel=0.03)
    b = cramer_rao_bound("fung", fung, _experiment(per="block"))
    assert [b.std_percent[p] for p in ("beta", "alpha22")] == pytest.approx([2.35, 2.50], rel=0.03)


def _dense_bound(model, params, experiment):
    """Brute force: every unknown (markers' too) in one vector, the whole Jacobian by central differences."""
    model = get_model(model)
    geo, steps, idx = experiment.geometry, experiment.steps, experiment.stretch_index
    n_p, k, m, n = len(model.parameter_names), steps.n_steps, idx.max() + 1, experiment.theta.size
    lt = solve_lam_theta(model, params, steps, geo)
    lz_u = np.array([steps.stretch[idx == j][0] for j in range(m)])
    x0 = np.concatenate([[params[p] for p in model.parameter_names], [geo.radius], lt, lz_u, np.zeros(5),
                         experiment.theta, experiment.Z])
    p0, f0 = tube_loads(model, params, lt, steps.stretch, geo)
    sp, sf = experiment.noise.load_sigma(p0, f0)

    def obs(x):
        par = dict(zip(model.parameter_names, x[:n_p]))
        radius, lt_, lz_ = x[n_p], x[n_p + 1:n_p + 1 + k], x[n_p + 1 + k:n_p + 1 + k + m][idx]
        axis = x[n_p + 1 + k + m:n_p + 6 + k + m]
        th, z = x[-2 * n:-n], x[-n:]
        pos = marker_positions(radius, lt_, lz_, th, z, axis)
        p, f = tube_loads(model, par, lt_, lz_, geo, radius=radius)
        return np.concatenate([pos.ravel() / experiment.noise.marker_sigma, p / sp, f / sf])

    scale = np.concatenate([np.abs(x0[:n_p]), np.full(x0.size - n_p, 1.0)])
    scale[n_p] = geo.radius
    jac = np.empty((obs(x0).size, x0.size))
    for j in range(x0.size):
        h = 1e-6 * scale[j]
        e = np.zeros_like(x0)
        e[j] = h
        jac[:, j] = (obs(x0 + e) - obs(x0 - e)) / (2 * h)
    d = scale
    scaled = (jac * d).T @ (jac * d)
    cov = np.linalg.inv(scaled) * np.outer(d, d)
    return cov[:n_p, :n_p]


@pytest.mark.parametrize("per", ["step", "block"])
def test_per_marker_schur_equals_the_dense_jacobian(per):
    theta, z = uniform_markers(15, L)
    steps = TubeSteps.from_blocks([(1.1, [0.0, 8e3, 16e3]), (1.2, [0.0, 12e3])])
    experiment = TubeExperiment(TubeGeometry(R, H), steps, theta, z, MeasurementNoise(0.1e-3), per)
    fung = PAPER_PARAMETERS["fung"]
    bound = cramer_rao_bound("fung", fung, experiment)
    dense = _dense_bound("fung", fung, experiment)
    np.testing.assert_allclose(bound.covariance, dense, rtol=1e-5)
    info, names = information_matrix("fung", fung, experiment)
    assert names[4:] == geometry_layout(experiment) and info.shape == (len(names), len(names))


def test_exact_loads_make_the_information_singular(caplog):
    exact = MeasurementNoise(0.17e-3, load_relative=0.0, pressure_floor=0.0, force_floor=0.0)
    with caplog.at_level(logging.WARNING, logger="identification.information"):
        b = cramer_rao_bound("fung", PAPER_PARAMETERS["fung"], _experiment(noise=exact))
    assert b.singular and b.condition > 1e12
    assert "singular" in b.warning and "exact loads" in b.warning
    assert any("singular" in r.getMessage() for r in caplog.records)
    noisy = cramer_rao_bound("fung", PAPER_PARAMETERS["fung"], _experiment())
    assert not noisy.singular and noisy.condition < 1e10


def test_maximum_likelihood_scatter_reaches_the_bound():
    """30 seeds at 0.05 mm, the project's forward model, every unknown fitted (markers profiled exactly).

    With 30 seeds the sample RMS of a parameter is uncertain by about 1/sqrt(2 x 30) = 13 % (one sigma), and the bound is
    asymptotic (the estimator is nonlinear): RMS / bound within [0.65, 1.35] is 2.7 sigma wide.
    (benchmarks/bench_bound.py: 100 seeds at 0.17 mm, truth from the simulator.)
    """
    fung = PAPER_PARAMETERS["fung"]
    experiment = _experiment(sigma=0.05e-3)
    bound = cramer_rao_bound("fung", fung, experiment)
    rng = np.random.default_rng(24)
    names = ("beta", "alpha11", "alpha22", "alpha12")
    errors = []
    for _ in range(30):
        obs = simulate_observations("fung", fung, experiment, rng, axis=(2e-4, -1e-4, 0.01, -0.02, 1e-3))
        fit = fit_tube("fung", obs, experiment, start=fung)
        assert fit.success
        errors.append([100.0 * (fit.parameters[p] / fung[p] - 1.0) for p in names])
    rms = np.sqrt(np.mean(np.square(errors), axis=0))
    ratio = rms / np.array([bound.std_percent[p] for p in names])
    assert np.all((ratio > 0.65) & (ratio < 1.35)), dict(zip(names, ratio.round(2)))


def test_fit_from_the_generic_guess_finds_the_same_minimum():
    fung = PAPER_PARAMETERS["fung"]
    experiment = _experiment(n=100)
    obs = simulate_observations("fung", fung, experiment, np.random.default_rng(3))
    a, b = fit_tube("fung", obs, experiment, start=fung), fit_tube("fung", obs, experiment)
    assert a.success and b.success and b.cost == pytest.approx(a.cost, rel=1e-9)
    for p in fung:
        assert b.parameters[p] == pytest.approx(a.parameters[p], rel=1e-5)
    r_bound = cramer_rao_bound("fung", fung, experiment).nuisance_std["R"]
    assert abs(a.nuisances["R"] - R) < 4.0 * r_bound


def test_design_and_suggestions():
    spec = DesignSpecimen(R, H, L)
    d = design([(1.1, PAPER_PRESSURES)], spec, "fung")
    assert d.half_width["alpha22"] == pytest.approx(1.96 * d.bound.std_percent["alpha22"], rel=1e-3)
    before, suggestions = suggest_steps([(1.1, PAPER_PRESSURES)], spec, "fung")
    assert before.half_width == d.half_width
    labels = [s.label for s in suggestions]
    assert "a second stretch at 1.15" in labels and "1200 markers instead of 300" in labels
    second = suggestions[labels.index("a second stretch at 1.15")]
    assert second.half_width["alpha22"] < 0.6 * before.half_width["alpha22"]
    assert suggestions[0].score == min(s.score for s in suggestions)
    _, targeted = suggest_steps([(1.1, PAPER_PRESSURES)], spec, "fung", target={"alpha22": 4.0})
    reach = [s for s in targeted if s.half_width["alpha22"] <= 4.0]
    assert targeted[0] is reach[0] and targeted[0].n_added_steps == min(s.n_added_steps for s in reach)
    with pytest.raises(ValueError, match="target names parameters"):
        suggest_steps([(1.1, PAPER_PRESSURES)], spec, "fung", target={"gamma": 4.0})


def test_design_cli_table_and_json():
    args = ["design", "examples/paper-protocol.toml", "--specimen", "examples/specimen.toml"]
    out = CliRunner().invoke(cli, args)
    assert out.exit_code == 0, out.output
    assert "95 % half-width" in out.output and "kPa" in out.output and " %" in out.output
    assert "Best addition:" in out.output and "→" in out.output
    js = CliRunner().invoke(cli, args + ["--json", "--model", "delfino", "--params", "beta=2000"])
    assert js.exit_code == 0, js.output
    report = json.loads(js.output)
    assert report["parameters"] == {"beta": 2000.0, "alpha": 4.6} and report["units"]["beta"] == "Pa"
    pressures = [b["pressures_Pa"] for b in report["blocks"]]
    assert report["reference_repeats"] == 4  # as the shipped protocol says
    d = design([(1.1, pressures[0])], DesignSpecimen(R, H, L), "delfino", {"beta": 2000.0, "alpha": 4.6},
               noise=MeasurementNoise(0.17e-3, reference_repeats=4))
    assert report["half_width_95_percent"] == pytest.approx(d.half_width, rel=1e-9)
    assert set(report["suggestions"][0]) >= {"label", "added_blocks", "half_width_95_percent", "n_added_steps"}
    bad = CliRunner().invoke(cli, args + ["--params", "beta=abc"])
    assert bad.exit_code == 2 and "--params" in bad.output
