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


# -- item 10: numbers that are not what they seem ----------------------------------------------------------------

def _import(capsys, tmp_path, markers, loads, *extra, out="s.h5"):
    return run(capsys, "import-markers", markers, loads, "--thickness-mm", "1.3", "-o", tmp_path / out, *extra)


def test_a_marker_six_radii_off_the_tube_is_refused_at_import_and_identify(tmp_path, capsys):
    from acquisition.session import write_result

    markers, loads = _write_inputs(tmp_path, n_markers=40, n_steps=4, missing=False)
    lines = markers.read_text().split("\n")
    k = next(i for i, line in enumerate(lines) if line.startswith("M007,0,"))
    label, step, x, y, z = lines[k].split(",")
    lines[k] = f"{label},{step},{float(x) * 6.3:.6f},{float(y) * 6.3:.6f},{z}"  # one typo: 63 mm off a 10 mm tube
    typo = tmp_path / "typo.csv"
    typo.write_text("\n".join(lines))
    rc, _, err = _import(capsys, tmp_path, typo, loads)
    assert rc == 2 and "typo.csv, step 0: marker M007 lies 63 mm from the tube axis, 6.3 times the radius 10 mm" in err
    assert not (tmp_path / "s.h5").exists()
    # at a loaded step too; and identify refuses a stored result with such a marker
    assert _import(capsys, tmp_path, markers, loads)[0] == 0
    session = tmp_path / "s.h5"
    from acquisition.session import open_session

    with open_session(session) as s:
        arrays = dict(s.latest("markers")["arrays"])
    positions = arrays["positions"].copy()
    positions[2, 7] *= np.array([8.0, 8.0, 1.0])
    arrays["positions"] = positions
    write_result(session, "markers", arrays, {"source": "test"}, units={"positions": "m"})
    rc, _, err = run(capsys, "identify", session, "--model", "delfino")
    assert rc == 2 and "markers_002, step 2: marker M007 lies" in err and "(at most 3 radii); a typo?" in err


@pytest.mark.parametrize("text", ["1_0.5", "١٠.5", "0x10", "1e"])
def test_numbers_python_would_accept_are_refused_in_csv(tmp_path, capsys, text):
    markers, loads = _write_inputs(tmp_path, n_markers=12, n_steps=3)
    lines = markers.read_text().split("\n")
    label, step, x, y, z = lines[5].split(",")
    lines[5] = f"{label},{step},{text},{y},{z}"
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines))
    rc, _, err = _import(capsys, tmp_path, bad, loads)
    assert rc == 2 and f"bad.csv, line 6, column x_mm: {text!r} is not a number" in err
    lines = loads.read_text().split("\n")
    lines[2] = lines[2].replace("1.03", "1_0.3")
    bad_loads = tmp_path / "bad_loads.csv"
    bad_loads.write_text("\n".join(lines))
    rc, _, err = _import(capsys, tmp_path, markers, bad_loads)
    assert rc == 2 and "'1_0.300' is not a number" in err


@pytest.mark.parametrize("damage", ["short", "deleted"])
def test_damaged_marker_labels_are_reported_and_never_renumbered(tmp_path, capsys, damage):
    import h5py

    markers, loads = _write_inputs(tmp_path, n_markers=12, n_steps=3)
    session = tmp_path / "s.h5"
    assert _import(capsys, tmp_path, markers, loads)[0] == 0
    with h5py.File(session, "a") as f:
        del f["entry/results/markers_001/marker_label"]
        if damage == "short":
            f["entry/results/markers_001/marker_label"] = np.array([b"M000", b"M001"])
    rc, out, err = run(capsys, "info", session)
    assert rc == 2 and "the result 'markers_001'" in err and "is damaged" in err
    rc, _, err = run(capsys, "export-markers", session, "-o", tmp_path / "m.csv")
    assert rc == 2 and "markers_001" in err and "damaged" in err and not (tmp_path / "m.csv").exists()


