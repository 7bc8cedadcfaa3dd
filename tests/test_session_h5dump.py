"""A session file is readable by the system's HDF5 tools (Debian's h5dump/h5ls, HDF5 1.10), not only by h5py.

docs/guide/session-format.md promises h5dump; h5py bundles a newer HDF5 (2.0), so the writer must bound the
format to what HDF5 1.10 reads (libver ("v110", "v110"): the oldest that keeps SWMR).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess

import numpy as np
import pytest

from acquisition.session import CameraSpec, SessionWriter, SpecimenInfo, StepRecord
from rig_sim.synthetic_session import make_session

CAMS = [CameraSpec("cam0", "sim", 64, 48), CameraSpec("cam1", "sim", 64, 48)]
H5DUMP_NEEDED = ("needs the system's HDF5 tools (h5dump, h5ls; Debian HDF5 1.10): "
                 "sudo apt-get install hdf5-tools")


def _tool(name: str) -> str:
    """The executable; skipped with the reason when absent, a failure in CI (.ci/run installs hdf5-tools)."""
    exe = shutil.which(name)
    if exe is None:
        if os.environ.get("CI"):
            pytest.fail(f"{H5DUMP_NEEDED} (CI is set: CI machines must have it; .ci/run installs it)")
        pytest.skip(H5DUMP_NEEDED)
    return exe


def _run(*cmd: str) -> str:
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, f"{' '.join(cmd)} failed ({proc.returncode}): {proc.stderr[-2000:]}"
    assert "error" not in proc.stderr.lower(), proc.stderr[-2000:]
    return proc.stdout


def _numbers(dump: str) -> np.ndarray:
    """The numbers of an h5dump DATA block, in order (the "(i,j): " index prefixes dropped)."""
    data = dump.split("DATA {", 1)[1].split("}", 1)[0]
    data = re.sub(r"\(\d+(,\d+)*\):", " ", data).replace("FALSE", "0").replace("TRUE", "1")
    return np.array([float(x) for x in re.findall(r"-?nan|-?inf|-?\d+(?:\.\d+)?(?:e[-+]?\d+)?", data)])


def _step(i: int) -> StepRecord:
    return StepRecord(block=0, stretch=1.1, target_pressure=1e3 * i, pressure=1e3 * i, force=0.1 * i,
                      t_monotonic=float(i), t_wall=1.7e9 + i)


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    return make_session(tmp_path_factory.mktemp("h5dump") / "s.h5")


def test_h5ls_lists_every_dataset_without_error(session):
    listing = _run(_tool("h5ls"), "-r", str(session))
    assert "*ERROR*" not in listing
    for name in ("/entry/steps/images/cam0", "/entry/results/markers_001/positions",
                 "/entry/results/markers_001/visible", "/entry/log/pressure/value"):
        assert name in listing


def test_h5dump_reads_the_whole_file(session):
    dump = _run(_tool("h5dump"), str(session))
    assert "*ERROR*" not in dump
    assert 'DATASET "positions"' in dump


def test_h5dump_reads_images_and_marker_arrays_with_their_values(session):
    import h5py

    h5dump = _tool("h5dump")
    with h5py.File(session, "r") as f:
        expected = {name: np.asarray(f[name][()], dtype=float).ravel()
                    for name in ("/entry/steps/images/cam1", "/entry/results/markers_001/positions",
                                 "/entry/results/markers_001/visible", "/entry/results/markers_001/marker_id")}
    for name, values in expected.items():
        got = _numbers(_run(h5dump, "-d", name, "-m", "%.17g", str(session)))
        np.testing.assert_array_equal(got, values, err_msg=name)


def test_h5dump_reads_a_resumed_session(tmp_path):
    """A session reopened for appending (SWMR writer) stays readable by HDF5 1.10."""
    path = tmp_path / "r.h5"
    w = SessionWriter.create(path, SpecimenInfo("A1", 10e-3, 35e-3, 1.3e-3), cameras=CAMS)
    w.add_step(_step(0), {c.name: np.full((48, 64), 3, np.uint8) for c in CAMS})
    w.close(status="interrupted")
    with SessionWriter.resume(path) as w:
        w.add_step(_step(1), {c.name: np.full((48, 64), 9, np.uint8) for c in CAMS})
    listing = _run(_tool("h5ls"), "-r", str(path))
    assert "*ERROR*" not in listing
    got = _numbers(_run(_tool("h5dump"), "-d", "/entry/steps/images/cam1", "-s", "1,0,0", "-c", "1,48,64",
                        str(path)))
    assert got.size == 48 * 64 and np.all(got == 9)
