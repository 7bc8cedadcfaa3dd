"""Camera interface: every backend opens, configures with read-back, grabs frames; errors are typed."""

import os
import subprocess
import sys
import time

import cv2
import numpy as np
import pytest

from acquisition.cameras import (CameraConfigError, CameraDisconnected, CameraExhausted, CameraNotFound,
                                 CameraTimeout, CaptureError, FolderCamera, FunctionCamera, capture_all, open_camera,
                                 to_mono)
from acquisition.cameras.basler import pylon_available


def _ramp(settings):
    h, w = settings["height"], settings["width"]
    return (np.add.outer(np.arange(h), np.arange(w)) % 256).astype(np.uint8)


def test_function_camera_configure_readback_and_frames():
    with FunctionCamera("c0", _ramp, {"width": 64, "height": 48}) as cam:
        assert cam.settings["width"] == 64
        back = cam.configure(exposure_us=2000.0)
        assert back["exposure_us"] == 2000.0 and back["height"] == 48
        f0, f1 = cam.grab(1.0), cam.grab(1.0)
        assert f0.pixels.shape == (48, 64) and f0.pixels.dtype == np.uint8 and f0.camera == "c0"
        assert (f0.frame_id, f1.frame_id) == (0, 1)
        assert f1.t_monotonic >= f0.t_monotonic and abs(f0.t_wall - time.time()) < 5
        assert f1.device_timestamp > f0.device_timestamp
        with pytest.raises(CameraConfigError, match="setting 'shutter' is not supported by the sim backend"):
            cam.configure(shutter=3)
        cam.unplugged = True
        with pytest.raises(CameraDisconnected, match="camera 'c0'"):
            cam.grab(1.0)
    with pytest.raises(CameraDisconnected, match="not open"):
        cam.grab(1.0)


def test_readback_mismatch_is_a_config_error():
    class Clamping(FunctionCamera):
        def _configure(self, settings):
            out = super()._configure(settings)
            out["width"] = min(out["width"], 100)
            return out

    cam = Clamping("c", _ramp, {"width": 64, "height": 48}).open()
    with pytest.raises(CameraConfigError, match=r"setting 'width': asked for 200, device reads back 100"):
        cam.configure(width=200)


def test_capture_all_reports_each_failed_camera():
    cams = [FunctionCamera(f"c{i}", _ramp, {"width": 32, "height": 24}).open() for i in range(4)]
    res = capture_all(cams, timeout=2.0)
    assert sorted(res.frames) == ["c0", "c1", "c2", "c3"] and res.spread_s < 1.0
    cams[1].unplugged = True
    cams[3].stalled = True
    t0 = time.monotonic()
    with pytest.raises(CaptureError) as info:
        capture_all(cams, timeout=0.3)
    assert time.monotonic() - t0 < 1.5
    assert sorted(info.value.failures) == ["c1", "c3"]
    assert isinstance(info.value.failures["c1"], CameraDisconnected)
    assert isinstance(info.value.failures["c3"], CameraTimeout)
    assert sorted(info.value.frames) == ["c0", "c2"]
    assert "c1" in str(info.value) and "c3" in str(info.value)


def test_simulated_cameras_are_not_timed_out_by_a_slow_machine():
    """A simulated camera's frame takes what its rendering takes (a loaded machine): capture_all waits for it;
    a real-time camera that slow is a timeout."""
    def slow(settings):
        time.sleep(0.4)
        return _ramp(settings)

    class RealTime(FunctionCamera):
        real_time = True

    sims = [FunctionCamera(f"s{i}", slow, {"width": 32, "height": 24}).open() for i in range(2)]
    res = capture_all(sims, timeout=0.05)
    assert sorted(res.frames) == ["s0", "s1"]
    with pytest.raises(CaptureError) as info:
        capture_all([RealTime("r", slow, {"width": 32, "height": 24}).open(), sims[0]], timeout=0.05)
    assert sorted(info.value.failures) == ["r"] and isinstance(info.value.failures["r"], CameraTimeout)
    sims[1].stalled = True  # a simulated stall is still a timeout
    with pytest.raises(CaptureError, match="s1"):
        capture_all(sims, timeout=0.05)


