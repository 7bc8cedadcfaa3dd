import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from acquisition.session import (
    CameraSpec,
    SessionError,
    SessionWriter,
    SpecimenInfo,
    StepRecord,
    open_session,
    write_result,
)

SPEC = SpecimenInfo("A1", radius=10e-3, length=35e-3, thickness=1.3e-3, notes="ascending aorta")
CAMS = [CameraSpec("cam0", "sim", 64, 48), CameraSpec("cam1", "sim", 64, 48)]


def _step(i: int) -> StepRecord:
    return StepRecord(block=0, stretch=1.1, target_pressure=1000.0 * i, pressure=1000.0 * i + 3,
                      force=0.1 * i, t_monotonic=float(i), t_wall=1.7e9 + i)


def _frames(i: int) -> dict[str, np.ndarray]:
    return {c.name: np.full((48, 64), i, dtype=np.uint8) for c in CAMS}


def test_round_trip(tmp_path):
    path = tmp_path / "s.h5"
    with SessionWriter.create(path, SPEC, cameras=CAMS, protocol_text="[test]\n", rig={"a": 1},
                              instruments={"pressure": {"identity": "MENSOR,CPC6050", "settings": {"units": 19}}},
                              load_cell_measures="total") as w:
        w.append_log("pressure", [1.0, 2.0], [10.0, 11.0], [5.0, 6.0], [" 5", " 6"], seq=[0, 1])
        for i in range(3):
            w.add_step(_step(i), _frames(i))
        w.add_step(StepRecord(0, 1.1, 2000.0, 2001.0, 0.2, 4.0, 1.7e9 + 4, supersedes=2), _frames(7))
        w.add_calibration_view({"cam0": np.ones((48, 64), np.uint8)})
        w.add_event("note", "operator: bubble removed")
    with open_session(path) as s:
        assert s.status == "complete"
        assert s.specimen == SPEC
        assert s.n_steps == 4
        assert s.load_cell_measures == "total"
        assert s.instruments["pressure"]["identity"] == "MENSOR,CPC6050"
        assert s.instruments["pressure"]["settings"] == {"units": 19}
        steps = s.steps
        np.testing.assert_array_equal(steps["active"], [True, True, False, True])
        np.testing.assert_allclose(steps["pressure"], [3.0, 1003.0, 2003.0, 2001.0])
        assert s.image("cam1", 3)[0, 0] == 7
        assert s.calibration_images("cam0").shape == (1, 48, 64)
        assert s.calibration_images("cam1")[0].max() == 0  # camera not in that view: blank frame
        log = s.log("pressure")
        np.testing.assert_array_equal(log["value"], [5.0, 6.0])
        assert list(log["raw"]) == [" 5", " 6"]
        assert s.events()[0]["message"] == "operator: bubble removed"
        assert s.protocol_text == "[test]\n"
        assert len(s.protocol_sha256) == 64
    # plain h5py can read everything without our code
    with h5py.File(path, "r") as f:
        assert f["entry/steps/images/cam0"].chunks == (1, 48, 64)
        assert f["entry/steps/images/cam0"].compression == "gzip"
        assert f["entry/sample/radius"].attrs["units"] == "m"


def test_results_never_overwrite(tmp_path):
    path = tmp_path / "s.h5"
    with SessionWriter.create(path, SPEC) as w:
        w.add_step(_step(0))
    positions = np.zeros((1, 5, 3))
    a = write_result(path, "markers", {"positions": positions, "camera_names": np.array(["a", "b"])},
                     {"method": "x"}, attrs={"flags": ["alpha12"]}, units={"positions": "m"})
    b = write_result(path, "markers", {"positions": positions + 1}, {"method": "y"})
    assert (a, b) == ("markers_001", "markers_002")
    with open_session(path) as s:
        assert s.results("markers") == [a, b]
        latest = s.latest("markers")
        assert latest["parameters"] == {"method": "y"}
        assert latest["arrays"]["positions"][0, 0, 0] == 1
        first = s.result(a)
        assert first["units"]["positions"] == "m"
        assert first["attrs"]["flags"] == ["alpha12"]
        assert list(first["arrays"]["camera_names"]) == ["a", "b"]
        assert s.latest("identification") is None


def test_refuses_to_overwrite_existing_file(tmp_path):
    path = tmp_path / "s.h5"
    SessionWriter.create(path, SPEC).close()
    with pytest.raises(SessionError, match="exists"):
        SessionWriter.create(path, SPEC)


