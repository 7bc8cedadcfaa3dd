"""Captures of the reference averaged into one (issue 24, ``[reference] repeats``): the averaging, the noise the
efficient path is told, the library keyword against the stage path, and the bound with repeats.

Simulated data as ``benchmarks.bench_reference_repeats`` (free homogeneous Fung tube, one stretch 1.1, 300 markers,
0.17 mm on every capture, each capture of the reference with its own noise). Over 100 seeds the efficient path's
alpha22 RMS falls from 4.3 % to 2.6 % with 4 captures (docs/validation/efficiency.md "Capturing the reference several
times"); on the 8 seeds here from 5.1 % to 1.9 %: the test asks for a ratio below 0.8.
"""

import numpy as np
import pytest

from acquisition.session import SessionWriter, SpecimenInfo, StepRecord, write_result
from benchmarks.bench_reference_repeats import repeated_data
from identification import EfficientSettings, MeasurementNoise, identify
from identification.design import DesignSpecimen, suggest_steps
from identification.information import TubeExperiment, cramer_rao_bound
from identification.optimize import identify as fit_stated
from identification.optimize import with_reference_sigma
from identification.reference_repeats import average_reference, averaged_marker_sigma, input_steps
from identification.tube_forward import TubeGeometry, TubeSteps, uniform_markers
from rig_sim.mechanics import PAPER_PARAMETERS, PAPER_PRESSURES, simulate_test
from vfmlab.pipeline import identify_stored

H, SIGMA = 1.3e-3, 0.17e-3
FUNG = PAPER_PARAMETERS["fung"]


@pytest.fixture(scope="module")
def sim():
    return simulate_test("fung", FUNG, clamped=False, stretches=(1.1,), n_markers=300, marker_margin=0.0,
                         radius=10e-3, thickness=H, length=35e-3)


def test_average_reference_per_marker_over_the_captures_where_seen():
    x = np.arange(5 * 4 * 3, dtype=float).reshape(5, 4, 3)  # 3 captures of the reference, 2 loaded steps
    x[1, 1] = np.nan  # marker 1 missed by capture 1
    x[0, 2] = x[2, 2] = np.nan  # marker 2 seen only by capture 1
    x[:3, 3] = np.nan  # marker 3 never seen at the reference
    avg, n_seen = average_reference(x, 3)
    assert avg.shape == (3, 4, 3) and n_seen.tolist() == [3, 2, 1, 0]
    np.testing.assert_array_equal(avg[0, 0], (x[0, 0] + x[1, 0] + x[2, 0]) / 3)
    np.testing.assert_array_equal(avg[0, 1], (x[0, 1] + x[2, 1]) / 2)
    np.testing.assert_array_equal(avg[0, 2], x[1, 2])
    assert np.isnan(avg[0, 3]).all()
    np.testing.assert_array_equal(avg[1:], x[3:])
    np.testing.assert_array_equal(average_reference(x, 1)[0], x)
    assert input_steps((0, 1, 2), 3) == (0, 3, 4)
    sigma = np.array([[1.0, 2.0], [1.0, np.nan], [1.0, 2.0], [5.0, 5.0]])
    np.testing.assert_allclose(averaged_marker_sigma(sigma, 3), [[np.sqrt(3) / 3, np.sqrt(8) / 2], [5.0, 5.0]])
    for bad in (0, 5, 2.0, True):
        with pytest.raises(ValueError, match="reference_repeats"):
            average_reference(x, bad)


def test_identical_captures_give_the_single_reference_fit(sim):
    x, p, f = repeated_data(sim, SIGMA, 1, np.random.default_rng(1), np.random.default_rng(2))
    x3, p3, f3 = np.concatenate([x[:1]] * 3 + [x[1:]]), np.r_[p[:1], p[:1], p], np.r_[f[:1], f[:1], f]
    # the paper's cost: the efficient weighting would (rightly) take three captures for a less noisy reference
    one = identify(x, p, f, thickness=H, wall="membrane", ends="free", uncertainty="gauss-newton", judged=False,
                   weighting="paper")
    three = identify(x3, p3, f3, thickness=H, wall="membrane", ends="free", uncertainty="gauss-newton", judged=False,
                     weighting="paper", reference_repeats=3)
    for k in FUNG:
        assert three.parameters[k] == pytest.approx(one.parameters[k], rel=1e-9)
    assert three.steps == (0,) + tuple(range(3, x3.shape[0]))