def test_folder_camera_replays_in_order(tmp_path):
    for i in range(3):
        cv2.imwrite(str(tmp_path / f"img_{i:03d}.png"), np.full((20, 30), 10 * i, np.uint8))
    cv2.imwrite(str(tmp_path / "colour_x.png"), np.zeros((20, 30, 3), np.uint8))
    with open_camera("f", "folder", {"path": str(tmp_path), "pattern": "img_*"}) as cam:
        assert cam.settings["n_images"] == 3 and (cam.settings["width"], cam.settings["height"]) == (30, 20)
        values = [int(cam.grab(1.0).pixels[0, 0]) for _ in range(3)]
        assert values == [0, 10, 20]
        with pytest.raises(CameraExhausted, match="all 3 images replayed"):
            cam.grab(1.0)
        cam.configure(loop=True)
        assert cam.grab(1.0).pixels[0, 0] == 0
    with pytest.raises(CameraNotFound, match="does not exist"):
        FolderCamera("g", {"path": str(tmp_path / "missing")}).open()


def test_opencv_camera_on_an_image_sequence(tmp_path):
    for i in range(3):
        img = np.zeros((24, 32, 3), np.uint8)
        img[..., 2] = 50 * (i + 1)  # red channel
        cv2.imwrite(str(tmp_path / f"seq_{i:03d}.png"), img)
    cam = open_camera("cv", "opencv", {"device": str(tmp_path / "seq_%03d.png")})
    with cam:
        assert (cam.settings["width"], cam.settings["height"]) == (32, 24)
        frames = [cam.grab(2.0) for _ in range(3)]
        assert [f.frame_id for f in frames] == [0, 1, 2]
        assert frames[1].pixels.shape == (24, 32)
        assert int(frames[1].pixels[0, 0]) == round(0.299 * 100)
    with pytest.raises(CameraNotFound, match="OpenCV cannot open"):
        open_camera("cv", "opencv", {"device": str(tmp_path / "none_%03d.png")}).open()


def test_to_mono_and_unknown_backend():
    assert to_mono(np.full((2, 2, 3), 255, np.uint8)).tolist() == [[255, 255], [255, 255]]
    with pytest.raises(ValueError, match=r"'sim' cameras exist only with --sim"):
        open_camera("x", "sim")


BASLER_SCRIPT = r"""
import numpy as np
from acquisition.cameras import open_camera, CameraConfigError, CameraNotFound
cam = open_camera("b", "basler", {"serial": "0815-0001", "width": 320, "height": 240, "exposure_us": 5000.0})
with cam:
    assert cam.identity.endswith("0815-0001"), cam.identity
    assert (cam.settings["width"], cam.settings["height"]) == (320, 240), cam.settings
    f0, f1 = cam.grab(2.0), cam.grab(2.0)
    assert f0.pixels.shape == (240, 320) and f0.pixels.dtype == np.uint8
    assert f1.frame_id > f0.frame_id or f1.device_timestamp >= f0.device_timestamp
    try:
        cam.configure(width=100000)
    except CameraConfigError as e:
        print("refused:", e)
    else:
        raise SystemExit("width=100000 accepted")
try:
    open_camera("n", "basler", {"serial": "nope"}).open()
except CameraNotFound as e:
    print("notfound:", e)
print("OK")
"""


@pytest.mark.skipif(not pylon_available(), reason="pypylon is not installed (pip install pypylon)")
def test_basler_backend_against_pylon_camera_emulation():
    # pylon reads PYLON_CAMEMU when its transport layers load: use a fresh process.
    env = dict(os.environ, PYLON_CAMEMU="2", PYTHONPATH=os.getcwd())
    out = subprocess.run([sys.executable, "-c", BASLER_SCRIPT], env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr + out.stdout
    assert "OK" in out.stdout and "refused: camera 'b'" in out.stdout and "notfound: camera 'n'" in out.stdout
