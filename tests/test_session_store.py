"""Issue 26, items 1-6: derived results beside the session, bound to it; a real full disk (tmpfs); the
test's own writer (run, resume, import-markers) at a full disk and after a kill; no journal applied."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rig_sim.synthetic_session import make_session
from acquisition.session import (CameraSpec, SessionWriter, SpecimenInfo, StepRecord, copy_session, open_session,
                                 results_dir, write_result)
from vfmlab.cli import main

ROOT = Path(__file__).resolve().parents[1]
SPEC = SpecimenInfo("s", 0.01, 0.03, 0.001)


def _env():
    return dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    return make_session(tmp_path_factory.mktemp("store") / "base.h5")


def _markers_csv(folder: Path, n_markers: int = 60, n_steps: int = 6) -> tuple[Path, Path]:
    markers, loads = folder / "m.csv", folder / "l.csv"
    rows = ["marker_id,step,x_mm,y_mm,z_mm"]
    for s in range(n_steps):
        for i in range(n_markers):
            th = 2 * np.pi * (i % 20) / 20
            r = 10 * (1 + 0.01 * s)
            rows.append(f"{i},{s},{r * np.cos(th):.4f},{r * np.sin(th):.4f},{(i // 20) * 2.0:.3f}")
    markers.write_text("\n".join(rows) + "\n")
    loads.write_text("step,pressure_kPa,axial_force_N,stretch\n"
                     + "".join(f"{s},{s},{0.1 * s},{1 + 0.01 * s}\n" for s in range(n_steps)))
    return markers, loads


# ---------------------------------------------------------------- item 1: results are files of their own
def test_a_result_is_its_own_file_listed_by_a_manifest_bound_to_the_session(base, tmp_path):
    path = copy_session(base, tmp_path / "s.h5")
    original = path.read_bytes()
    name = write_result(path, "markers", {"positions": np.zeros((2, 3, 3))}, {"k": 1}, attrs={"flags": {"a": "b"}})
    assert path.read_bytes() == original  # the session file is only read
    manifest = json.loads((results_dir(path) / "manifest.json").read_text())
    with open_session(path) as s:
        assert manifest["session"]["uuid"] == s.uuid and len(s.uuid) == 32
        assert s.results()[-1] == name == "markers_002"  # numbered after the result inside the file
        assert s.result(name)["attrs"]["flags"] == {"a": "b"} and s.result(name)["parameters"] == {"k": 1}
    assert [e["name"] for e in manifest["results"]] == [name]
    assert (results_dir(path) / f"{name}.h5").stat().st_size == manifest["results"][0]["size"]


def test_a_damaged_result_file_is_reported_and_the_others_read(base, tmp_path, capsys):
    path = copy_session(base, tmp_path / "s.h5")
    name = write_result(path, "markers", {"positions": np.zeros((2, 3, 3))}, {})
    file = results_dir(path) / f"{name}.h5"
    file.write_bytes(file.read_bytes()[:-10] + b"0123456789")
    assert main(["info", str(path)]) != 0  # a damaged part: an error exit, the rest shown
    err = " ".join(capsys.readouterr().err.split())
    assert "markers_002.h5: 6136 bytes whose checksum does not match the manifest" in err
    assert "everything else shown is readable" in err
    with open_session(path) as s:
        assert s.result("markers_001")["arrays"]["positions"].shape[2] == 3


# ---------------------------------------------------------------- item 4: bound to the file, no journal
def test_results_of_another_session_are_never_applied(base, tmp_path, capsys):
    path = copy_session(base, tmp_path / "s.h5")
    write_result(path, "markers", {"positions": np.zeros((2, 3, 3))}, {})
    other = make_session(tmp_path / "other.h5", seed=3)
    shutil.copyfile(other, path)  # another session copied onto the name, its results folder left behind
    with open_session(path) as s:
        assert "markers_002" not in s.results() and "holds the results of another session" in s.results_note
    assert main(["info", str(path)]) == 0
    said = capsys.readouterr()
    assert "holds the results of another session" in " ".join((said.out + said.err).split())
    name = write_result(path, "markers", {"positions": np.ones((2, 3, 3))}, {})
    assert name == "markers_003"  # never the number of a file on disk
    aside = [p.name for p in results_dir(path).iterdir() if p.name.startswith("manifest-of-")]
    assert len(aside) == 1  # the other session's list is kept, not deleted
    with open_session(path) as s:
        assert s.results("markers") == ["markers_001", "markers_003"]


def test_a_leftover_journal_is_never_applied_nor_deleted(base, tmp_path, capsys):
    path = copy_session(base, tmp_path / "s.h5")
    original = path.read_bytes()
    journal = tmp_path / "s.h5.journal"
    for content in (b"my notes", b"VFMLAB-H5-JOURNAL-1\n" + (40).to_bytes(8, "little") + b"\0" * 16):
        journal.write_bytes(content)
        assert main(["info", str(path), "--json"]) == 0
        assert journal.read_bytes() == content and path.read_bytes() == original
    capsys.readouterr()


def test_import_under_a_reused_name_moves_the_old_results_aside(tmp_path, capsys):
    markers, loads = _markers_csv(tmp_path)
    out = tmp_path / "a.h5"
    args = ["import-markers", str(markers), str(loads), "-o", str(out), "--thickness-mm", "1"]
    assert main(args) == 0
    write_result(out, "identification", {"parameters": np.ones(2)}, {})
    out.unlink()  # the session deleted, its results folder left behind; then imported again under the name
    assert main(args) == 0
    with open_session(out) as s:
        assert s.results() == ["markers_001"] and not s.results_note
    assert (tmp_path / "a.h5.results.replaced-1" / "identification_001.h5").exists()
    capsys.readouterr()


# ---------------------------------------------------------------- item 2: every image with its row
def test_an_extra_frame_without_its_row_is_not_a_step_and_is_replaced(tmp_path):
    import h5py

    path = tmp_path / "s.h5"
    w = SessionWriter.create(path, SPEC, cameras=[CameraSpec("cam0", "s", 8, 6), CameraSpec("cam1", "s", 8, 6)])
    for k in range(3):
        w.add_step(StepRecord(0, 1.1, k, k, 0, k, k), {c: np.full((6, 8), k, np.uint8) for c in ("cam0", "cam1")})
    w.close(status="interrupted")
    with h5py.File(path, "r+") as f:  # a flush cut short: 4 rows, cam1 with 3 frames (cam0 with 4)
        for name in ("block", "stretch", "target_pressure", "pressure", "force", "t_monotonic", "t_wall",
                     "supersedes"):
            f["entry/steps"][name].resize((4,))
        f["entry/steps/images/cam0"].resize((4, 6, 8))
    with open_session(path) as s:
        assert s.n_steps == 3
    with SessionWriter.resume(path) as w:
        w.add_step(StepRecord(0, 1.1, 9, 9, 0, 9, 9), {c: np.full((6, 8), 9, np.uint8) for c in ("cam0", "cam1")})
    with open_session(path) as s:
        assert s.n_steps == 4 and s.steps["pressure"][3] == 9
        assert s.image("cam0", 3)[0, 0] == 9 and s.image("cam1", 3)[0, 0] == 9


# ---------------------------------------------------------------- items 1, 5, 6: a real full file system
@pytest.fixture
def small_fs(tmp_path):
    """A 2 MB tmpfs mounted for the test (skipped where mounting is not permitted)."""
    where = tmp_path / "fs"
    where.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(where)], capture_output=True,
                          text=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here ({done.stderr.strip() or 'mount failed'}); needs root")
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], check=False)


def _fill(folder: Path, leave: int) -> None:
    """Fill ``folder``'s file system until ``leave`` bytes are free."""
    free = shutil.disk_usage(folder).free
    with open(folder / "filler", "wb") as fh:
        fh.write(b"\1" * max(0, free - leave))
    while shutil.disk_usage(folder).free > leave + 4096:
        with open(folder / "filler", "ab") as fh:
            fh.write(b"\1" * 4096)


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "vfmlab", *args], env=_env(), capture_output=True, text=True,
                          timeout=300)


