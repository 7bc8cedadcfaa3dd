"""Issue 15: bad input and damaged files give one line and a meaningful exit code, never a traceback.

One test per category of the abuse campaign, each asserting the message and the exit code
(decision 0007: 0 ok, 1 failed operation, 2 bad input, 130 interrupted).
"""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest

from acquisition.errors import DamagedFileError, ImplausibleInputError, InputError, OperationError
from acquisition.session import DamagedSessionError, SessionError, SessionWriteError, open_session, write_result
from rig_sim.synthetic_session import make_session
from tests.test_markers_csv import _write_inputs
from vfmlab.cli import exit_code_for, main

SESSION_COMMANDS = {
    "info": ["info", "{s}"],
    "info --json": ["info", "--json", "{s}"],
    "results": ["results", "{s}"],
    "identify": ["identify", "{s}", "--model", "delfino"],
    "report": ["report", "{s}", "-o", "{tmp}/report"],
    "export": ["export", "{s}", "-o", "{tmp}/export"],
    "export-markers": ["export-markers", "{s}", "-o", "{tmp}/m.csv"],
    "reconstruct": ["reconstruct", "{s}", "--no-store"],
    "calibrate": ["calibrate", "{s}", "-o", "{tmp}/c.toml"],
}


def run(capsys, *argv) -> tuple[int, str]:
    """``vfmlab argv`` in-process: (exit code, stderr as one line)."""
    rc = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert "Traceback" not in err and "internal error" not in err, err
    return rc, " ".join(err.split())


@pytest.fixture(scope="module")
def full_session(tmp_path_factory):
    """A session with images, calibration, markers and identifications (rig_sim/synthetic_session.py)."""
    return make_session(tmp_path_factory.mktemp("full") / "s.h5", n_markers=60)


def _import(capsys, tmp_path, markers, loads, *extra, out="s.h5"):
    return run(capsys, "import-markers", markers, loads, "--thickness-mm", "1.3", "-o", tmp_path / out, *extra)


# -- the exit-code table ---------------------------------------------------------------------

def test_exit_codes_come_from_the_exception_types():
    assert exit_code_for(InputError("x")) == 2
    assert exit_code_for(DamagedSessionError("x")) == 2
    assert exit_code_for(ImplausibleInputError("x")) == 2
    assert exit_code_for(OperationError("x")) == 1
    assert exit_code_for(SessionWriteError("x")) == 1  # a SessionError, but a failed write
    assert exit_code_for(PermissionError(13, "Permission denied", "x.h5")) == 1
    assert exit_code_for(KeyboardInterrupt()) == 130
    assert exit_code_for(RuntimeError("bug")) == 1
    assert issubclass(DamagedSessionError, DamagedFileError) and issubclass(SessionError, InputError)


def test_usage_errors_and_unexpected_errors_are_one_line(capsys, monkeypatch):
    rc, err = run(capsys, "info", "--no-such-option")
    assert rc == 2 and "No such option" in err
    import vfmlab.cli.cmd_info as cmd_info

    monkeypatch.setattr(cmd_info, "summarise", lambda s: 1 / 0)
    assert main(["info", "whatever.h5"]) == 2  # missing file: bad input before any bug can show
    capsys.readouterr()


# -- damaged sessions --------------------------------------------------------------------------

def _damage(src, dst, how):
    shutil.copy(src, dst)
    with h5py.File(dst, "a") as f:
        if how == "steps":  # a step column whose object header is gone
            del f["entry/steps/pressure"]
            f["entry/steps/pressure"] = np.zeros((2, 2, 2))
        elif how == "log":
            del f["entry/log/pressure/value"]
        elif how == "markers":
            del f["entry/results/markers_001/positions"]
            f["entry/results/markers_001/positions"] = np.zeros((3, 5))  # 2-D positions
        elif how == "params":  # identification parameters shorter than their names
            g = f["entry/results/identification_001"]
            del g["parameters"]
            g["parameters"] = np.array([1.0])
    return dst


