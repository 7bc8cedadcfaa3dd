"""Matching by likelihood ratio (benchmarks/research/likelihood_matching.py): dense particles rendered through glass and
water into 4 cameras whose calibration is off by a smooth bias of up to ~1 px, as the real data's after the
self-calibration; the score keeps more true matches than the hard gates at no more chance ones."""

import numpy as np

from _window_rig import window_rig
from reconstruction.correspondence import match_views
from benchmarks.research.likelihood_matching import (TrueModel, fit_true_model, likelihood_match, local_density,
                                                log_likelihood_ratio, select_by_score, with_subsets)
from benchmarks.research.temporal_matching import persistence_support

BOUNDS = (np.array([-0.03, -0.03, -0.02]), np.array([0.03, 0.03, 0.02]))
#: per camera: constant bias (px) and its gradient over the image (px per half image), the calibration's error
BIAS = [((0.4, -0.3), (0.3, 0.2)), ((-0.5, 0.2), (-0.2, 0.3)), ((0.2, 0.5), (0.3, -0.3)), ((-0.3, -0.4), (0.2, 0.2))]


def _frame(cams, rng, n=2500, noise=0.15, seen=0.8):
    """``n`` particles in the volume, each seen by each camera with probability ``seen``; detections moved by the
    camera's BIAS and ``noise`` px. Returns the detections per camera and per detection its particle id."""
    X = rng.uniform(*BOUNDS, (n, 3)) * [0.95, 0.95, 0.9]
    dets, ids = [], []
    for c, ((b0, grad), cam) in enumerate(zip(BIAS, cams)):
        keep = rng.permutation(np.flatnonzero(rng.random(n) < seen))
        px = cam.project(X[keep])
        W, H = cam.image_size
        uv = np.c_[2 * px[:, 0] / W - 1, 2 * px[:, 1] / H - 1]
        bias = np.asarray(b0) + uv * np.asarray(grad)
        dets.append(px - bias + rng.normal(0, noise, px.shape))
        ids.append(keep)
    return dets, ids


def _true_and_false(obs, ids):
    """>= 3-view matches whose detections are all of one particle, and the others."""
    pid = np.stack([np.where(obs[:, c] >= 0, ids[c][np.maximum(obs[:, c], 0)], -1) for c in range(obs.shape[1])], 1)
    first = pid.max(axis=1)
    one = np.all((pid == first[:, None]) | (pid < 0), axis=1)
    three = (obs >= 0).sum(axis=1) >= 3
    return int((one & three).sum()), int((~one & three).sum())


def test_likelihood_keeps_more_true_matches_than_hard_gates_at_no_more_false_ones():
    rng = np.random.default_rng(11)
    cams = window_rig()
    train, _ = _frame(cams, rng)
    dets, ids = _frame(cams, rng)
    hard = match_views(dets, cams, epipolar_px=1.5, max_reprojection_px=1.0, max_pair_angle_deg=180.0, bounds=BOUNDS)
    hard_true, hard_false = _true_and_false(hard.observations, ids)
    # the model (bias map, scatter) measured on another frame, then frozen
    model = fit_true_model(train, cams, BOUNDS, threshold=10.0, degree=1, iterations=2)
    assert np.all((model.sigma_px > 0.08) & (model.sigma_px < 0.3)), model.sigma_px
    m = likelihood_match(dets, cams, BOUNDS, model, threshold=14.0)
    true, false = _true_and_false(m.observations, ids)
    # measured: hard gates 1,807 true, 177 false; likelihood 2,021 true, 20 false
    assert true > 1.06 * hard_true, (true, hard_true)
    assert false < 0.3 * hard_false, (false, hard_false)


def test_score_and_greedy_selection_on_hand_made_candidates():
    # a 4-view candidate with moderate residuals beats a 3-view one with small residuals in a crowded region
    res = np.full((4, 2, 2), np.nan)
    res[:, 0] = 0.5  # 4 views, |r| = 0.71 px
    res[:3, 1] = 0.1  # 3 views, |r| = 0.14 px
    rho = np.array([[1 / 350, 1 / 50]] * 4)  # the 3-view one in a 7x denser region
    s = log_likelihood_ratio(res, rho, np.full(4, 0.4))
    assert s[0] > s[1] + 5, s
    r2 = 2 * 0.5**2
    assert abs(s[0] - 4 * (-r2 / (2 * 0.16) - np.log(2 * np.pi * 0.16 / 350))) < 1e-9
    # each detection used once, best first, threshold applied
    obs = np.array([[0, 0, 0, -1], [0, 1, 1, 1], [1, 2, 2, 2], [2, 3, 3, 3]])
    keep = select_by_score(obs, np.array([5.0, 9.0, 7.0, 1.0]), threshold=2.0)
    assert keep.tolist() == [1, 2]
    assert select_by_score(obs[:0], np.zeros(0)).shape == (0,)
    subs = with_subsets(np.array([[4, 5, 6, 7]]), 3)
    assert len(subs) == 5 and np.all((subs >= 0).sum(axis=1) >= 3)
    assert np.allclose(local_density(np.array([[0.0, 0.0], [3.0, 0.0], [100.0, 0.0]]), 10.0),
                       [1 / (np.pi * 100)] * 3)
    assert TrueModel.isotropic(0.3, 4).coefficients.shape == (4, 10, 2)


def test_persistence_support_counts_smooth_moving_triplets_only():
    from benchmarks.research.temporal_matching import FrameCandidates

    def frame(t):
        pts = np.array([[0.0, 0.0, 3e-4 * t], [0.01, 0.0, 0.0], [0.02, 0.0, 3e-4 * t]])  # moving, static, moving
        res = np.zeros((4, 3, 2))
        res[0, 2] = 0.4 * t  # the third one's residual changes by 0.4 px per frame in camera 1
        return FrameCandidates(np.zeros((3, 4), np.int64), pts, np.zeros(3), res)

    sup = persistence_support([frame(t) for t in range(4)], max_step_m=1e-3, max_accel_m=0.1e-3,
                              max_residual_change_px=0.3, min_motion_m=0.2e-3)
    assert [s.tolist() for s in sup] == [[1, 0, 0], [2, 0, 0], [2, 0, 0], [1, 0, 0]]
