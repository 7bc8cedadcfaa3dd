"""The efficient virtual-work balance (``weighting="efficient"``, issue 24) against the paper's fields and cost.

Simulated seed-paper protocol (``rig_sim.simulate_test``, homogeneous free tube, one stretch 1.1, 8 levels 0-150 mmHg,
300 markers), 0.17 mm marker noise on every step (reference included) and 0.1 % load noise, the generator of
``benchmarks.bench_efficiency``. Eight seeds: the measured RMS ratio efficient / paper is about 0.4 (beta, alpha11)
and 0.55 (alpha22) over 40 seeds (docs/validation/efficiency.md); the assertion asks for 0.75, a margin that eight
seeds keep (the RMS of eight errors is uncertain by about 25 %).
"""

import numpy as np
import pytest

from identification import MeasurementNoise
from identification.optimize import identify as fit_stated
from identification.efficient import whitening_matrix
from rig_sim.mechanics import PAPER_PARAMETERS, simulate_test

NAMES = ("beta", "alpha11", "alpha22")
H = 1.3e-3


def simulate_case(model, **_):
    """The free homogeneous tube of ``benchmarks.bench_efficiency`` (its layout, seeded 0)."""
    return simulate_test(model, PAPER_PARAMETERS[model], clamped=False, stretches=(1.1,), n_markers=300,
                         marker_margin=0.0, radius=10e-3, thickness=H, length=35e-3)


def noisy_data(sim, sigma, rng):
    """Marker noise on every step (reference included), 0.1 % load noise (floors 3 Pa, 2 mN), as the benchmark."""
    p, f = np.array(sim.pressure), np.array(sim.axial_force)
    sp, sf = MeasurementNoise(sigma).load_sigma(p[1:], f[1:])
    x = sim.exact_positions + sigma * rng.standard_normal(sim.exact_positions.shape)
    p[1:] += sp * rng.standard_normal(sp.shape)
    f[1:] += sf * rng.standard_normal(sf.shape)
    return x, p, f


def _errors(result):
    truth = PAPER_PARAMETERS["fung"]
    return np.array([result.parameters[k] / truth[k] - 1.0 for k in NAMES])


def identify(*args, **kwargs):
    """The fit under stated settings (the membrane wall of these cases, Gauss-Newton errors): what the efficient
    weighting is compared in; ``identification.identify`` adds the judgement of the settings not given."""
    return fit_stated(*args, wall=kwargs.pop("wall", "membrane"), **kwargs)


@pytest.fixture(scope="module")
def fung_errors():
    sim = simulate_case("fung", wall="membrane", ends="free", stretches=(1.1,))
    paper, efficient = [], []
    for seed in range(8):
        x, p, f = noisy_data(sim, 0.17e-3, np.random.default_rng([20261127, seed]))
        paper.append(_errors(identify(x, p, f, thickness=H, model="fung", ends="free", smoothing="auto")))
        efficient.append(_errors(identify(x, p, f, thickness=H, model="fung", ends="free", smoothing="auto",
                                          weighting="efficient")))
    return np.array(paper), np.array(efficient)


def test_efficient_weighting_beats_the_papers_fields_at_the_paper_noise(fung_errors):
    paper, efficient = fung_errors
    rms_paper = np.sqrt(np.mean(paper**2, axis=0))
    rms_efficient = np.sqrt(np.mean(efficient**2, axis=0))
    assert np.all(rms_efficient < 0.75 * rms_paper), (rms_efficient, rms_paper)


def test_efficient_weighting_keeps_exact_data_exact():
    sim = simulate_case("fung", wall="membrane", ends="free", stretches=(1.1,))
    res = identify(np.array(sim.exact_positions), np.array(sim.pressure), np.array(sim.axial_force), thickness=H,
                   model="fung", ends="free", smoothing="auto", weighting="efficient")
    assert np.all(np.abs(_errors(res)) < 0.01)


def test_whitening_matrix_whitens_and_drops_noiseless_gaps():
    rng = np.random.default_rng(0)
    a = rng.standard_normal((5, 5))
    cov = np.zeros((6, 6))
    cov[1:, 1:] = a @ a.T + 0.1 * np.eye(5)
    W = whitening_matrix(cov)
    assert np.allclose(W @ cov @ W.T, np.diag([0, 1, 1, 1, 1, 1]), atol=1e-8)


def test_efficient_weighting_refuses_what_it_does_not_support():
    sim = simulate_case("fung", wall="membrane", ends="free", stretches=(1.1,))
    args = (np.array(sim.exact_positions), np.array(sim.pressure), np.array(sim.axial_force))
    with pytest.raises(ValueError, match="optimizer"):
        identify(*args, thickness=H, ends="free", weighting="efficient", optimizer="nelder-mead")
    with pytest.raises(ValueError, match="uncertainty"):  # the bootstrap is available to it now; "gls" is its own
        identify(*args, thickness=H, ends="free", weighting="paper", uncertainty="gls")
    with pytest.raises(ValueError, match="weighting"):
        identify(*args, thickness=H, ends="free", weighting="optimal")


def test_the_efficient_fit_has_intervals_from_its_own_covariance():
    """``uncertainty="gls"`` (what "auto" gives the efficient weighting, the default): 95 % intervals from the
    generalised least squares' covariance, in the structure the bootstrap fills; within a factor 2 of the
    bootstrap's with the same whitening (coverage measured in docs/validation/efficiency.md)."""
    sim = simulate_case("fung", wall="membrane", ends="free", stretches=(1.1,))
    x, p, f = noisy_data(sim, 0.17e-3, np.random.default_rng([20261127, 0]))
    gls = identify(x, p, f, thickness=H, model="fung", ends="free", smoothing="auto", weighting="efficient",
                   uncertainty="auto")
    boot = identify(x, p, f, thickness=H, model="fung", ends="free", smoothing="auto", weighting="efficient",
                    uncertainty="bootstrap", uncertainty_options={"n_replicates": 8})
    assert gls.uncertainty.method == "gls" and boot.uncertainty.method == "bootstrap"
    assert gls.parameters == boot.parameters  # the same estimate; only its interval differs
    for n, v in gls.parameters.items():
        lo, hi = gls.uncertainty.interval[n]
        assert lo < v < hi and gls.stderr[n] > 0
    for n in NAMES:  # alpha12 (poorly identifiable on one stretch) is linearised less well
        ratio = np.subtract(*gls.uncertainty.interval[n][::-1]) / np.subtract(*boot.uncertainty.interval[n][::-1])
        assert 0.5 < ratio < 2.0, (n, ratio)
    assert gls.uncertainty.model_error_factor >= 1.0 and gls.uncertainty.replicates.shape == (0, 4)


def test_the_defaults_are_the_efficient_fit_with_its_own_intervals():
    from identification import DEFAULTS
    from identification.defaults import uncertainty_for

    assert (DEFAULTS.weighting, DEFAULTS.uncertainty) == ("efficient", "auto")
    assert uncertainty_for("auto", "efficient") == "gls"
    assert uncertainty_for("auto", "paper") == uncertainty_for("auto", "noise") == "bootstrap"
    assert uncertainty_for("bootstrap", "efficient") == "bootstrap"
    with pytest.raises(ValueError, match="uncertainty"):
        uncertainty_for("jackknife", "efficient")