@pytest.mark.parametrize("how,what", [("log", "the pressure log (/entry/log/pressure)"),
                                      ("markers", "the result 'markers_001' (/entry/results/markers_001)")])
def test_info_lists_what_is_readable_and_what_is_damaged(tmp_path, capsys, full_session, how, what):
    bad = _damage(full_session, tmp_path / "bad.h5", how)
    rc = main(["info", str(bad)])
    out, err = capsys.readouterr()
    assert rc == 2
    assert "Specimen synthetic-01" in out and "Cameras:" in out  # the readable parts are shown
    assert f"{what} is damaged and cannot be read" in " ".join(err.split())


@pytest.mark.parametrize("name", list(SESSION_COMMANDS))
def test_every_session_command_on_a_damaged_dataset(tmp_path, capsys, full_session, name):
    bad = _damage(full_session, tmp_path / "bad.h5", "markers")
    argv = [a.format(s=bad, tmp=tmp_path) for a in SESSION_COMMANDS[name]]
    rc, err = run(capsys, *argv)
    if name == "report":  # the report is written from what is readable; the damage is said
        assert rc == 0 and "markers_001" in err and "is damaged" in err
    elif name in ("reconstruct", "calibrate", "results"):  # they do not need the damaged result
        assert rc in (0, 2)
    else:
        assert rc == 2, err
        assert "markers_001" in err and "is damaged and cannot be read" in err
        assert name.startswith("info") or "'vfmlab info" in err  # where to see what is still readable


def test_identification_parameters_shorter_than_names_are_damage(tmp_path, capsys, full_session):
    bad = _damage(full_session, tmp_path / "bad.h5", "params")
    with open_session(bad) as s, pytest.raises(DamagedSessionError, match="parameters must be numbers of shape"):
        s.result("identification_001")
    rc, err = run(capsys, "report", bad, "-o", tmp_path / "r")
    assert rc == 0 and "identification_001" in err


def test_short_model_parameters_give_a_warning_not_a_traceback(tmp_path, capsys, full_session):
    path = shutil.copy(full_session, tmp_path / "short.h5")
    from rig_sim.synthetic_session import add_identification

    add_identification(path, "fung", ["beta", "alpha11"], [5e3, 14.5], n_steps=7, cost=1e-3)
    rc, err = run(capsys, "report", path, "-o", tmp_path / "r")
    assert rc == 0 and "missing ['alpha22', 'alpha12']" in err


def test_bit_flips_never_escape_as_tracebacks(tmp_path, capsys, monkeypatch):
    import acquisition.session._preflight

    # a sound 20-marker session is walked in milliseconds; the flips that make HDF5 loop for ever
    # would otherwise each wait out the rig-sized 20 s limit
    monkeypatch.setattr(acquisition.session._preflight, "PREFLIGHT_TIMEOUT", 3.0)
    markers, loads = _write_inputs(tmp_path, n_markers=20)
    assert _import(capsys, tmp_path, markers, loads)[0] == 0
    data = (tmp_path / "s.h5").read_bytes()
    rng = np.random.default_rng(15)
    codes = set()
    for k in range(12):
        flipped = bytearray(data)
        for pos in rng.integers(0, 4096, 3):  # the metadata lives at the start of a small file
            flipped[pos] ^= 1 << int(rng.integers(8))
        bad = tmp_path / f"flip{k}.h5"
        bad.write_bytes(bytes(flipped))
        for name in ("info", "info --json", "export-markers", "identify"):
            (tmp_path / "m.csv").unlink(missing_ok=True)
            rc, err = run(capsys, *[a.format(s=bad, tmp=tmp_path) for a in SESSION_COMMANDS[name]])
            assert rc in (0, 2), (name, rc, err)
            assert rc == 0 or str(bad) in err
            codes.add(rc)
    assert 2 in codes  # some flips did damage the file


