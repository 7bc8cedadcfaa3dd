"""Correspondence of unlabelled markers across a ring of cameras (synthetic projections)."""

import numpy as np
import pytest

from _recon_synth import camera_ring, projected_series
from reconstruction.correspondence import CylinderPrior, match_views


@pytest.fixture(scope="module")
def cams():
    return camera_ring(6)


def _labels(res, ids):
    """Truth marker id per reconstructed point; -2 if its views disagree or include a fake."""
    out = []
    for o in res.observations:
        lab = {int(ids[c][o[c]]) for c in range(len(o)) if o[c] >= 0}
        out.append(lab.pop() if len(lab) == 1 and min(lab) >= 0 else -2)
    return np.array(out)


def test_all_markers_matched_consistently(cams):
    dets, ids, C, _, V = projected_series(cams, n_steps=1, n_fake=10, seed=4)
    prior = CylinderPrior(radius=4.2e-3, tolerance=1e-3, half_length=10e-3)
    res = match_views(dets[0], cams, prior=prior)
    lab = _labels(res, ids[0])
    seen = V[0].sum(axis=0) >= 2
    assert np.all(lab >= 0), "a point mixes detections of different markers or a fake"
    assert len(set(lab)) == len(lab) == seen.sum()
    err = np.linalg.norm(res.points - C[0][lab], axis=1)
    assert np.sqrt(np.mean(err**2)) < 2e-6  # 0.03 px noise at ~50 px/mm
    # every detection used at most once, fakes unused
    for c in range(6):
        used = res.observations[:, c][res.observations[:, c] >= 0]
        assert len(used) == len(set(used))
        assert np.all(ids[0][c][res.unmatched[c]] < 0) or np.all(~V[0][:, ids[0][c][res.unmatched[c]][ids[0][c][res.unmatched[c]] >= 0]].sum(0) >= 2)
    # each point uses all the views it is seen in
    np.testing.assert_array_equal(res.triangulation.n_views, V[0].sum(axis=0)[lab])


def test_missing_camera_and_occlusions(cams):
    def hide(k, vis):
        vis[3] = False  # camera 3 delivered no image
        vis[1, ::7] = False  # some markers occluded in camera 1
        return vis

    dets, ids, C, _, V = projected_series(cams, n_steps=1, n_fake=10, seed=5, hide=hide)
    prior = CylinderPrior(radius=4.2e-3, tolerance=1e-3, half_length=10e-3)
    res = match_views(dets[0], cams, prior=prior)
    lab = _labels(res, ids[0])
    seen = V[0].sum(axis=0) >= 2
    assert np.all(lab >= 0) and len(set(lab)) == len(lab)
    assert len(lab) >= 0.99 * seen.sum()
    assert len(dets[0][3]) == 10  # only fakes in the missing camera; none of them used
    assert np.all(res.observations[:, 3] < 0)


def test_without_prior_three_view_points_are_right(cams):
    """With no specimen prior (the bootstrap before a cylinder is known), every marker seen in >= 3
    views is found; the few chance 3-view ghosts betray themselves by their reprojection error."""
    dets, ids, C, _, V = projected_series(cams, n_steps=1, n_fake=0, seed=6)
    res = match_views(dets[0], cams, min_views=3)
    lab = _labels(res, ids[0])
    clean = res.triangulation.reprojection_rms < 0.2  # 0.03 px noise
    assert np.all(lab[clean] >= 0) and len(set(lab[clean])) == clean.sum()
    assert clean.sum() >= 0.97 * (V[0].sum(axis=0) >= 3).sum()
    assert (~clean).sum() <= 0.05 * len(lab)


def test_validation(cams):
    with pytest.raises(ValueError, match="one array per camera"):
        match_views([np.zeros((0, 2))] * 5, cams)
    with pytest.raises(ValueError, match="min_views"):
        match_views([np.zeros((0, 2))] * 6, cams, min_views=1)
    with pytest.raises(ValueError, match="radius and tolerance"):
        CylinderPrior(radius=-1.0, tolerance=1e-3)
    res = match_views([np.zeros((0, 2))] * 6, cams)
    assert res.observations.shape == (0, 6) and res.points.shape == (0, 3)


def test_bootstrap_without_three_view_markers_keeps_the_loose_prior(cams):
    """Two cameras cannot see a marker three times: the specimen prior stays the one given (no
    empty-array statistics, which would warn and fail under filterwarnings=error)."""
    from reconstruction import ReconstructionSettings
    from reconstruction.step_points import _bootstrap_prior

    pair = cams[:2]
    dets, *_ = projected_series(pair, n_steps=1, n_fake=0, seed=7)
    loose = CylinderPrior(radius=4.2e-3, tolerance=2e-3, half_length=12e-3)
    assert _bootstrap_prior(dets[0], pair, ReconstructionSettings(), loose) is loose
    assert _bootstrap_prior(dets[0], pair, ReconstructionSettings(), None) is None
