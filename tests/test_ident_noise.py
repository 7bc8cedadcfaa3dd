"""Noise regression at the seed paper's marker accuracy (0.17 mm; issue 10, "Robust at the paper's noise").

Homogeneous closed-form tube (rig_sim/homogeneous_tube.py, independent of rig_sim's mechanics), the paper's protocol:
one axial stretch 1.1, 8 pressure levels 0-150 mmHg, 300 markers. Few fixed seeds, so these are
regression tests of two measured levers, not the statistics (docs/validation/identification.md, "Noise").
"""

import numpy as np
import pytest

from identification.optimize import identify
from identification import identify_noise_weighted
from identification.noise_weights import weighted_data
from identification.vfm import internal_virtual_work, prepare
from rig_sim.homogeneous_tube import E0, PAPER, homogeneous, lam_t_for_pressures

LZ = 1.1
NOISE = 0.17e-3
NAMES = ("beta", "alpha11", "alpha22")


def _paper_protocol():
    ps = np.linspace(0, 20e3, 8)[1:]
    lt = np.concatenate([[1.0], lam_t_for_pressures("fung", PAPER["fung"], ps, LZ)])
    lz = np.concatenate([[1.0], np.full(len(ps), LZ)])
    return homogeneous("fung", PAPER["fung"], lt, lz, n=300, seed=0)


def _errors(result):
    return np.array([result.parameters[k] / PAPER["fung"][k] - 1.0 for k in NAMES])


def test_reference_radius_noise_no_longer_biases_the_hoop_parameter():
    # noise on the reference markers' radius only: its slope noise entered the reference metric
    # (a sigma^2 bias, alpha11 +0.8..+2.3 % in these seeds with the measured reference radius)
    pos, p, f = _paper_protocol()
    radial = pos[0, :, :2] / np.linalg.norm(pos[0, :, :2], axis=1, keepdims=True)
    new, old = [], []
    for seed in range(3):
        noisy = pos.copy()
        noisy[0, :, :2] += np.random.default_rng([seed, 17]).normal(0.0, NOISE, (pos.shape[1], 1)) * radial
        new.append(_errors(identify(noisy, p, f, thickness=E0, model="fung", ends="free", smoothing="auto", wall="membrane")))
        old.append(_errors(identify(noisy, p, f, thickness=E0, model="fung", ends="free", smoothing="auto",
                                    smooth_reference=False, wall="membrane")))
    new, old = np.array(new), np.array(old)
    assert np.abs(new).max() < 0.012, new
    assert abs(new[:, 1].mean()) < 0.006, new
    assert old[:, 1].mean() > 0.01, old  # the bias the default removes (if this fails, the test lost its point)


def test_noise_weighted_gaps_halve_the_error_at_the_paper_noise():
    # seeds 0, 1: the paper's (unweighted) cost is off by up to 20 % (alpha22); weighting each gap by
    # its measured noise brings the RMS error of beta, alpha11, alpha22 from 11 % to 5 %
    pos, p, f = _paper_protocol()
    plain, weighted = [], []
    for seed in range(2):
        noisy = pos + np.random.default_rng([seed, 17]).normal(0.0, NOISE, pos.shape)
        plain.append(_errors(identify(noisy, p, f, thickness=E0, model="fung", ends="free", smoothing="auto",
                                      wall="membrane")))
        r = identify_noise_weighted(noisy, p, f, thickness=E0, model="fung", ends="free", smoothing="auto",
                                    n_weight_replicates=6, wall="membrane")
        weighted.append(_errors(r))
        # what is stored and checked is the paper's balance at the weighted estimate, in joules
        paper = prepare(noisy, p, f, thickness=E0, ends="free", smoothing="auto")
        np.testing.assert_allclose(r.evw, paper.evw, rtol=1e-9)
        np.testing.assert_allclose(r.residuals, (internal_virtual_work(paper, "fung", r.parameters) - paper.evw)
                                   / paper.scale[:, None], rtol=1e-6, atol=1e-12)
    rms_plain = float(np.sqrt(np.mean(np.square(plain))))
    rms_weighted = float(np.sqrt(np.mean(np.square(weighted))))
    assert rms_weighted < 0.07, weighted
    assert rms_weighted < 0.6 * rms_plain, (plain, weighted)


def test_weighting_keeps_the_balance_exact():
    # internal and external work are scaled alike: at the true parameters the weighted gaps stay 0
    pos, p, f = _paper_protocol()
    data = prepare(pos, p, f, thickness=E0, ends="free", smoothing=(1, 1))
    w = np.random.default_rng(0).uniform(0.1, 10.0, data.evw.shape)
    wd = weighted_data(data, w)
    gap = internal_virtual_work(wd, "fung", PAPER["fung"]) - wd.evw
    assert np.abs(gap).max() < 1e-9 * np.abs(wd.evw).max()
    assert np.allclose(wd.evw, data.evw * w)
    with pytest.raises(ValueError, match="weights must be positive"):
        weighted_data(data, -w)
