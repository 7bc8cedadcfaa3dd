"""MyPTV's real 3-camera calibration dots (tests/data/myptv-example): read, calibrated per camera with OpenCV's
model, triangulated by vfmlab: the dots seen by all three cameras land within 0.096 mm RMS of their target places."""

import cv2
import numpy as np
import pytest

from _data import data_path
from acquisition.dic import DICImportError, parse_myptv_cal_points, read_myptv_cal_points, read_myptv_target
from reconstruction import Camera, triangulate

SIZE = (1280, 1024)


def _calibrate(pixels: np.ndarray, target: np.ndarray, name: str) -> tuple[float, Camera]:
    """One view of the three-level dot plate (a non-planar target): OpenCV from a rough K, k1, k2, p1, p2 (k3 = 0)."""
    K0 = np.array([[6000.0, 0, SIZE[0] / 2], [0, 6000.0, SIZE[1] / 2], [0, 0, 1]])
    rms, K, dist, rv, tv = cv2.calibrateCamera([target.astype(np.float32)], [pixels.astype(np.float32)], SIZE, K0,
                                               None, flags=cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_K3)
    return rms, Camera(name, K, dist.ravel()[:5], rv[0].ravel(), tv[0].ravel(), SIZE)


def _by_dot(pixels: np.ndarray, target: np.ndarray) -> dict:
    """{target dot on a 10 µm grid: its pixel}."""
    return dict(zip(map(tuple, np.round(target * 1e5).astype(int)), pixels))


def test_three_cameras_from_dot_pairs():
    pairs = [read_myptv_cal_points(data_path(f"myptv-example/Calibration/cam{k}_cal_points")) for k in (1, 2, 3)]
    assert [len(p[0]) for p in pairs] == [421, 432, 411]
    target = read_myptv_target(data_path("myptv-example/Calibration/target_file"))
    assert target.shape == (437, 3) and set(np.round(target[:, 2] * 1e3, 6)) == {0.0, -6.0, -12.0}
    # every calibration dot is a target dot (metres on both sides)
    dots = [_by_dot(px, X) for px, X in pairs]
    assert all(set(d) <= set(_by_dot(target, target)) for d in dots)
    fits = [_calibrate(px, X, f"cam{k + 1}") for k, (px, X) in enumerate(pairs)]
    assert max(r for r, _ in fits) < 0.6
    cams = [c for _, c in fits]
    common = sorted(set.intersection(*(set(d) for d in dots)))
    assert len(common) == 406
    pixels = np.stack([np.array([d[c] for c in common]) for d in dots])
    X = triangulate(pixels, cams, covariance=False).points
    rms = np.sqrt(np.mean(np.sum((X - np.array(common) * 1e-5) ** 2, -1)))
    assert rms <= 0.096e-3  # measured 0.093 mm


def test_bad_cal_points():
    with pytest.raises(DICImportError, match="cam9: line 2 has 4 fields; expected 5"):
        parse_myptv_cal_points("1 2 3 4 5\n1 2 3 4\n", where="cam9")
    px, X = parse_myptv_cal_points("10.5 20.25 3 6 -12\n")
    np.testing.assert_allclose(X, [[0.003, 0.006, -0.012]])
    np.testing.assert_allclose(px, [[10.5, 20.25]])
