"""Joint calibration: rendered ChArUco views (ground truth known), synthetic correspondences, real stereo photos."""

import glob
import os

import cv2
import numpy as np
import pytest

from rig_sim.calibration_scene import SPEC, align_cameras, board_corners_world, rendered_charuco, rigid_fit
from _data import data_path
from reconstruction.calibration import CalibrationError, calibrate_cameras, calibrate_from_detections, detections_to_arrays
from reconstruction.cameras import rotation_matrix
from reconstruction.targets import BoardSpec, detect_board
from reconstruction.triangulation import triangulate
from rig_sim.cameras import camera_ring, specimen_triangulation_error

STEREO = data_path("opencv-stereo-chessboard")


@pytest.fixture(scope="module")
def charuco():
    cams, views, det = rendered_charuco()
    res = calibrate_from_detections(det, SPEC, {c.name: c.image_size for c in cams}, fix_k3=True)
    return cams, views, det, res


def _aligned(res, views):
    est, ok = board_corners_world(res.board_rvecs, res.board_tvecs)
    true = np.concatenate([SPEC.object_points() @ rotation_matrix(r).T + t for r, t in zip(views.rvecs[ok], views.tvecs[ok])])
    R, t = rigid_fit(est, true)
    return align_cameras(res.cameras, R, t)


def test_charuco_detections_match_truth(charuco):
    cams, views, det, _ = charuco
    errs, found = [], []
    for ci, c in enumerate(cams):
        for v, d in enumerate(det[c.name]):
            if views.seen[ci, v]:
                found.append(len(d) / SPEC.n_points)
            if len(d):
                errs.append(d.points - views.points[ci, v, d.ids])
    assert np.mean(found) > 0.95 and np.min(found) > 0.5  # oblique views may lose a marker or two
    errs = np.concatenate(errs)
    errs = errs[np.isfinite(errs).all(1)]
    assert np.sqrt(np.mean(np.sum(errs**2, 1))) < 0.1  # measured 0.05 px


def test_charuco_calibration_recovers_truth(charuco):
    cams, views, det, res = charuco
    assert res.converged
    assert res.rms_total < 0.1  # measured 0.054 px
    assert res.rms.shape == (4,) and res.rms_per_view.shape == (4, 24)
    assert res.n_outliers <= 0.01 * res.n_observations
    assert res.n_observations > 1000
    # reported uncertainties are honest: intrinsic errors within a few standard deviations
    std = res.parameter_std
    assert std.shape == (4, 15) and np.isnan(std[0, 9:]).all() and np.isnan(std[:, 8]).all()  # gauge, fixed k3
    for a, b, sd in zip(res.cameras, cams, std):
        err = np.array([a.K[0, 0] - b.K[0, 0], a.K[1, 1] - b.K[1, 1], a.K[0, 2] - b.K[0, 2], a.K[1, 2] - b.K[1, 2]])
        assert (np.abs(err) < 4 * sd[:4]).all()  # measured |err| / std <= 2.1
        assert (sd[:4] < 5).all()  # px
    est = _aligned(res, views)
    for a, b in zip(est, cams):
        np.testing.assert_allclose(np.diag(a.K)[:2], np.diag(b.K)[:2], rtol=2e-3)  # measured <= 0.07 %
        np.testing.assert_allclose(a.K[:2, 2], b.K[:2, 2], atol=10)  # px at 1224 x 1024, measured <= 5.4
        np.testing.assert_allclose(a.dist[[0, 2, 3]], b.dist[[0, 2, 3]], atol=5e-3)
        angle = np.linalg.norm(cv2.Rodrigues(a.R @ b.R.T)[0])
        assert np.rad2deg(angle) < 0.3  # measured <= 0.11 deg
        assert np.linalg.norm(a.center - b.center) < 300e-6  # measured <= 94 um (mostly along the optical axis)
    # what matters: points on the specimen triangulated with the estimated cameras
    err, seen = specimen_triangulation_error(cams, est, n_points=1000)
    assert seen.mean() > 0.5  # 4 cameras 90 deg apart: about 2/3 of the wall is seen twice
    assert np.sqrt(np.mean(err**2)) < 5e-6  # measured 1.7 um RMS
    assert err.max() < 10e-6  # measured 2.9 um


def test_outliers_rejected_and_result_unchanged(charuco):
    cams, views, det, res = charuco
    names, uv, obj = detections_to_arrays(det, SPEC)
    rng = np.random.default_rng(3)
    idx = np.argwhere(np.isfinite(uv).all(-1))
    bad = idx[rng.choice(len(idx), 12, replace=False)]
    uv2 = uv.copy()
    uv2[bad[:, 0], bad[:, 1], bad[:, 2]] += rng.choice([-1, 1], (12, 2)) * rng.uniform(3, 20, (12, 2))
    res2 = calibrate_cameras(uv2, obj, [c.image_size for c in cams], names, fix_k3=True)
    rejected = {tuple(o) for o in res2.outliers}
    assert {tuple(b) for b in bad} <= rejected
    assert res2.n_outliers <= 12 + 3
    assert res2.rms_total < 0.1
    # same answer as without the corrupted observations at all
    uv3 = uv.copy()
    uv3[tuple(res2.outliers.T)] = np.nan
    res3 = calibrate_cameras(uv3, obj, [c.image_size for c in cams], names, fix_k3=True)
    for a, b in zip(res2.cameras, res3.cameras):
        np.testing.assert_allclose(a.K, b.K, atol=1e-3)
        np.testing.assert_allclose(a.tvec, b.tvec, atol=1e-8)


