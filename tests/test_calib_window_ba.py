"""The window refined in the board bundle adjustment (issue 14): exact projections through a flat window, a wrong
start (plane 2 mm off, normal 2 deg off) recovered; planes that the board views cannot fix are flagged ILL-POSED."""

import cv2
import numpy as np
import pytest

from reconstruction.calibration import CalibrationError, _tilt_basis, calibrate_cameras
from reconstruction.cameras import Camera, rotation_matrix
from reconstruction.refraction import Window


def _look_at(name, centre, target, f=2000.0, size=(1224, 1024)):
    z = (target - centre) / np.linalg.norm(target - centre)
    x = np.cross([0, 1.0, 0], z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    K = np.array([[f, 0, size[0] / 2 + 6.5], [0, 1.001 * f, size[1] / 2 - 5.5], [0, 0, 1]])
    return Camera(name, K, np.array([-0.05, 0.05, 0, 0, 0]), cv2.Rodrigues(R)[0].ravel(), -R @ centre, size)


def window_scene(*, per_camera=False, n_views=9, depths=(0.17, 0.2, 0.23), tilt_deg=30.0, seed=0):
    """Three cameras (world = camera 0) looking through a 6 mm glass wall 90 mm away, tilted 2 deg, into water at a
    board (8 x 6 corners, 5 mm) at ``depths`` (m) with tilts up to ``tilt_deg``; exact refracted projections.
    ``per_camera``: each camera its own window (planes 0/5/10 mm apart, normals 0/1.1/2.3 deg apart)."""
    rng = np.random.default_rng(seed)
    target = np.array([0, 0, 0.2])
    cams = [_look_at(f"cam{i}", c, target) for i, c in enumerate([np.zeros(3), np.array([0.07, 0, 0.01]),
                                                                   np.array([-0.05, 0.05, 0])])]
    n = np.array([0.03, -0.02, 1.0]) / np.linalg.norm([0.03, -0.02, 1.0])
    wins = [Window(n + [0.02 * i * per_camera, 0, 0], 0.09 + 0.005 * i * per_camera, (0.006,), (1.52,), 1.333)
            for i in range(3)]
    cams = [Camera(c.name, c.K, c.dist, c.rvec, c.tvec, c.image_size, window=w) for c, w in zip(cams, wins)]
    obj = np.array([[i * 5e-3, j * 5e-3, 0] for j in range(6) for i in range(8)])
    uv = np.full((3, n_views, len(obj), 2), np.nan)
    for v in range(n_views):
        tilt = np.deg2rad(tilt_deg) * rng.uniform(-1, 1, 2)
        R = rotation_matrix(np.array([tilt[0], tilt[1], rng.uniform(-0.3, 0.3)]))
        X = (obj - obj.mean(0)) @ R.T + [rng.uniform(-0.01, 0.01), rng.uniform(-0.01, 0.01), depths[v % len(depths)]]
        for c, cam in enumerate(cams):
            p = cam.project(X)
            ok = np.isfinite(p).all(1) & (p > 0).all(1) & (p[:, 0] < 1223) & (p[:, 1] < 1023)
            uv[c, v, ok] = p[ok]
    return cams, obj, uv


def _wrong(w: Window) -> Window:
    """``w`` moved 2 mm along its normal and turned 2 deg."""
    e = _tilt_basis(w.normal)[0]
    a = np.deg2rad(2.0)
    return Window(np.cos(a) * w.normal + np.sin(a) * e, w.offset + 2e-3, w.thicknesses, w.indices, w.n_bath, w.n_air)


def _angle_deg(a, b):
    return float(np.rad2deg(np.arccos(np.clip(a @ b, -1, 1))))


def test_shared_wall_recovered_from_a_wrong_start():
    cams, obj, uv = window_scene()
    truth = cams[0].window
    res = calibrate_cameras(uv, obj, [c.image_size for c in cams], [c.name for c in cams], windows=_wrong(truth),
                            refine_window=True)
    fit = res.window_fit
    assert fit.cameras == [["cam0", "cam1", "cam2"]]  # one plane: the cameras were given the same window
    got = fit.refined[0]
    assert abs(got.offset - truth.offset) <= 0.05e-3  # measured 1e-12 m
    assert _angle_deg(got.normal, truth.normal) <= 0.1  # measured 0
    assert res.rms_total < 1e-3  # exact projections: reprojection at noise level (measured 2e-13 px)
    assert fit.well_posed and "ILL-POSED" not in fit.message
    assert fit.offset_std[0] < 0.5e-3 and np.rad2deg(fit.normal_std[0]) < 0.3  # 0.05 px noise floor: measured 0.22 mm, 0.09 deg
    assert all(c.window is not None and c.window.offset == got.offset for c in res.cameras)
    row = fit.summary()[0]
    assert row["plane_distance_mm"] == pytest.approx(90.0, abs=0.05) and row["plane_shift_mm"] == pytest.approx(-2, abs=0.05)
    assert row["normal_change_deg"] == pytest.approx(2.0, abs=0.1)
    for c, t in zip(res.cameras, cams):
        assert np.linalg.norm(c.center - t.center) < 1e-6 and c.K[0, 0] == pytest.approx(t.K[0, 0], rel=1e-6)


def test_one_window_per_camera_is_flagged_ill_posed():
    cams, obj, uv = window_scene(per_camera=True)
    res = calibrate_cameras(uv, obj, [c.image_size for c in cams], [c.name for c in cams],
                            windows=[_wrong(c.window) for c in cams], refine_window=True)
    fit = res.window_fit
    assert len(fit.refined) == 3 and fit.cameras == [["cam0"], ["cam1"], ["cam2"]]
    assert not fit.well_posed and "ILL-POSED" in fit.message
    assert np.max(fit.offset_std) > 2e-3  # measured 3.7-11 mm
    assert not np.any(fit.max_correlation < 0) and np.max(fit.max_correlation) > 0.99  # plane vs camera distance
    for got, cam in zip(fit.refined, cams):  # refused: the planes stay where given
        assert got.offset == pytest.approx(cam.window.offset + 2e-3, abs=1e-12)
    assert "refused" in fit.message and res.cameras[1].window.offset == fit.refined[1].offset


def test_refine_window_needs_a_window():
    cams, obj, uv = window_scene(n_views=4)
    with pytest.raises(CalibrationError, match="refine_window needs"):
        calibrate_cameras(uv, obj, [c.image_size for c in cams], refine_window=True)
