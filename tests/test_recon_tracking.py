"""Tracking marker identities through load steps (synthetic projections of a deforming tube)."""

import numpy as np
import pytest

from _recon_synth import camera_ring, projected_series
from reconstruction.pipeline import ReconstructionSettings, track_series
from reconstruction.tracking import _detect_swaps, match_step

LOST_MARKER = 7
LOST_STEP = 4
MISSING_CAMERA_STEP = 6


def _hide(k, vis):
    vis[1, ::9] = False  # some markers occluded in one camera at every step
    if k == LOST_STEP:
        vis[:, LOST_MARKER] = False  # a marker lost for one step (e.g. a bubble), found again later
    if k == MISSING_CAMERA_STEP:
        vis[2] = False  # a camera delivered no image in this step
    return vis


@pytest.fixture(scope="module")
def series():
    cams = camera_ring(6)
    # large steps: the radius grows 8 % and the length 3 % per step, with twist and a growing bulge
    dets, ids, C, S, V = projected_series(cams, n_steps=9, seed=11, hide=_hide, radial_step=0.08,
                                          axial_step=0.03, twist_step=0.03, bulge_step=0.01)
    res = track_series(dets, cams, ReconstructionSettings(marker_diameter=0.4e-3, specimen_radius=4e-3))
    return cams, ids, C, S, V, res, dets


def _identity(res, C):
    """Truth id of each track from the reference step (nearest true centre)."""
    d = np.linalg.norm(res.centres[0][:, None, :] - C[0][None], axis=-1)
    return np.argmin(d, axis=1)


def test_identities_complete_and_correct(series):
    cams, ids, C, S, V, res, _ = series
    gt = _identity(res, C)
    assert len(set(gt)) == len(gt)
    for k in range(C.shape[0]):
        seen2 = V[k].sum(axis=0) >= 2
        vis = res.visible[k]
        # a tracked marker's position is its own true position (never a neighbour's)
        err = np.linalg.norm(res.centres[k, vis] - C[k][gt[vis]], axis=1)
        assert np.max(err) < 20e-6, f"step {k}: identity swap or outlier ({np.max(err) * 1e6:.1f} um)"
        tracked_right = np.zeros(C.shape[1], bool)
        tracked_right[gt[vis]] = True
        completeness = tracked_right[seen2].mean()
        assert completeness >= 0.99, f"step {k}: completeness {completeness:.3f}"
        assert res.diagnostics["swaps"][k] == 0
        assert np.sqrt(np.mean(err**2)) < 2e-6
    # never-seen (single-view) markers are NaN, not dropped or renumbered
    assert res.centres.shape == (C.shape[0], len(gt), 3)
    assert np.array_equal(res.visible, np.all(np.isfinite(res.centres), axis=2))


def test_marker_lost_for_one_step_is_found_again(series):
    cams, ids, C, S, V, res, _ = series
    gt = _identity(res, C)
    track = int(np.flatnonzero(gt == LOST_MARKER)[0])
    assert not res.visible[LOST_STEP, track]
    assert np.isnan(res.positions[LOST_STEP, track]).all() and np.isnan(res.uncertainty[LOST_STEP, track])
    later = res.visible[LOST_STEP + 1 :, track]
    assert later.all()
    np.testing.assert_allclose(res.centres[LOST_STEP + 1 :, track], C[LOST_STEP + 1 :, LOST_MARKER], atol=10e-6)


def test_missing_camera_step(series):
    cams, ids, C, S, V, res, _ = series
    k = MISSING_CAMERA_STEP
    assert res.diagnostics["detected"][k, 2] == 5  # only the fake detections
    seen2 = V[k].sum(axis=0) >= 2
    assert res.visible[k].sum() >= 0.99 * seen2.sum()
    assert res.visible[k].sum() < res.visible[k - 1].sum()  # markers seen only by camera 2 + one other are lost


def test_surface_points_and_uncertainty(series):
    cams, ids, C, S, V, res, _ = series
    gt = _identity(res, C)
    vis = res.visible
    err = np.linalg.norm(res.positions[vis] - S[np.nonzero(vis)[0], gt[np.nonzero(vis)[1]]], axis=1)
    assert np.sqrt(np.mean(err**2)) < 3e-6  # the 0.2 mm marker offset is removed
    unc = res.uncertainty[vis]
    assert np.all(unc > 0) and np.median(unc) < 5e-6


def test_match_step_recovers_large_inflation():
    rng = np.random.default_rng(0)
    th = rng.uniform(-np.pi, np.pi, 300)
    z = rng.uniform(-8e-3, 8e-3, 300)
    prev = np.stack([4e-3 * np.cos(th), 4e-3 * np.sin(th), z], 1)
    # 30 % inflation and 10 % extension in one step: displacements exceed the marker spacing
    cur = np.stack([5.2e-3 * np.cos(th + 0.05), 5.2e-3 * np.sin(th + 0.05), 1.1 * z], 1)
    perm = rng.permutation(300)
    m = match_step(prev, cur[perm][:290])  # 10 markers not reconstructed in this step
    inv = np.argsort(perm)
    truth = np.where(inv < 290, inv, -1)
    assert np.array_equal(m.assignment, truth)
    assert m.swaps.shape == (0, 2)


def test_swap_detector_flags_exchanged_neighbours():
    rng = np.random.default_rng(1)
    prev = rng.uniform(-5e-3, 5e-3, (100, 3))
    obs = prev + 1e-4
    assign = np.arange(100)
    d = np.linalg.norm(prev[:, None] - prev[None], axis=-1) + np.eye(100)
    i, j = np.unravel_index(np.argmin(d), d.shape)
    assign[i], assign[j] = j, i
    swaps = _detect_swaps(prev, obs, obs, assign, k=8, gate=0.5 * d[i, j] + 1e-4)
    assert sorted(map(int, swaps[0])) == sorted([i, j]) and swaps.shape == (1, 2)


def test_specimen_frame_output(series):
    """frame='specimen': the same tracks, rigidly moved so the fitted axis is z and the origin is mid-length."""
    cams, ids, C, S, V, res, dets = series
    spec = track_series(dets[:2], cams, ReconstructionSettings(marker_diameter=0.4e-3, specimen_radius=4e-3),
                        frame="specimen")
    T = spec.world_to_rig
    assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3)) and np.allclose(T[3], [0, 0, 0, 1])
    moved = res.centres[:2] @ T[:3, :3].T + T[:3, 3]
    np.testing.assert_allclose(spec.centres, moved, atol=1e-12, equal_nan=True)
    z = spec.centres[0, :, 2]
    assert abs(0.5 * (np.nanmin(z) + np.nanmax(z))) < 1e-12
    # the synthetic tube's axis is the world z axis through the origin
    assert abs(abs(T[2, 2]) - 1) < 1e-5
    assert np.linalg.norm(np.hypot(spec.centres[0, :, 0], spec.centres[0, :, 1])[res.visible[0]] - 4.2e-3, ord=np.inf) < 0.1e-3
    with pytest.raises(ValueError, match="frame must be"):
        track_series(dets[:1], cams, frame="lab")
