"""Issue 26, items 7-11: inputs judged by physics as well as by syntax, and text from files that cannot act on
the terminal. One test per item, each asserting the message and the exit code (decision 0007: 0 complete,
1 failed, 2 bad input, 130 interrupted).
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.test_markers_csv import _write_inputs
from vfmlab.cli import main

ESC = "\x1b"


def run(capsys, *argv) -> tuple[int, str, str]:
    """``vfmlab argv`` in-process: (exit code, stdout, stderr as one line); never a traceback."""
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert "Traceback" not in err and "internal error" not in err, err
    return rc, out, " ".join(err.split())


# -- item 8: terminal escape sequences -----------------------------------------------------------------------

def test_escape_sequences_from_a_session_are_shown_escaped(tmp_path, capsys):
    markers, loads = _write_inputs(tmp_path, n_markers=12, n_steps=3)
    evil = tmp_path / f"m{ESC}]0;owned{chr(7)}.csv"  # a file name is text from outside too
    evil.write_bytes(markers.read_bytes())
    out = tmp_path / "s.h5"
    rc, _, _ = run(capsys, "import-markers", evil, loads, "--thickness-mm", "1.3", "-o", out,
                   "--specimen-id", f"A1{ESC}[2J{ESC}]0;pwned{chr(7)}", "--notes", f"note\r{ESC}[31mred\u202eevil")
    assert rc == 0
    for argv in (["info", out], ["results", out], ["info", "--json", out], ["results", "--json", out]):
        rc, text, err = run(capsys, *argv)
        assert rc == 0 and ESC not in text + err and "\r" not in text and chr(7) not in text, argv
        assert "\u202e" not in text
    rc, text, _ = run(capsys, "info", out)
    # (rich itself drops BEL and CR; the rest is shown escaped)
    assert "A1\\x1b[2J\\x1b]0;pwned" in text and "note\\x1b[31mred\\u202eevil" in text
    rc, text, _ = run(capsys, "results", out)
    assert "m\\x1b]0;owned" in text
    rc, _, err = run(capsys, "info", tmp_path / f"no{ESC}[2Jsuch.h5")
    assert rc == 2 and ESC not in err and "no\\x1b[2Jsuch.h5" in err


def test_log_lines_show_control_characters_escaped(capsys):
    import logging

    from vfmlab.cli._common import _EchoHandler

    _EchoHandler().emit(logging.LogRecord("vfmlab", logging.WARNING, __file__, 1, f"x{ESC}[2Jy", None, None))
    err = capsys.readouterr().err
    assert ESC not in err and "x\\x1b[2Jy" in err


# -- item 9: an HDF5 session with a user block -------------------------------------------------------------------

@pytest.mark.parametrize("userblock", [512, 1024, 4096])
def test_export_markers_never_overwrites_an_hdf5_file_with_a_user_block(tmp_path, capsys, userblock):
    import h5py

    markers, loads = _write_inputs(tmp_path, n_markers=12, n_steps=3)
    session = tmp_path / "s.h5"
    assert run(capsys, "import-markers", markers, loads, "--thickness-mm", "1.3", "-o", session)[0] == 0
    other = tmp_path / "U.h5"
    with h5py.File(other, "w", userblock_size=userblock) as f:
        f["entry/data"] = np.arange(10.0)
    before = other.read_bytes()
    assert before[:8] != b"\x89HDF\r\n\x1a\n" and before[userblock:userblock + 8] == b"\x89HDF\r\n\x1a\n"
    rc, _, err = run(capsys, "export-markers", session, "-o", other, "--force")
    assert rc == 1 and "is an HDF5 session file; vfmlab never overwrites a session, even with --force" in err
    assert other.read_bytes() == before
    text = tmp_path / "t.csv"  # 8 bytes that look like the signature, but not at an offset the spec allows
    text.write_bytes(b"x" * 100 + b"\x89HDF\r\n\x1a\n")
    assert run(capsys, "export-markers", session, "-o", text, "--force")[0] == 0


# -- item 7: calibration files that cannot be cameras ------------------------------------------------------------

def _calibration_text() -> str:
    from reconstruction.calibration_io import cameras_to_toml
    from rig_sim.cameras import camera_ring

    return cameras_to_toml(camera_ring(2, image_size=(64, 48)))


def _cam1(text: str, key: str, value: str) -> str:
    """``text`` with ``key`` of [cam_1] set to ``value``."""
    head, cam1 = text.split("[cam_1]")
    lines = [f"{key} = {value}" if line.startswith(f"{key} =") else line for line in cam1.split("\n")]
    return head + "[cam_1]" + "\n".join(lines)


BAD_CAMERAS = {
    "K = 0": ("matrix", "[[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]", "focal lengths fx, fy must be positive"),
    "negative focal length": ("matrix", "[[-800.0, 0.0, 32.0], [0.0, -800.0, 24.0], [0.0, 0.0, 1.0]]",
                              "focal lengths fx, fy must be positive (px); got fx = -800"),
    "booleans": ("matrix", "[[true, 0.0, 32.0], [0.0, 800.0, 24.0], [0.0, 0.0, 1.0]]", "matrix must hold numbers; got True"),
    "translation as strings": ("translation", '["0", "0", "300"]', "translation must hold numbers; got '0' (str)"),
    "principal point far outside": ("matrix", "[[800.0, 0.0, 5000.0], [0.0, 800.0, 24.0], [0.0, 0.0, 1.0]]",
                                    "principal point (5000, 24) px is far outside the 64 x 48 px image"),
    "non-finite rotation": ("rotation", "[nan, 0.0, 0.0]", "rotation must be finite numbers"),
    "infinite translation": ("translation", "[0.0, inf, 300.0]", "translation must be finite numbers"),
    "size 0 x 48": ("size", "[0, 48]", "size must be two image sides in 1..40000 px; got 0 x 48"),
}


@pytest.mark.parametrize("case", sorted(BAD_CAMERAS))
def test_calibration_that_cannot_be_a_camera_is_refused_by_every_reader(tmp_path, capsys, case):
    from reconstruction import CameraError, cameras_from_toml

    key, value, message = BAD_CAMERAS[case]
    bad = tmp_path / "bad.toml"
    bad.write_text(_cam1(_calibration_text(), key, value))
    with pytest.raises(CameraError) as info:
        cameras_from_toml(bad.read_text())
    assert message in str(info.value) and info.value.field == key and "cam_1" in str(info.value)
    session = tmp_path / "s.h5"
    from acquisition.session import CameraSpec, SessionWriter, SpecimenInfo

    with SessionWriter.create(session, SpecimenInfo("t", 0.01, 0.035, 0.001),
                              cameras=[CameraSpec(f"cam{i}", "sim", 64, 48) for i in range(2)]):
        pass
    for argv in (["calibrate", session, "--import", bad], ["calibrate", "--import", bad, "-o", tmp_path / "c.yaml"],
                 ["reconstruct", session, "--calibration", bad, "--no-store"],
                 ["import-images", tmp_path, "--calibration", bad, "--loads", tmp_path / "l.csv",
                  "--marker-diameter-mm", "0.4", "-o", tmp_path / "i.h5"]):
        rc, _, err = run(capsys, *argv)
        assert rc == 2 and message in err and str(bad) in err, (argv, err)


def test_a_valid_calibration_passes_and_a_stored_impossible_one_is_refused(tmp_path, capsys):
    from reconstruction import cameras_from_toml

    assert len(cameras_from_toml(_calibration_text())[0]) == 2
    markers, loads = _write_inputs(tmp_path, n_markers=12, n_steps=3)
    session = tmp_path / "s.h5"
    from rig_sim.synthetic_session import make_session
    from acquisition.session import write_result

    make_session(session, n_markers=20, with_results=False)
    write_result(session, "calibration", {
        "camera_names": np.array([f"cam{i}" for i in range(4)]), "K": np.zeros((4, 3, 3)), "dist": np.zeros((4, 5)),
        "rvec": np.zeros((4, 3)), "tvec": np.zeros((4, 3)), "image_size": np.tile([64, 48], (4, 1))}, {})
    rc, _, err = run(capsys, "reconstruct", session, "--no-store")
    assert rc == 2 and "stored calibration calibration_001 is unusable (camera 'cam0': matrix focal lengths" in err


def test_reconstruct_says_which_camera_saw_nothing():
    from types import SimpleNamespace

    from reconstruction import Camera
    from tests._recon_synth import camera_ring, cylinder_markers
    from vfmlab.stages.reconstruct import blind_cameras

    cams = camera_ring(3)
    pts = cylinder_markers(50)
    result = SimpleNamespace(centres=pts[None], world_to_rig=np.eye(4))
    assert blind_cameras(cams, result) == []
    c = cams[1]
    turned = Camera(c.name, c.K, c.dist, c.rvec, c.tvec + np.array([0.05, 0.0, 0.0]), c.image_size)  # looks aside
    lines = blind_cameras([cams[0], turned, cams[2]], result)
    assert len(lines) == 1 and lines[0].startswith(f"camera {c.name!r} sees only 0% of the 50 reconstructed")
