"""DuoDIC's real sample data (tests/data/duodic-sample): its MATLAB results and calibration read into vfmlab's
conventions, checked against MATLAB's and DuoDIC's own numbers and against a rigid-body motion of known size."""

import cv2
import numpy as np
import pytest

from _data import data_path
from acquisition.dic import (DICImportError, read_duodic_2d_pairs, read_duodic_points, read_mat_struct,
                             read_matlab_calibration_session)
from reconstruction import cameras_from_arrays, rotation_matrix, triangulate

DUO = "duodic-sample"
SIZE = (2448, 2048)


@pytest.fixture(scope="module")
def calib():
    return read_matlab_calibration_session(data_path(f"{DUO}/calibration_11_18_10mm/calibrationSession.mat"))


@pytest.fixture(scope="module")
def recalibrated(calib):
    """OpenCV mono + joint stereo calibration from MATLAB's corner lists, MATLAB's model (k1, k2; no tangential)."""
    obj = [calib.object_points.astype(np.float32)] * calib.board_points.shape[1]
    img = [[v.astype(np.float32) for v in calib.board_points[k]] for k in range(2)]
    flags = cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
    mono = [cv2.calibrateCamera(obj, img[k], SIZE, None, None, flags=flags) for k in range(2)]
    rms, K1, d1, K2, d2, R, T, _, _ = cv2.stereoCalibrate(obj, img[0], img[1], mono[0][1], mono[0][2], mono[1][1],
                                                          mono[1][2], SIZE, flags=cv2.CALIB_USE_INTRINSIC_GUESS | flags)
    arrays = dict(calib.camera_arrays, K=np.stack([K1, K2]), dist=np.stack([d1.ravel(), d2.ravel()]),
                  rvec=np.stack([np.zeros(3), cv2.Rodrigues(R)[0].ravel()]), tvec=np.stack([np.zeros(3), T.ravel()]))
    return (mono[0][0], mono[1][0]), rms, cameras_from_arrays(arrays)


def test_calibration_layout(calib):
    assert calib.board_points.shape == (2, 37, 70, 2)
    assert calib.object_points.shape == (70, 3) and calib.square_size == pytest.approx(0.010)
    assert calib.camera_arrays["image_size"].tolist() == [[2448, 2048], [2448, 2048]]
    # camera 2 sits ~160 mm beside camera 1 (metres inside)
    assert np.linalg.norm(calib.camera_arrays["tvec"][1]) == pytest.approx(0.1604, abs=1e-3)


def test_matlab_conventions_reproduce_matlab_rms(calib):
    """K transposed, principal point and corners 1-based, rotation of camera 2 transposed: reprojecting the corners
    with the imported cameras and MATLAB's board poses gives MATLAB's own RMS (0.572 / 0.602 px)."""
    cams = cameras_from_arrays(calib.camera_arrays)
    R = rotation_matrix(calib.board_rvecs)
    world = np.einsum("vij,pj->vpi", R, calib.object_points) + calib.board_tvecs[:, None]
    rms = [np.sqrt(np.mean(np.sum((c.project(world) - calib.board_points[k]) ** 2, -1))) for k, c in enumerate(cams)]
    np.testing.assert_allclose(rms, calib.matlab_rms, rtol=1e-9)
    np.testing.assert_allclose(rms, [0.572, 0.602], atol=5e-4)


def test_duodic_points_match_triangulated_pairs(calib):
    """DuoDIC's 3-D result, read from its v7.3 file, equals vfmlab's triangulation of DuoDIC's own 2-D pairs with
    the imported calibration (same mm -> m, same frame, same missing points) to under 2 µm."""
    res = read_duodic_points(data_path(f"{DUO}/uniaxial_tension/DIC3Dstereo.mat"))
    pairs = read_duodic_2d_pairs(data_path(f"{DUO}/uniaxial_tension/DIC2DpairResults.mat"))
    assert res.points.shape == (20, 435, 3) and res.quality.shape == (20, 435)
    assert res.triangles.shape == (722, 3) and res.triangles.min() == 0 and res.triangles.max() == 434
    cams = cameras_from_arrays(calib.camera_arrays)
    mine = np.stack([triangulate(pairs.pixels[:, s], cams, covariance=False).points for s in range(20)])
    np.testing.assert_array_equal(np.isnan(mine), np.isnan(res.points))
    gap = np.linalg.norm(mine - res.points, axis=-1)
    assert np.nanmax(gap) < 2e-6 and np.nanmedian(gap) < 1e-6