def test_schema_version_must_be_a_version_string(tmp_path, capsys):
    markers, loads = _write_inputs(tmp_path, n_markers=20)
    _import(capsys, tmp_path, markers, loads)
    with h5py.File(tmp_path / "s.h5", "a") as f:
        f.attrs["vfmlab_schema_version"] = 1
    rc, err = run(capsys, "info", tmp_path / "s.h5")
    assert rc == 2 and "schema version (/@vfmlab_schema_version) must be a string like '1.0'; found int64 1" in err


# -- reconstruct: cameras and images -------------------------------------------------------------

def test_reconstruct_a_calibrated_camera_without_images(tmp_path, capsys, full_session):
    bad = shutil.copy(full_session, tmp_path / "noimg.h5")
    with h5py.File(bad, "a") as f:
        del f["entry/steps/images/cam3"]
    rc, err = run(capsys, "reconstruct", bad, "--no-store")
    assert rc == 2 and "calibrated camera(s) ['cam3'] have no images in the session" in err


def test_reconstruct_images_of_another_size_than_the_calibration(tmp_path, capsys, full_session):
    path = shutil.copy(full_session, tmp_path / "size.h5")
    with open_session(path) as s:
        arrays = dict(s.latest("calibration")["arrays"])
    arrays["image_size"] = np.tile([128, 96], (4, 1))
    write_result(path, "calibration", arrays, {})
    rc, err = run(capsys, "reconstruct", path, "--no-store")
    assert rc == 2 and "camera 'cam0' was calibrated at 128x96 px but its images are 64x48 px" in err


# -- import-markers: reader bounds, file system ----------------------------------------------------

@pytest.mark.parametrize("step", ["100000000000000000000", "1e20", "9223372036854775808"])
def test_huge_step_numbers(tmp_path, capsys, step):
    markers, loads = _write_inputs(tmp_path, n_markers=20)
    text = markers.read_text().replace("\nM000,1,", f"\nM000,{step},", 1)
    markers.write_text(text)
    rc, err = _import(capsys, tmp_path, markers, loads)
    assert rc == 2 and f"column step: '{step}' is not a step number" in err


def test_output_on_a_read_only_file_system(tmp_path, capsys, monkeypatch):
    import acquisition.session._writer as session_module

    def read_only(path, *args, **kwargs):
        raise OSError(f"Unable to synchronously create file (unable to open file: name = '{path}', errno = 30, "
                      "error message = 'Read-only file system', flags = 13, o_flags = 242)")

    markers, loads = _write_inputs(tmp_path, n_markers=20)
    monkeypatch.setattr(session_module.h5py, "File", read_only)
    rc, err = _import(capsys, tmp_path, markers, loads)
    assert rc == 1 and err == f"Error: {tmp_path / 's.h5'}: cannot create the file: Read-only file system"


# -- physical plausibility ---------------------------------------------------------------------

def _loads(tmp_path, rows):
    path = tmp_path / "loads_bad.csv"
    path.write_text("step,pressure_mmHg,axial_force_N,stretch\n" + "".join(f"{r}\n" for r in rows))
    return path


@pytest.mark.parametrize("row,message", [
    ("2,-40,1,1.06", "step 2: pressure -5.333 kPa (-40 mmHg) is negative"),
    ("2,1000000,1,1.06", "step 2: pressure 1.333e+05 kPa (1e+06 mmHg) is beyond 100 kPa (750.1 mmHg)"),
    ("2,40,2000,1.06", "step 2: axial force 2000 N is beyond the load cell's 200 N (kN or mN given"),
    ("2,40,1,3.5", "step 2: axial stretch 3.5 is outside (0.5, 3.0)"),
    ("2,40,1,0.4", "step 2: axial stretch 0.4 is outside (0.5, 3.0)"),
])
def test_implausible_loads_are_refused(tmp_path, capsys, row, message):
    markers, _ = _write_inputs(tmp_path, n_markers=20)
    loads = _loads(tmp_path, ["0,0,0,1", "1,20,0.5,1.03", row, "3,60,1.5,1.09"])
    rc, err = _import(capsys, tmp_path, markers, loads)
    assert rc == 2 and message in err, err