@pytest.mark.parametrize("thickness,radius,message", [
    ("12", "10", "the wall thickness 12 mm is not smaller than the radius 10 mm"),
    ("0.000001", "10", "the specimen thickness 1e-06 mm is outside the plausible range 0.005..50 mm"),
])
def test_implausible_specimen_geometry_is_refused_at_import(tmp_path, capsys, thickness, radius, message):
    markers, loads = _write_inputs(tmp_path, n_markers=12, n_steps=3)
    rc, _, err = run(capsys, "import-markers", markers, loads, "--thickness-mm", thickness, "--radius-mm", radius,
                     "-o", tmp_path / "s.h5")
    assert rc == 2 and message in err


def test_a_session_whose_wall_is_thicker_than_its_radius_is_not_identified(tmp_path, capsys):
    import h5py

    markers, loads = _write_inputs(tmp_path, n_markers=40, n_steps=4)
    session = tmp_path / "s.h5"
    assert _import(capsys, tmp_path, markers, loads)[0] == 0
    with h5py.File(session, "a") as f:  # as a session recorded by another tool might say
        f["entry/sample/thickness"][...] = 0.012
    rc, _, err = run(capsys, "identify", session, "--model", "delfino")
    assert rc == 2 and "the wall thickness 12 mm is not smaller than the radius 10 mm" in err


@pytest.mark.parametrize("key,value,message", [
    ("radius_mm", "1e-6", "radius_mm: expected a plausible radius of 0.1..100 mm; got 1e-06"),
    ("thickness_mm", "1e-6", "thickness_mm: expected a plausible thickness of 0.005..50 mm; got 1e-06"),
    ("length_mm", "5000", "length_mm: expected a plausible length of 0.5..1000 mm; got 5000"),
])
def test_a_1_nm_specimen_is_refused_with_the_plausible_range(tmp_path, capsys, key, value, message):
    from pathlib import Path

    text = Path("examples/specimen.toml").read_text()
    lines = [f"{key} = {value}" if line.startswith(f"{key} ") or line.startswith(f"{key}=") else line
             for line in text.split("\n")]
    specimen = tmp_path / "specimen.toml"
    specimen.write_text("\n".join(lines))
    rc, _, err = run(capsys, "run", "examples/paper-protocol.toml", "--specimen", specimen, "--out", tmp_path / "s.h5",
                     "--sim", "--yes")
    assert rc == 2 and message in err and not (tmp_path / "s.h5").exists()


# -- items 10 and 11: work beyond the machine is refused before it starts, with the estimate ----------------------

def _levels_protocol(tmp_path, n_levels: int):
    import re
    from pathlib import Path

    text = Path("examples/paper-protocol.toml").read_text()
    levels = "[" + ", ".join(f"{150 * i / n_levels:.5f}" for i in range(n_levels)) + "]"
    text = re.sub(r"pressures_mmHg = \[.*\]", f"pressures_mmHg = {levels}", text)
    text = text.replace("dwell_s = 0.3", "dwell_s = 0.0").replace("band_mmHg = 0.1 ", "band_mmHg = 0.0001 ")
    path = tmp_path / "levels.toml"
    path.write_text(text)
    return path


def test_a_protocol_of_100001_levels_is_refused_with_its_duration(tmp_path, capsys):
    rc, _, err = run(capsys, "run", _levels_protocol(tmp_path, 100_001), "--specimen", "examples/specimen.toml",
                     "--out", tmp_path / "s.h5", "--sim", "--yes")
    assert rc == 2 and "the protocol has 100,005 steps (at most 10,000) and would take at least 19.5 h" in err  # + 4 reference captures
    assert not (tmp_path / "s.h5").exists()


def test_a_camera_of_100000_px_is_refused_with_its_memory(tmp_path, capsys):
    from pathlib import Path

    rig = tmp_path / "rig.toml"
    rig.write_text(Path("examples/sim-rig.toml").read_text().replace("width = 640, height = 480", "width = 100000, "
                                                                      "height = 480", 1))
    rc, _, err = run(capsys, "run", "examples/paper-protocol.toml", "--specimen", "examples/specimen.toml",
                     "--rig", rig, "--out", tmp_path / "s.h5", "--sim", "--yes")
    assert rc == 2 and "width must be a whole number of pixels in 1..40,000; got 100000" in err
    assert "(one 100,000 x 480 px frame is 48 MB, about 2.3 GB of memory to capture)" in err