def test_plain_correspondences_noise_free_exact():
    """Non-planar object points, no noise: the adjustment lands on the truth (gauge: reference camera)."""
    cams = camera_ring(3, image_size=(800, 600), seed=4, distortion=(-0.1, 0.05, 1e-3, -5e-4, 0.0))
    rng = np.random.default_rng(5)
    obj = rng.uniform(-6e-3, 6e-3, (40, 3))  # a 3-D target, m
    n_views = 8
    uv = np.full((3, n_views, 40, 2), np.nan)
    for v in range(n_views):
        R = rotation_matrix(rng.normal(0, 0.3, 3))
        t = rng.uniform(-3e-3, 3e-3, 3)
        Xw = obj @ R.T + t
        for c, cam in enumerate(cams):
            uv[c, v] = cam.project(Xw)
    res = calibrate_cameras(uv, obj, [c.image_size for c in cams], fix_k3=True)
    assert res.converged and res.rms_total < 1e-6
    ref = cams[0]
    for a, b in zip(res.cameras, cams):
        np.testing.assert_allclose(a.K, b.K, atol=1e-4)
        # relative pose to the reference camera is the truth
        Rrel_est = a.R
        Rrel_true = b.R @ ref.R.T
        np.testing.assert_allclose(Rrel_est, Rrel_true, atol=1e-8)


def test_errors_name_the_problem():
    uv = np.full((2, 3, 10, 2), np.nan)
    with pytest.raises(CalibrationError, match="image_points"):
        calibrate_cameras(uv[0], np.zeros((10, 3)), [(10, 10)] * 2)
    with pytest.raises(CalibrationError, match="object_points"):
        calibrate_cameras(uv, np.zeros((9, 3)), [(10, 10)] * 2)
    with pytest.raises(CalibrationError, match="seen in 0 views"):
        calibrate_cameras(uv, np.zeros((10, 3)), [(10, 10)] * 2)


@pytest.fixture(scope="module")
def stereo():
    spec = BoardSpec(kind="chessboard", columns=9, rows=6, square_size=1.0, subpix_half_window=5)
    ids = sorted(os.path.basename(p)[4:6] for p in glob.glob(f"{STEREO}/left*.jpg"))
    det = {s: [detect_board(cv2.imread(f"{STEREO}/{s}{i}.jpg", cv2.IMREAD_GRAYSCALE), spec) for i in ids] for s in ("left", "right")}
    res = calibrate_from_detections(det, spec, {"left": (640, 480), "right": (640, 480)})
    return spec, det, res


def test_real_stereo_joint_ba_at_least_as_good_as_opencv(stereo):
    spec, det, res = stereo
    assert all(len(d) == 54 for s in det for d in det[s])
    assert res.converged and res.n_outliers == 0
    # README reference: stereo RMS 0.217 px with intrinsics fixed; joint adjustment must not be worse
    assert res.rms_total <= 0.217  # measured 0.215
    assert res.rms[0] < 0.215 and res.rms[1] < 0.225  # single-camera (own board poses): 0.196, 0.207
    left, right = res.cameras
    np.testing.assert_allclose(left.K[0, 0], 532.8, rtol=5e-3)
    np.testing.assert_allclose(left.K[:2, 2], [342.5, 233.9], atol=2.0)
    np.testing.assert_allclose(right.tvec, [-3.328, 0.037, 0.014], atol=0.03)


def test_real_stereo_corner_spacing(stereo):
    spec, det, res = stereo
    px = np.stack([np.stack([d.points for d in det[s]]) for s in ("left", "right")])  # (2, 13, 54, 2)
    tri = triangulate(px.reshape(2, -1, 2), res.cameras)
    P = tri.points.reshape(13, 6, 9, 3)
    d = np.concatenate([np.linalg.norm(np.diff(P, axis=1), axis=-1).ravel(), np.linalg.norm(np.diff(P, axis=2), axis=-1).ravel()])
    err = d - 1.0
    # README (stereoCalibrate, intrinsics fixed): mean 0.0004, std 0.0082, max 0.047 square
    assert abs(err.mean()) < 0.002
    assert err.std() < 0.0082
    assert np.abs(err).max() < 0.047


def test_reversed_point_order_resolved(charuco):
    """Chessboard-like targets may be numbered from either end, differently per camera: resolve_flips fixes it."""
    cams, views, det, res = charuco
    names, uv, obj = detections_to_arrays(det, SPEC)
    seen = np.isfinite(uv).all(-1).sum(-1) >= 6
    shared = np.argwhere(seen & (seen.sum(0) >= 2)[None, :])
    flipped = shared[::3]  # every third (camera, view) of the shared views
    uv2 = uv.copy()
    for c, v in flipped:
        uv2[c, v] = uv[c, v, ::-1]
    res2 = calibrate_cameras(uv2, obj, [c.image_size for c in cams], names, fix_k3=True, resolve_flips=True)
    assert res2.n_outliers == res.n_outliers and res2.rms_total == pytest.approx(res.rms_total, rel=1e-6)
    for a, b in zip(res2.cameras, res.cameras):
        np.testing.assert_allclose(a.K, b.K, atol=1e-3)
