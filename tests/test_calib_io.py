"""Calibration files: TOML (aniposelib) and OpenCV YAML round trips, units handling, session arrays."""

import cv2
import numpy as np
import pytest

from reconstruction.calibration_io import (
    CalibrationFileError,
    cameras_from_arrays,
    cameras_from_toml,
    cameras_from_yaml,
    cameras_to_arrays,
    cameras_to_toml,
    cameras_to_yaml,
)
from rig_sim.cameras import camera_ring

ANIPOSE = """
[cam_0]
name = "A"
size = [ 1280, 1024,]
matrix = [ [ 1500.0, 0.0, 640.0,], [ 0.0, 1500.0, 512.0,], [ 0.0, 0.0, 1.0,],]
distortions = [ -0.1, 0.01, 0.0, 0.0, 0.0,]
rotation = [ 0.0, 0.0, 0.0,]
translation = [ 0.0, 0.0, 0.0,]

[cam_1]
name = "B"
size = [ 1280, 1024,]
matrix = [ [ 1510.0, 0.0, 630.0,], [ 0.0, 1511.0, 500.0,], [ 0.0, 0.0, 1.0,],]
distortions = [ -0.12, 0.02, 0.001, 0.0, 0.0,]
rotation = [ 0.1, -0.5, 0.02,]
translation = [ -120.0, 3.0, 25.0,]

[metadata]
adjusted = true
error = 0.31
"""


def _same(a, b, tol=1e-12):
    assert [c.name for c in a] == [c.name for c in b]
    for x, y in zip(a, b):
        np.testing.assert_allclose(x.K, y.K, rtol=tol)
        np.testing.assert_allclose(x.dist, y.dist, rtol=tol, atol=1e-300)
        np.testing.assert_allclose(x.rvec, y.rvec, rtol=tol, atol=1e-15)
        np.testing.assert_allclose(x.tvec, y.tvec, rtol=tol, atol=1e-15)
        assert x.image_size == y.image_size


@pytest.mark.parametrize("units", ["mm", "m", "um"])
def test_toml_round_trip(units):
    cams = camera_ring(6)
    text = cameras_to_toml(cams, units=units, metadata={"rms_px": [0.1] * 6})
    back, meta = cameras_from_toml(text)
    _same(cams, back)
    assert meta["units"] == units and meta["rms_px"] == [0.1] * 6


def test_toml_written_in_mm_by_default():
    cams = camera_ring(2)
    text = cameras_to_toml(cams)
    import tomllib

    doc = tomllib.loads(text)
    np.testing.assert_allclose(doc["cam_1"]["translation"], cams[1].tvec * 1e3)
    assert doc["metadata"]["units"] == "mm" and "distortions" in doc["cam_0"]


def test_aniposelib_file_units():
    cams, meta = cameras_from_toml(ANIPOSE)  # no units key: default mm
    assert [c.name for c in cams] == ["A", "B"] and meta["error"] == 0.31
    np.testing.assert_allclose(cams[1].tvec, [-0.120, 0.003, 0.025])
    cams_m, _ = cameras_from_toml(ANIPOSE, units="m")  # option used when the file says nothing
    np.testing.assert_allclose(cams_m[1].tvec, [-120.0, 3.0, 25.0])
    with_key = ANIPOSE.replace("adjusted = true", 'adjusted = true\nunits = "cm"')
    cams_cm, _ = cameras_from_toml(with_key, units="m")  # the file's key wins over the option
    np.testing.assert_allclose(cams_cm[1].tvec, [-1.20, 0.03, 0.25])
    with pytest.raises(CalibrationFileError, match="units"):
        cameras_from_toml(ANIPOSE.replace("adjusted = true", 'units = "furlong"'))


def test_toml_cam_order_is_numeric_and_errors_are_named():
    text = cameras_to_toml(camera_ring(12))
    back, _ = cameras_from_toml(text)
    assert [c.name for c in back] == [f"cam{i}" for i in range(12)]
    with pytest.raises(CalibrationFileError, match=r"\[cam_1\].*translation"):
        cameras_from_toml(ANIPOSE.replace("translation = [ -120.0, 3.0, 25.0,]", ""))
    with pytest.raises(CalibrationFileError, match="fisheye"):
        cameras_from_toml(ANIPOSE.replace('name = "A"', 'name = "A"\nfisheye = true'))


@pytest.mark.parametrize("units", ["mm", "m"])
def test_yaml_round_trip(units):
    cams = camera_ring(4)
    text = cameras_to_yaml(cams, units=units, metadata={"rms_px": 0.05})
    assert "!!opencv-matrix" in text
    back, meta = cameras_from_yaml(text)
    _same(cams, back)
    assert meta["units"] == units and meta["rms_px"] == 0.05


def test_yaml_opencv_single_camera_and_stereo_layouts():
    fs = cv2.FileStorage("", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY | cv2.FILE_STORAGE_FORMAT_YAML)
    K = np.array([[532.8, 0, 342.5], [0, 532.9, 233.9], [0, 0, 1.0]])
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", np.array([[-0.281, 0.027, 0.0012, -0.00013, 0.157]]))
    cams, _ = cameras_from_yaml(fs.releaseAndGetString())
    assert len(cams) == 1 and cams[0].image_size == (640, 480)
    np.testing.assert_allclose(cams[0].K, K)
    fs = cv2.FileStorage("", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY | cv2.FILE_STORAGE_FORMAT_YAML)
    for k, v in dict(M1=K, D1=np.zeros((1, 5)), M2=K, D2=np.zeros((1, 5)), R=cv2.Rodrigues(np.array([0, 0.1, 0.0]))[0],
                     T=np.array([[-3.328], [0.037], [0.014]])).items():
        fs.write(k, v)
    cams, _ = cameras_from_yaml(fs.releaseAndGetString(), units="m")
    np.testing.assert_allclose(cams[1].tvec, [-3.328, 0.037, 0.014])
    np.testing.assert_allclose(cams[1].rvec, [0, 0.1, 0], atol=1e-12)
    with pytest.raises(CalibrationFileError, match="neither"):
        cameras_from_yaml("%YAML:1.0\n---\nfoo: 1\n")


def test_session_arrays_round_trip():
    cams = camera_ring(3)
    arrays = cameras_to_arrays(cams, rms=[0.1, 0.2, 0.3])
    assert arrays["K"].shape == (3, 3, 3) and arrays["dist"].shape == (3, 5) and arrays["image_size"].dtype == np.int64
    arrays["camera_names"] = np.array([n.encode() for n in arrays["camera_names"]])  # as h5py returns strings
    _same(cams, cameras_from_arrays(arrays))
    with pytest.raises(CalibrationFileError, match="tvec"):
        cameras_from_arrays({k: v for k, v in arrays.items() if k != "tvec"})