def test_a_session_beyond_the_free_disk_or_the_memory_is_refused_with_the_estimate():
    from acquisition.errors import ImplausibleInputError
    from acquisition.plausibility import check_session_resources

    frames = [(640, 480, 1)] * 4
    check_session_resources(frames, 100, free_disk=1e9, memory=8e9, source="p.toml")
    with pytest.raises(ImplausibleInputError, match=r"p.toml: the session would need about 12.5 GB on disk \(10,000 "
                                                    r"captures x 4 camera\(s\) x 307 kB per image\) but only 1 GB"):
        check_session_resources(frames, 10_000, free_disk=1e9, memory=8e9, source="p.toml")
    with pytest.raises(ImplausibleInputError, match=r"capturing would need about 19.6 GB of memory \(largest frame "
                                                    r"400,000,000 px\) but the machine has 8 GB"):
        check_session_resources([(20_000, 20_000, 1)], 1, free_disk=1e12, memory=8e9, source="p.toml")


def test_run_refuses_a_session_that_does_not_fit_the_disk(tmp_path, capsys, monkeypatch):
    import shutil
    from collections import namedtuple

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(1e9, 1e9 - 5e6, 5e6))
    rc, _, err = run(capsys, "run", "examples/paper-protocol.toml", "--specimen", "examples/specimen.toml",
                     "--out", tmp_path / "s.h5", "--sim", "--yes")
    assert rc == 2 and "the session would need about" in err and "but only 5 MB are free there" in err
    assert not (tmp_path / "s.h5").exists()


# -- item 11: a mutation harness over every command's file inputs ---------------------------------------------------
# Deterministic (seeded) mutations of valid files; every outcome must be a success or exit 2 with a one-line
# message naming the file, never "internal error" (exit 1) and never a traceback (run() asserts both).

_ALPHABET = list("0123456789,.-+eE_ \n\"'[]{}=#xyzabn\x00\xff\u202e") + ["nan", "inf", "true", "1e400", "-0", "1_0"]


def _mutants(text: str, n: int, seed: int) -> list[str]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        t = text
        for _ in range(int(rng.integers(1, 4))):
            at = int(rng.integers(0, max(len(t), 1)))
            kind = rng.integers(0, 5)
            char = _ALPHABET[int(rng.integers(0, len(_ALPHABET)))]
            if kind == 0:
                t = t[:at] + t[at + 1:]
            elif kind == 1:
                t = t[:at] + char + t[at + 1:]
            elif kind == 2:
                t = t[:at] + char + t[at:]
            elif kind == 3:
                t = t[:at]
            else:  # a number changed by orders of magnitude
                t = t[:at] + "1e9" + t[at:]
        out.append(t)
    return out


def _judge(rc: int, err: str, path, ok=(0,)) -> None:
    assert rc in (*ok, 2), (rc, err)
    if rc == 2:
        assert "Error:" in err or "Usage:" in err, err


def test_mutated_csv_inputs_of_import_markers(tmp_path, capsys):
    markers, loads = _write_inputs(tmp_path, n_markers=12, n_steps=3)
    for i, text in enumerate(_mutants(markers.read_text(), 40, seed=1) + [""]):
        bad = tmp_path / f"m{i}.csv"
        bad.write_text(text, encoding="utf-8", errors="surrogatepass")
        rc, _, err = _import(capsys, tmp_path, bad, loads, out=f"m{i}.h5")
        _judge(rc, err, bad)
    for i, text in enumerate(_mutants(loads.read_text(), 40, seed=2)):
        bad = tmp_path / f"l{i}.csv"
        bad.write_text(text, encoding="utf-8", errors="surrogatepass")
        rc, _, err = _import(capsys, tmp_path, markers, bad, out=f"l{i}.h5")
        _judge(rc, err, bad)