def test_add_step_requires_every_camera(tmp_path):
    with SessionWriter.create(tmp_path / "s.h5", SPEC, cameras=CAMS) as w:
        with pytest.raises(ValueError, match="cam1"):
            w.add_step(_step(0), {"cam0": np.zeros((48, 64), np.uint8)})
        with pytest.raises(ValueError, match="shape"):
            w.add_step(_step(0), {"cam0": np.zeros((48, 64)), "cam1": np.zeros((2, 2))})


def test_specimen_in_mm_is_rejected():
    with pytest.raises(ValueError, match="metres"):
        SpecimenInfo("x", radius=10.0, length=35e-3, thickness=1.3e-3)


def test_exception_marks_session_aborted(tmp_path):
    path = tmp_path / "s.h5"
    with pytest.raises(RuntimeError):
        with SessionWriter.create(path, SPEC) as w:
            w.add_step(_step(0))
            raise RuntimeError("boom")
    with open_session(path) as s:
        assert s.status == "aborted"
        assert s.n_steps == 1


def test_sigkill_mid_session_loses_no_completed_step(tmp_path):
    """A real writer process is killed while writing; every step it reported complete survives."""
    path, ready = tmp_path / "crash.h5", tmp_path / "ready.txt"
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    proc = subprocess.Popen([sys.executable, str(Path(__file__).with_name("session_writer_child.py")),
                             str(path), str(ready)], env=env)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            if ready.exists() and len(ready.read_text().split()) >= 5:
                break
            assert proc.poll() is None, "writer process died on its own"
            time.sleep(0.05)
        else:
            pytest.fail("writer did not complete 5 steps in 60 s")
        # A reader can open the file while it is being written.
        with open_session(path) as live:
            assert live.status == "running"
            assert live.n_steps >= 5
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    completed = [int(x) for x in ready.read_text().split()]
    with open_session(path) as s:
        assert s.status == "interrupted"
        assert s.n_steps >= len(completed)
        steps = s.steps
        np.testing.assert_allclose(steps["target_pressure"][: len(completed)], np.array(completed) * 100.0)
        last = len(completed) - 1
        assert s.image("cam0", last).shape == (240, 320)
        assert len(s.log("pressure")["value"]) >= len(completed)
    # The interrupted session can be resumed and completed.
    with SessionWriter.resume(path) as w:
        n_before = w.n_steps
        w.add_step(StepRecord(0, 1.1, 0.0, 0.0, 0.0, 0.0, 0.0), {"cam0": np.zeros((240, 320), np.uint8)})
    with open_session(path) as s:
        assert s.status == "complete"
        assert s.n_steps == n_before + 1
        assert [e["kind"] for e in s.events()] == ["resume"]


def test_resume_refuses_complete_session(tmp_path):
    path = tmp_path / "s.h5"
    SessionWriter.create(path, SPEC).close()
    with pytest.raises(SessionError, match="only an interrupted session"):
        SessionWriter.resume(path)


# -- bad files: one readable message each ---------------------------------------------------

def test_missing_file(tmp_path):
    with pytest.raises(SessionError, match="no such file"):
        open_session(tmp_path / "nope.h5")


def test_not_hdf5(tmp_path):
    path = tmp_path / "x.h5"
    path.write_text("marker_id,step\n")
    with pytest.raises(SessionError, match="not HDF5"):
        open_session(path)


def test_hdf5_but_not_a_session(tmp_path):
    path = tmp_path / "x.h5"
    with h5py.File(path, "w") as f:
        f["data"] = [1, 2]
    with pytest.raises(SessionError, match="not a vfmlab session"):
        open_session(path)


@pytest.mark.parametrize("version,word", [("2.0", "newer"), ("0.3", "older")])
def test_other_schema_version(tmp_path, version, word):
    path = tmp_path / "s.h5"
    SessionWriter.create(path, SPEC).close()
    with h5py.File(path, "a") as f:
        f.attrs["vfmlab_schema_version"] = version
    with pytest.raises(SessionError, match=word):
        open_session(path)


def test_truncated_file(tmp_path):
    path = tmp_path / "s.h5"
    with SessionWriter.create(path, SPEC, cameras=CAMS) as w:
        for i in range(3):
            w.add_step(_step(i), {c.name: np.random.default_rng(i).integers(0, 255, (48, 64), np.uint8) for c in CAMS})
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(SessionError, match="truncated|damaged"):
        open_session(path)


def test_missing_required_group(tmp_path):
    path = tmp_path / "s.h5"
    SessionWriter.create(path, SPEC).close()
    with h5py.File(path, "a") as f:
        del f["entry/steps"]
    with pytest.raises(SessionError, match="/entry/steps"):
        open_session(path)