def test_full_disk_result_writes_leave_the_session_intact(base, small_fs, capsys):
    path = small_fs / "s.h5"
    shutil.copyfile(base, path)
    original = path.read_bytes()
    stored = 4
    for leave in (0, 3000, 12000, 20000, 40000, 60000):  # the result's file is ~30 kB: failures, then fits
        _fill(small_fs, leave)
        code = main(["identify", str(path), "--model", "delfino"])
        err = " ".join(capsys.readouterr().err.split())
        if code == 1:
            assert "disk full while writing the result" in err and "left exactly as it was before" in err, err
        else:
            assert code == 0, err
            stored += 1
        assert path.read_bytes() == original
        assert main(["info", str(path), "--json"]) == 0
        with open_session(path) as s:
            assert len(s.results()) == stored
            for name in s.results():
                s.result(name)
        (small_fs / "filler").unlink()
    assert stored < 4 + 6  # at least one level was too full
    assert main(["identify", str(path), "--model", "delfino"]) == 0
    with open_session(path) as s:
        assert len(s.results()) == stored + 1


def test_full_disk_import_markers_is_all_or_nothing(tmp_path, small_fs):
    markers, loads = _markers_csv(tmp_path, n_markers=200, n_steps=40)
    out = small_fs / "a.h5"
    for leave in (0, 50_000, 400_000, 1_000_000):
        _fill(small_fs, leave)
        done = _cli("import-markers", str(markers), str(loads), "-o", str(out), "--thickness-mm", "1")
        assert done.returncode == 1 and "Segmentation" not in done.stderr, done.stderr
        assert "disk full while writing the session" in done.stderr and "no session was created" in done.stderr
        assert not out.exists() and not list(small_fs.glob(".a.h5*"))
        (small_fs / "filler").unlink()
    done = _cli("import-markers", str(markers), str(loads), "-o", str(out), "--thickness-mm", "1")
    assert done.returncode == 0, done.stderr
    with open_session(out) as s:
        assert s.n_steps == 40 and s.results() == ["markers_001"]