def test_unusual_values_are_accepted_stored_and_shown(tmp_path, capsys):
    markers, _ = _write_inputs(tmp_path, n_markers=20)
    loads = _loads(tmp_path, ["0,0,0,1", "1,20,0.5,0.97", "2,350,1,1.06", "3,60,1.5,1.09"])
    rc, err = _import(capsys, tmp_path, markers, loads)
    assert rc == 0 and "Warning: " in err and "axial stretch 0.97 is below 1" in err
    assert "pressure 46.66 kPa (350 mmHg) is above the usual 40 kPa (300 mmHg)" in err
    rc = main(["info", str(tmp_path / "s.h5")])
    out = " ".join(capsys.readouterr().out.split())
    assert rc == 0 and "axial stretch 0.97 is below 1" in out and "(300 mmHg)" in out
    from vfmlab.report import build_report

    page = build_report(tmp_path / "s.h5", tmp_path / "report").read_text(encoding="utf-8")
    assert "<td>input warnings</td>" in page and "axial stretch 0.97 is below 1" in page


@pytest.mark.parametrize("scale,extra,message", [
    (1e-3, [], "mm; expected 0.1..100 mm (metres given where mm expected?)"),
    (1e-3, ["--radius-mm", "10"], "mm but the specimen radius is 10 mm; expected within a factor "
                                  "of 2 (metres given where mm expected?)"),
    (1.0, ["--radius-mm", "2000"], "mm but the specimen radius is 2000 mm; expected within a factor of 2"),
    (1.0, ["--radius-mm", "1e6"], "mm but the specimen radius is 1e+06 mm; expected within a factor of 2"),
    (1.0, ["--radius-mm", "0"], "--radius-mm must be a positive length in mm; got 0.0"),
    (1.0, ["--radius-mm", "10", "--thickness-mm", "12"], "the wall thickness 12 mm is not smaller than the radius "
                                                         "10 mm"),
    (5e3, [], "mm; expected 0.1..100 mm (µm given where mm expected?)"),
])
def test_geometry_and_units(tmp_path, capsys, scale, extra, message):
    markers, loads = _write_inputs(tmp_path, n_markers=20, missing=False)
    lines = markers.read_text().splitlines()
    rows = [line.split(",") for line in lines[1:]]
    markers.write_text("\n".join([lines[0]] + [",".join(r[:2] + [f"{float(v) * scale:.9g}" for v in r[2:]])
                                               for r in rows]) + "\n")
    rc, err = _import(capsys, tmp_path, markers, loads, *extra)
    assert rc == 2 and message in err, err


def test_2_m_specimen_from_a_toml_like_radius_option_is_refused_without_warnings(tmp_path, capsys):
    markers, loads = _write_inputs(tmp_path, n_markers=20)
    rc, err = _import(capsys, tmp_path, markers, loads, "--radius-mm", "2000")
    assert rc == 2 and "RuntimeWarning" not in err


@pytest.mark.parametrize("n_markers,collinear,message", [
    (3, False, "step 0: 3 marker(s) measured; at least 8 are needed to mesh the specimen surface"),
    (2, False, "step 0: 2 marker(s) measured; at least 8"),
    (20, True, "the 20 reference markers lie on one line"),
])
def test_too_few_or_collinear_markers(tmp_path, capsys, n_markers, collinear, message):
    markers, loads = _write_inputs(tmp_path, n_markers=n_markers, missing=False)
    if collinear:
        lines = markers.read_text().splitlines()
        markers.write_text("\n".join([lines[0]] + [f"{r.split(',')[0]},{r.split(',')[1]},10,0,{i % 20}"
                                                   for i, r in enumerate(lines[1:])]) + "\n")
    rc, err = _import(capsys, tmp_path, markers, loads)
    assert rc == 2 and message in err, err