def test_mutated_calibration_toml_of_calibrate_reconstruct_and_import_images(tmp_path, capsys):
    good = _calibration_text()
    for i, text in enumerate(_mutants(good, 60, seed=3)):
        bad = tmp_path / f"c{i}.toml"
        bad.write_text(text, encoding="utf-8", errors="surrogatepass")
        rc, _, err = run(capsys, "calibrate", "--import", bad, "-o", tmp_path / f"c{i}.yaml")
        _judge(rc, err, bad)
        rc, _, err = run(capsys, "import-images", tmp_path / "none", "--calibration", bad, "--loads",
                         tmp_path / "l.csv", "--marker-diameter-mm", "0.4", "-o", tmp_path / f"i{i}.h5")
        _judge(rc, err, bad, ok=())  # no images folder: refused either way


@pytest.mark.parametrize("which", ["protocol", "specimen", "rig"])
def test_mutated_toml_inputs_of_run(tmp_path, capsys, monkeypatch, which):
    from pathlib import Path

    import vfmlab.operate as operate

    def parsed(*args, **kwargs):
        raise operate.OperateError("inputs accepted", exit_code=3)  # stop before the rig starts

    monkeypatch.setattr(operate, "_sim_bench", parsed)
    codes = []
    files = {"protocol": Path("examples/paper-protocol.toml"), "specimen": Path("examples/specimen.toml"),
             "rig": Path("examples/sim-rig.toml")}
    for i, text in enumerate(_mutants(files[which].read_text(), 60, seed=4)):
        bad = tmp_path / f"{which}{i}.toml"
        bad.write_text(text, encoding="utf-8", errors="surrogatepass")
        args = {**{k: str(v) for k, v in files.items()}, which: str(bad)}
        rc, _, err = run(capsys, "run", args["protocol"], "--specimen", args["specimen"], "--rig", args["rig"],
                         "--out", tmp_path / f"s{i}.h5", "--sim", "--yes")
        _judge(rc, err, bad, ok=(3,))
        codes.append(rc)
    assert codes.count(3) >= 5 and codes.count(2) >= 5  # the mutants test both sides


def test_mutated_sessions_for_the_session_commands(tmp_path, capsys):
    markers, loads = _write_inputs(tmp_path, n_markers=12, n_steps=3)
    session = tmp_path / "s.h5"
    assert _import(capsys, tmp_path, markers, loads)[0] == 0
    data = session.read_bytes()
    rng = np.random.default_rng(5)
    for i in range(24):
        damaged = bytearray(data)
        if i % 4 == 3:
            damaged = damaged[: int(rng.integers(0, len(damaged)))]
        else:
            for where in rng.integers(0, len(damaged), 6):
                damaged[int(where)] ^= 1 << int(rng.integers(0, 8))
        bad = tmp_path / f"d{i}.h5"
        bad.write_bytes(bytes(damaged))
        for argv in (["info", bad], ["results", bad], ["export-markers", bad, "-o", tmp_path / f"d{i}.csv"]):
            rc, _, err = run(capsys, *argv)
            _judge(rc, err, bad)


def test_import_images_refuses_a_wall_thicker_than_the_radius(tmp_path, capsys):
    import cv2

    cal = tmp_path / "cal.toml"
    cal.write_text(_calibration_text())
    for cam in ("cam0", "cam1"):
        (tmp_path / "img" / cam).mkdir(parents=True)
        cv2.imwrite(str(tmp_path / "img" / cam / "0.png"), np.full((48, 64), 128, np.uint8))
    loads = tmp_path / "loads.csv"
    loads.write_text("step,pressure_mmHg,axial_force_N,stretch\n0,0,0,1\n")
    rc, _, err = run(capsys, "import-images", tmp_path / "img", "--calibration", cal, "--loads", loads,
                     "--marker-diameter-mm", "0.4", "--radius-mm", "10", "--length-mm", "30", "--thickness-mm", "12",
                     "-o", tmp_path / "s.h5")
    assert rc == 2 and "the wall thickness 12 mm is not smaller than the radius 10 mm" in err
    assert not (tmp_path / "s.h5").exists()