_WRITER = """
import sys, numpy as np
from acquisition.session import CameraSpec, SessionWriter, SpecimenInfo, StepRecord
w = SessionWriter.resume(sys.argv[1]) if sys.argv[2] == "resume" else SessionWriter.create(
    sys.argv[1], SpecimenInfo("s", 0.01, 0.03, 0.001), cameras=[CameraSpec("cam0", "s", 200, 150)])
rng = np.random.default_rng(0)
try:
    for k in range(1000):
        w.append_log("pressure", [k], [k], [k])
        w.add_step(StepRecord(0, 1.1, k, k, 0, k, k), {"cam0": rng.integers(0, 255, (150, 200), np.uint8)})
except OSError as exc:
    print("stopped:", exc, flush=True)
    w.close(status="interrupted")
    sys.exit(1)
"""


def test_run_writer_on_a_full_disk_stops_cleanly_and_resumes(small_fs):
    path = small_fs / "s.h5"
    _fill(small_fs, 1_500_000)
    done = subprocess.run([sys.executable, "-c", _WRITER, str(path), "create"], env=_env(), capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 1, done.stderr  # not a segmentation fault (-11)
    assert "No space left on device while writing" in done.stdout and "completed before" in done.stdout
    with open_session(path) as s:
        n = s.n_steps
        assert n >= 1 and s.status == "interrupted"
        first = s.image("cam0", 0).copy()
    (small_fs / "filler").unlink()
    done = subprocess.run([sys.executable, "-c", _WRITER, str(path), "resume"], env=_env(), capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 1 and "completed before" in done.stdout, done.stderr
    with open_session(path) as s:
        assert s.n_steps > n + 10 and np.array_equal(s.image("cam0", 0), first) and s.status == "interrupted"
