"""The distortion model of ``vfmlab calibrate`` by default: k3 free only if held-out views say so; an unphysical
distortion refused."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruction.cameras import Camera, rotation_matrix
from reconstruction.calibration_select import choose_distortion, distortion_problem
from rig_sim.cameras import camera_ring


def _camera(dist, name="c", f=2000.0):
    K = np.array([[f, 0, 640], [0, f, 512], [0, 0, 1]])  # corner at r = 0.41 (f 2000 px), 0.22 (f 3700 px)
    return Camera(name, K, np.asarray(dist, float), np.zeros(3), np.array([0, 0, 0.1]), (1280, 1024))


def test_distortion_problem_names_folding_and_huge_distortion():
    assert distortion_problem(_camera([-0.09, 0.1, 0, 0, 0])) is None  # a macro lens
    # free k3 of the rendered rig (corners at r = 0.22): mild over its image, unphysical over a wider one
    assert distortion_problem(_camera([-0.07, -0.68, 0, 0, 28.9], f=3700.0)) is None
    assert "changes the radius by +46 %" in distortion_problem(_camera([-0.07, -0.68, 0, 0, 28.9]))
    folds = distortion_problem(_camera([-2.0, 0, 0, 0, 0], "cam2"))
    assert folds is not None and "cam2" in folds and "folds back" in folds
    huge = distortion_problem(_camera([0.0, 0, 0, 0, 2000.0]))
    assert huge is not None and "changes the radius by" in huge


def _board_views(cams, n_views, rng, noise_px):
    obj = np.stack(np.meshgrid(np.arange(8) * 4e-3, np.arange(6) * 4e-3), -1).reshape(-1, 2)
    obj = np.column_stack([obj - obj.mean(0), np.zeros(len(obj))])  # a planar board, m
    uv = np.full((len(cams), n_views, len(obj), 2), np.nan)
    for v in range(n_views):
        R = rotation_matrix(rng.normal(0, 0.35, 3))
        t = rng.uniform(-4e-3, 4e-3, 3)
        for c, cam in enumerate(cams):
            uv[c, v] = cam.project(obj @ R.T + t) + rng.normal(0, noise_px, (len(obj), 2))
    return uv, obj


def test_held_out_views_keep_k3_fixed_when_the_lens_has_none():
    cams = camera_ring(2, image_size=(800, 600), seed=4, distortion=(-0.1, 0.05, 0.0, 0.0, 0.0))
    uv, obj = _board_views(cams, 12, np.random.default_rng(0), 0.1)
    choice = choose_distortion(uv, obj, [c.image_size for c in cams], [c.name for c in cams])
    assert choice.fix_k3, choice.reason
    assert set(choice.heldout_rms_px) == {"k3 fixed", "k3 free"} and choice.n_heldout_views == 3
    assert all(0 < v < 0.5 for v in choice.heldout_rms_px.values())
    assert "held-out RMS over 3 views" in choice.reason


def test_too_few_views_or_a_window_fix_k3_without_trying():
    cams = camera_ring(2, image_size=(800, 600), seed=4)
    uv, obj = _board_views(cams, 5, np.random.default_rng(1), 0.1)
    choice = choose_distortion(uv, obj, [c.image_size for c in cams])
    assert choice.fix_k3 and "too few" in choice.reason and not choice.heldout_rms_px
    assert choose_distortion(uv, obj, [c.image_size for c in cams], windows=object()).fix_k3


def test_calibrate_refuses_an_unphysical_distortion(monkeypatch, tmp_path):
    """The stage stores nothing when a calibrated camera's distortion is unphysical (here forced by --free-k3)."""
    from vfmlab.stages import calibrate as stage
    from vfmlab.stages.errors import StageFailed

    class Result:
        cameras = [_camera([0.0, 0, 0, 0, 2000.0], "cam1")]

    with pytest.raises(StageFailed, match="unphysical lens distortion: camera cam1.*--fix-k3"):
        stage._refuse_unphysical(Result(), fix_k3=False)
    Result.cameras = [_camera([-0.09, 0.1, 0, 0, 0])]
    stage._refuse_unphysical(Result(), fix_k3=True)  # a physical one passes
