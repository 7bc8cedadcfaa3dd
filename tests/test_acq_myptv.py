"""MyPTV's real 3-camera example (tests/data/myptv-example): the calibration dots read, calibrated per camera with
OpenCV's model, triangulated by vfmlab: the dots seen by all three cameras land within 0.096 mm RMS of their target
places; MyPTV's particle images matched by vfmlab and compared with MyPTV's own particles."""

import cv2
import numpy as np
import pytest

from _data import DATA_DIR, data_path
from acquisition.dic import (
    DICImportError,
    parse_myptv_blobs,
    parse_myptv_cal_points,
    parse_myptv_particles,
    read_myptv_blobs,
    read_myptv_cal_points,
    read_myptv_particles,
    read_myptv_target,
)
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


def test_blobs_and_particles_read():
    blobs = read_myptv_blobs(data_path("myptv-example/blobs_cam1"))
    assert sorted(blobs) == list(range(7)) and [len(blobs[f]) for f in range(7)] == [78, 78, 76, 73, 78, 81, 88]
    # MyPTV writes (row, column): the reader gives OpenCV's (x = column, y = row), in file order
    np.testing.assert_allclose(blobs[0][0], [377.85, 181.10])
    p = read_myptv_particles(data_path("myptv-example/particles"), 3)
    assert p.points.shape == (281, 3) and p.blobs.shape == (281, 3) and np.all(p.blobs >= 0)
    np.testing.assert_allclose(p.points[0], [6.432e-3, 17.481e-3, -3.761e-3])
    assert list(p.blobs[0]) == [49, 36, 43] and p.frames[0] == 0 and p.error[0] == pytest.approx(0.020e-3)
    assert np.bincount(p.frames).tolist() == [37, 38, 42, 41, 38, 43, 42]


def test_particles_matched_against_myptv():
    """MyPTV's blobs (frames 0-6) matched across the three cameras by vfmlab's match_views with vfmlab's calibration
    of the dot plate, against MyPTV's own particles (benchmarks/bench_myptv.py prints the table)."""
    from benchmarks.bench_myptv import compare_example, summary

    comparisons, rms3d = compare_example(DATA_DIR / "myptv-example")
    s = summary(comparisons, rms3d)
    assert rms3d <= 0.096e-3 and s["tolerance_mm"] == pytest.approx(0.279, abs=0.01)  # 3 x the 3-D RMS
    # MyPTV's blob triplets triangulated with our cameras: the blob reader's axes and numbering are right (a swap or
    # an off-by-one puts them millimetres away); what is left is the two calibrations' disagreement
    assert s["retriangulated"]["median_mm"] <= 0.13 and s["retriangulated"]["p95_mm"] <= 0.30  # 0.111, 0.277
    assert s["n_myptv"] == 281 and s["n_ours"] <= 300  # 292
    assert s["fraction_same_blobs"] >= 0.97  # 278 of 281 (98.9 %): the same three blobs
    assert s["fraction_found"] >= 0.93  # 266 of 281 (94.7 %) within 0.279 mm
    assert s["found"]["median_mm"] <= 0.12 and s["found"]["p95_mm"] <= 0.26  # 0.107, 0.238
    # the ones beyond the tolerance with the same blobs lie far from the plate's depths (z -52..41 mm, plate 0..-12)
    assert s["n_myptv_only"] <= 18 and s["n_myptv_only_same_blobs"] >= s["n_myptv_only"] - 4  # 15, 12
    assert s["n_ours_only"] <= 30  # 26: 12 with MyPTV's blobs, 2 sharing some, 12 with blobs MyPTV left unmatched


def test_bad_blobs_and_particles():
    with pytest.raises(DICImportError, match="blobs_cam9: line 2 has 3 fields; expected 6") as exc:
        parse_myptv_blobs("1 2 3 4 5 0\n1 2 3\n", where="blobs_cam9")
    assert "\n" not in str(exc.value)
    with pytest.raises(DICImportError, match="frame column must hold whole numbers"):
        parse_myptv_blobs("1 2 3 4 5 0.5\n")
    # a trajectories file (14 columns) given as particles of 3 cameras
    with pytest.raises(DICImportError, match="particles: line 1 has 14 fields; expected 8"):
        parse_myptv_particles("0 1 2 3 0 0 0 0 0 0 4 5 6 0\n", 3)
    with pytest.raises(DICImportError, match="must be blob numbers"):
        parse_myptv_particles("1 2 3 4 5.5 -1 0.02 0\n", 3)
    with pytest.raises(DICImportError, match="cannot read"):
        read_myptv_blobs(DATA_DIR / "myptv-example" / "no_such_blobs")