def test_recalibration_from_corner_lists(calib, recalibrated):
    """OpenCV on MATLAB's corners: mono 0.430 / 0.465 px, stereo 0.587 px; camera 2 within 2 µm of MATLAB's."""
    mono, rms, cams = recalibrated
    np.testing.assert_allclose(mono, [0.430, 0.465], atol=2e-3)
    assert rms <= 0.5875
    assert np.abs(cams[1].tvec - calib.camera_arrays["tvec"][1]).max() < 2e-6


def test_rigid_body_motion_against_stage(recalibrated):
    """DuoDIC's RBM: 3,476 points x 15 stage steps (0 to 2.8 mm), triangulated: mean |error| of the displacement
    magnitude 1.72 µm (DuoDIC's paper: 1.3 ± 1.1 µm)."""
    _, _, cams = recalibrated
    pairs = read_duodic_2d_pairs(data_path(f"{DUO}/RBM/DIC2DpairResults.mat"))
    stage = np.asarray(read_mat_struct(data_path(f"{DUO}/RBM/stage_translations.mat"))).ravel() * 1e-3
    assert pairs.pixels.shape == (2, 15, 3476, 2) and stage.shape == (15,)
    X = np.stack([triangulate(pairs.pixels[:, s], cams, covariance=False).points for s in range(15)])
    err = (np.linalg.norm(X - X[0], axis=-1) - stage[:, None])[1:]
    assert np.isfinite(err).mean() > 0.999
    assert np.nanmean(np.abs(err)) <= 2e-6
    assert np.nanstd(err) < 1.6e-6


def test_bad_files_name_the_file(tmp_path):
    junk = tmp_path / "junk.mat"
    junk.write_bytes(b"not a mat file at all" * 10)
    with pytest.raises(DICImportError, match="junk.mat.*not a MATLAB"):
        read_duodic_points(junk)
    with pytest.raises(DICImportError, match="stage_translations.mat.*Points3D"):
        read_duodic_points(data_path(f"{DUO}/RBM/stage_translations.mat"))
    with pytest.raises(DICImportError, match="DIC3Dstereo.mat"):
        read_matlab_calibration_session(data_path(f"{DUO}/uniaxial_tension/DIC3Dstereo.mat"))
    with pytest.raises(DICImportError, match="missing.mat: no such file"):
        read_duodic_2d_pairs(tmp_path / "missing.mat")


@pytest.mark.slow
def test_vfmlab_joint_calibration_from_corner_lists(calib):
    """vfmlab's own bundle adjustment (k1, k2, p1, p2) on MATLAB's corners: RMS 0.521 px (<= OpenCV's 0.587), and its
    cameras measure the RBM to mean |error| 1.96 µm (<= 2 µm). About 17 s on an idle machine."""
    from reconstruction import calibrate_cameras

    res = calibrate_cameras(calib.board_points, calib.object_points, [SIZE, SIZE], ["cam1", "cam2"], fix_k3=True)
    assert res.n_outliers == 0 and res.rms_total <= 0.587
    pairs = read_duodic_2d_pairs(data_path(f"{DUO}/RBM/DIC2DpairResults.mat"))
    stage = np.asarray(read_mat_struct(data_path(f"{DUO}/RBM/stage_translations.mat"))).ravel() * 1e-3
    X = np.stack([triangulate(pairs.pixels[:, s], res.cameras, covariance=False).points for s in range(15)])
    err = (np.linalg.norm(X - X[0], axis=-1) - stage[:, None])[1:]
    assert np.nanmean(np.abs(err)) <= 2e-6


def test_multidic_v5_struct(tmp_path):
    """A MultiDIC-style ``DIC3DPPresults`` saved as MATLAB v5 (scipy.io writes it as MATLAB would): same reader."""
    import scipy.io

    pts = [np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]]),
           np.array([[1.5, 2, 3], [np.nan] * 3, [7, 8, 9.5]])]
    cells = np.empty((2, 1), dtype=object)
    cells[0, 0], cells[1, 0] = pts
    corr = np.empty((2, 1), dtype=object)
    corr[0, 0], corr[1, 0] = np.array([[0.01], [0.02], [0.03]]), np.array([[0.04], [np.nan], [0.06]])
    path = tmp_path / "DIC3DPPresults.mat"
    scipy.io.savemat(path, {"DIC3DPPresults": {"Points3D": cells, "corrComb": corr, "Faces": np.array([[1, 2, 3]])}})
    res = read_duodic_points(path)
    np.testing.assert_allclose(res.points, np.stack(pts) * 1e-3)
    np.testing.assert_allclose(res.quality[0], [0.01, 0.02, 0.03])
    assert res.triangles.tolist() == [[0, 1, 2]]