def test_all_nan_reference_step(tmp_path, capsys):
    markers, loads = _write_inputs(tmp_path, n_markers=20, missing=False)
    lines = markers.read_text().splitlines()
    markers.write_text("\n".join([lines[0]] + [(",".join(r.split(",")[:2]) + ",,," if r.split(",")[1] == "0" else r)
                                               for r in lines[1:]]) + "\n")
    rc, err = _import(capsys, tmp_path, markers, loads)
    assert rc == 2 and "step 0: no marker has coordinates at the reference step" in err
    assert "RuntimeWarning" not in err


def test_one_step_or_an_all_nan_loaded_step_is_imported_but_not_identified(tmp_path, capsys):
    markers, loads = _write_inputs(tmp_path, n_markers=20, n_steps=1)
    rc, err = _import(capsys, tmp_path, markers, loads)
    assert rc == 0 and "1 step(s); identification needs the reference and at least two loaded steps" in err
    rc, err = run(capsys, "identify", tmp_path / "s.h5")
    assert rc == 2 and "1 step(s); identification needs the reference and at least two loaded steps" in err

    markers, loads = _write_inputs(tmp_path, n_markers=20, n_steps=3, missing=False)
    lines = markers.read_text().splitlines()
    markers.write_text("\n".join([lines[0]] + [(",".join(r.split(",")[:2]) + ",,," if r.split(",")[1] == "2" else r)
                                               for r in lines[1:]]) + "\n")
    rc, err = _import(capsys, tmp_path, markers, loads, out="t.h5")
    assert rc == 0 and "steps [2] have no measured marker" in err
    rc, err = run(capsys, "identify", tmp_path / "t.h5")
    assert rc == 2 and "identification needs the reference and at least two loaded steps with markers" in err


def test_huge_coordinates_are_refused_by_the_reader(tmp_path, capsys):
    markers, loads = _write_inputs(tmp_path, n_markers=20)
    markers.write_text(markers.read_text().replace("\nM001,0,", "\nM001,0,1e300,", 1).replace("1e300,", "1e300,", 1))
    text = markers.read_text().splitlines()
    text[2] = "M001,0,1e300,1,1"
    markers.write_text("\n".join(text) + "\n")
    rc, err = _import(capsys, tmp_path, markers, loads)
    assert rc == 2 and "line 3, column x_mm: '1e300' mm is not a marker coordinate (expected within 100 m" in err


# -- warnings and Ctrl-C --------------------------------------------------------------------------

def test_library_warnings_never_reach_the_user(capsys, monkeypatch):
    import vfmlab.cli.cmd_info as cmd_info

    def noisy(path):
        np.nanmean(np.array([np.nan]))  # RuntimeWarning: Mean of empty slice
        raise SessionError(f"{path}: no such file")

    monkeypatch.setattr(cmd_info, "cli_session", noisy)
    rc, err = run(capsys, "info", "x.h5")
    assert rc == 2 and err == "Error: x.h5: no such file"


def test_ctrl_c_during_report_exits_130_without_traceback(tmp_path, full_session):
    out = tmp_path / "report"
    proc = subprocess.Popen([sys.executable, "-m", "vfmlab", "report", str(full_session), "-o", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    # the report is built in a staging folder beside its place (renamed into place when complete): made first
    while not (out.exists() or any(tmp_path.glob(".report.*.part"))) and proc.poll() is None:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "Interrupted." in err
    # a loaded machine may deliver the signal only after the page was written (the report of this small
    # session takes ~1 s): then the page must be whole; a half page never appears under its name
    page = out / "report.html"
    assert not page.exists() or page.read_text(encoding="utf-8").rstrip().endswith("</html>")