def test_resume_drops_half_appended_records(tmp_path):
    """A kill between the columns of one append leaves ragged tables; resume cuts them back."""
    path = tmp_path / "s.h5"
    w = SessionWriter.create(path, SPEC, cameras=CAMS)
    w.append_log("force", [1.0], [2.0], [3.0], ["3"])
    w.add_step(_step(0), _frames(0))
    w.close(status="interrupted")
    with h5py.File(path, "a") as f:  # simulate a kill mid-append: some columns one row longer
        for name in ("time", "monotonic_time"):
            ds = f["entry/log/force"][name]
            ds.resize((2,))
        f["entry/steps/images/cam0"].resize((2, 48, 64))
        f["entry/steps/block"].resize((2,))
    with open_session(path) as s:
        assert s.status == "interrupted"
        assert s.n_steps == 1
        assert len(s.steps["pressure"]) == 1
    with SessionWriter.resume(path) as w:
        w.append_log("force", [5.0], [6.0], [7.0], ["7"])
        w.add_step(_step(1), _frames(1))
    with open_session(path) as s:
        np.testing.assert_array_equal(s.log("force")["value"], [3.0, 7.0])
        np.testing.assert_array_equal(s.log("force")["t_monotonic"], [1.0, 5.0])
        assert s.n_steps == 2
        assert s.image("cam0", 1)[0, 0] == 1
        assert "dropped partial records" in s.events()[0]["message"]


def test_results_can_be_added_to_an_interrupted_session(tmp_path):
    path = tmp_path / "s.h5"
    w = SessionWriter.create(path, SPEC)
    w.add_step(_step(0))
    w.close(status="interrupted")
    write_result(path, "markers", {"positions": np.zeros((1, 2, 3))}, {})
    with open_session(path) as s:
        assert s.status == "interrupted"
        assert s.results() == ["markers_001"]


# -- the damaged-file check (structure walk in a child) ----------------------------------------

def _count_walks(monkeypatch) -> list:
    import acquisition.session._preflight as session_module

    forks = []
    original = session_module._fork_walk
    monkeypatch.setattr(session_module, "_fork_walk", lambda path, timeout: forks.append(path) or original(path, timeout))
    return forks


def test_walk_not_repeated_while_a_quiet_file_is_unchanged(tmp_path, monkeypatch):
    import acquisition.session._preflight as session_module

    path = tmp_path / "s.h5"
    SessionWriter.create(path, SPEC).close()
    monkeypatch.setattr(session_module, "QUIET_BEFORE_WALK", -1.0)  # the file counts as long untouched
    forks = _count_walks(monkeypatch)
    open_session(path).close()
    open_session(path).close()
    assert len(forks) == 1
    write_result(path, "markers", {"positions": np.zeros((1, 2, 3))}, {})  # its own open: still unchanged
    assert len(forks) == 1
    open_session(path).close()  # a result is a file of its own: the session is unchanged, not walked again
    assert len(forks) == 1
    with open(path, "r+b") as fh:  # a change of the session file itself: walked again
        fh.seek(0, os.SEEK_END)
        fh.write(b"\0")
    open_session(path).close()
    assert len(forks) == 2


def test_a_recently_written_file_is_walked_at_every_open(tmp_path, monkeypatch):
    path = tmp_path / "s.h5"
    SessionWriter.create(path, SPEC).close()
    forks = _count_walks(monkeypatch)
    open_session(path).close()
    open_session(path).close()
    assert len(forks) == 2  # written < QUIET_BEFORE_WALK s ago: its stat could miss a same-size rewrite


def test_walk_started_ahead_is_waited_for(tmp_path, monkeypatch):
    import acquisition.session._preflight as session_module

    path = tmp_path / "s.h5"
    SessionWriter.create(path, SPEC).close()
    forks = _count_walks(monkeypatch)
    session_module.start_preflight(path)
    with open_session(path) as s:
        assert s.specimen.specimen_id == "A1"
    assert len(forks) == 1  # the walk started ahead was the open's walk


def test_walk_started_ahead_that_hangs_is_a_damaged_file(tmp_path, monkeypatch):
    import acquisition.session._preflight as session_module

    path = tmp_path / "s.h5"
    SessionWriter.create(path, SPEC).close()
    monkeypatch.setattr(session_module, "_walk_structure", lambda path: time.sleep(60))  # HDF5 looping on a header
    session_module.start_preflight(path)
    pid = session_module._pending[1]
    with pytest.raises(SessionError, match="does not finish reading its structure"):
        session_module._preflight(path, timeout=0.5)
    with pytest.raises(ChildProcessError):  # killed and reaped
        os.waitpid(pid, os.WNOHANG)