def test_efficient_path_is_told_the_averaged_reference_noise(sim):
    x, p, f = repeated_data(sim, SIGMA, 4, np.random.default_rng(1), np.random.default_rng(2))
    xa, n_seen = average_reference(x, 4)
    first = fit_stated(xa, p[3:], f[3:], thickness=H, model="fung", wall="membrane", ends="free", smoothing="auto")
    sigma = with_reference_sigma(EfficientSettings(), first.data, xa, n_seen).marker_sigma
    assert sigma.shape == xa.shape[:2]
    assert np.median(sigma[1:]) == pytest.approx(SIGMA, rel=0.1)  # the loaded steps' level, not 2/(1+1/4)
    assert np.median(sigma[0]) == pytest.approx(SIGMA / 2, rel=0.1)  # four captures: half the noise
    given = with_reference_sigma(EfficientSettings(marker_sigma=SIGMA), first.data, xa, n_seen).marker_sigma
    np.testing.assert_allclose(given[[0, 1]], [[SIGMA / 2] * 300, [SIGMA] * 300])


def test_four_captures_cut_the_efficient_alpha22_error(sim):
    errors = {1: [], 4: []}
    for seed in range(8):
        for n in (1, 4):
            x, p, f = repeated_data(sim, SIGMA, n, np.random.default_rng([5, seed]), np.random.default_rng([6, seed]))
            r = identify(x, p, f, thickness=H, wall="membrane", ends="free", weighting="efficient",
                         uncertainty="gauss-newton", judged=False, reference_repeats=n)
            errors[n].append(r.parameters["alpha22"] / FUNG["alpha22"] - 1.0)
    rms = {n: float(np.sqrt(np.mean(np.square(e)))) for n, e in errors.items()}
    assert rms[4] < 0.8 * rms[1], rms


def test_library_keyword_equals_the_stage_path(sim, tmp_path):
    x, p, f = repeated_data(sim, SIGMA, 3, np.random.default_rng(7), np.random.default_rng(8))
    protocol = "[test]\nstretches = [1.1]\npressures_mmHg = [0, 150]\n[reference]\ncapture = true\nrepeats = 3\n"
    path = tmp_path / "s.h5"
    with SessionWriter.create(path, SpecimenInfo("s1", 10e-3, 35e-3, H), protocol_text=protocol) as w:
        for k in range(x.shape[0]):
            w.add_step(StepRecord(block=int(k >= 3), stretch=1.0 if k < 3 else 1.1, target_pressure=float(p[k]),
                                  pressure=float(p[k]), force=float(f[k]), t_monotonic=float(k), t_wall=1.7e9 + k),
                       images={})
    write_result(path, "markers", {"positions": x, "step_index": np.arange(x.shape[0])}, {"source": "test"},
                 units={"positions": "m"})
    group, stored, data = identify_stored(path, model="fung", wall="membrane", ends="free",
                                          uncertainty="gauss-newton", check=False)
    assert data["reference_repeats"] == 3 and any("captured 3 times" in n for n in data["notes"])
    lib = identify(x, p, f, thickness=H, wall="membrane", ends="free", uncertainty="gauss-newton", judged=False,
                   reference_repeats=3)
    assert stored.parameters == lib.parameters
    assert stored.steps == lib.steps == (0,) + tuple(range(3, x.shape[0]))


def _experiment(repeats: int, n: int = 120) -> TubeExperiment:
    theta, z = uniform_markers(n, 35e-3)
    return TubeExperiment(TubeGeometry(10e-3, H), TubeSteps.from_blocks([(1.1, PAPER_PRESSURES)]), theta, z,
                          MeasurementNoise(SIGMA, reference_repeats=repeats))


def test_bound_with_repeats_lies_below_the_bound_without():
    one = cramer_rao_bound("fung", FUNG, _experiment(1))
    plain = cramer_rao_bound("fung", FUNG, TubeExperiment(**{**_experiment(1).__dict__,
                                                              "noise": MeasurementNoise(SIGMA)}))
    assert one.std == plain.std  # repeats = 1: the figures as before, bit for bit
    four = cramer_rao_bound("fung", FUNG, _experiment(4))
    for k in FUNG:
        assert four.std[k] < 0.99 * one.std[k], k
    with pytest.raises(ValueError, match="reference_repeats"):
        MeasurementNoise(SIGMA, reference_repeats=0)


def test_design_suggests_capturing_the_reference():
    spec = DesignSpecimen(10e-3, H, 35e-3)
    before, suggestions = suggest_steps([(1.1, PAPER_PRESSURES)], spec, "fung", n_markers=120)
    ref = [s for s in suggestions if s.reference_repeats == 4]
    assert len(ref) == 1 and ref[0].n_added_steps == 3 and "capture the reference 4 times" in ref[0].label
    assert all(ref[0].half_width[k] < before.half_width[k] for k in FUNG)
    _, none = suggest_steps([(1.1, PAPER_PRESSURES)], spec, "fung", n_markers=120,
                            noise=MeasurementNoise(SIGMA, reference_repeats=4))
    assert not [s for s in none if "reference" in s.label]
