"""Result writes cannot damage a session: SIGKILL at every disk write and disk full at every write.

``identify``, ``reconstruct`` and ``calibrate`` run through the real CLI (``vfmlab.cli.main``) in a
forked child whose result store (``acquisition.session._store._io``, the one place a result write
touches the disk: writes, fsyncs, renames) kills the process at its k-th operation, for every k.
The parent then runs ``info`` and checks that the session file is byte-identical to the one before
the command and that its results are the earlier ones (plus the new one when the kill came after
the manifest's rename, the commit point). The heavy computation of each command is
computed once (identify) or stubbed (reconstruct's series, calibrate --import) so the loop is fast:
what is under test is the write path, which is the same.
"""

from __future__ import annotations

import errno
import os
import shutil
import signal
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from rig_sim.synthetic_session import make_session, synthetic_tube
from acquisition.session import _store
from acquisition.session import open_session
from vfmlab.cli import main

_REAL_IO = _store._io


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    return make_session(tmp_path_factory.mktemp("faults") / "base.h5")


@pytest.fixture(scope="module")
def identify_result(base, tmp_path_factory):
    """The real identification result of the base session, computed once."""
    import identification

    seen = {}
    real = identification.identify

    def spy(*args, **kwargs):
        seen["result"] = real(*args, **kwargs)
        return seen["result"]

    copy = tmp_path_factory.mktemp("ident") / "s.h5"
    shutil.copy(base, copy)
    identification.identify = spy
    try:
        assert main(["identify", str(copy), "--model", "delfino", "--json"]) == 0
    finally:
        identification.identify = real
    return seen["result"]


def _fake_series(n_steps: int, n_cams: int):
    pos, *_ = synthetic_tube(160)
    pos = pos[:n_steps]
    n = pos.shape[1]
    zeros = np.zeros(n_steps, int)
    diag = {"detected": np.full((n_steps, n_cams), n), "rejects": np.zeros((n_steps, n_cams, 2), int),
            "reject_reasons": np.array(["size", "shape"]), "reconstructed": zeros + n, "tracked": zeros + n,
            "lost": zeros, "recovered": zeros, "unassigned": zeros, "swaps": zeros, "ambiguous": zeros,
            "outliers": zeros, "sigma_px": np.full(n_steps, 0.1), "reprojection_rms_median": np.full(n_steps, 0.2)}
    return SimpleNamespace(positions=pos, centres=pos, visible=np.ones(pos.shape[:2], bool),
                           uncertainty=np.full(pos.shape[:2], 5e-6), n_views=np.full(pos.shape[:2], 3),
                           reprojection_rms=np.full(pos.shape[:2], 0.2), marker_id=np.arange(n),
                           world_to_rig=np.eye(4), diagnostics=diag)


def _commands(path: Path, identify_result, calib_file: Path):
    """name -> (argv, stub installer) for the three commands that append results."""
    def stub_identify():
        import identification
        identification.identify = lambda *a, **k: identify_result

    def stub_reconstruct():
        import reconstruction as rp
        rp.reconstruct_series = lambda images, cameras, settings, n_steps, **k: _fake_series(n_steps, len(cameras))

    return {
        "identify": (["identify", str(path), "--model", "delfino", "--json"], stub_identify),
        "reconstruct": (["reconstruct", str(path), "--json"], stub_reconstruct),
        "calibrate": (["calibrate", str(path), "--import", str(calib_file), "--json"], lambda: None),
    }


def _run_child(argv, stub, fault) -> int:
    """Run ``vfmlab argv`` in a forked child with ``fault(k_counter)`` installed; returns its wait status."""
    pid = os.fork()
    if pid == 0:  # pragma: no cover - child
        code = 3
        try:
            sys.stdout = sys.stderr = open(os.devnull, "w")
            stub()
            _store._io = fault
            code = main(argv)
        finally:
            os._exit(code)
    return os.waitpid(pid, 0)[1]


def _count_writes(argv, stub) -> int:
    r, w = os.pipe()

    def counting(op, target, data=b"", _n=[0]):
        _n[0] += 1
        os.write(w, b".")
        return _REAL_IO(op, target, data)

    status = _run_child(argv, stub, counting)
    os.close(w)
    n = len(os.read(r, 1 << 16))
    os.close(r)
    assert os.waitstatus_to_exitcode(status) == 0
    return n


@pytest.fixture(scope="module")
def calib_file(base, tmp_path_factory):
    from reconstruction.calibration_io import cameras_from_arrays, cameras_to_toml

    with open_session(base) as s:
        cams = cameras_from_arrays(s.latest("calibration")["arrays"])
    path = tmp_path_factory.mktemp("cal") / "cal.toml"
    path.write_text(cameras_to_toml(cams, units="mm"))
    return path


@pytest.mark.parametrize("command", ["identify", "reconstruct", "calibrate"])
def test_sigkill_at_every_write_leaves_the_session_byte_identical(command, base, identify_result, calib_file,
                                                                  tmp_path):
    path = tmp_path / "s.h5"
    original = base.read_bytes()
    with open_session(base) as s:
        results_before = s.results()
    argv, stub = _commands(path, identify_result, calib_file)[command]
    shutil.copy(base, path)
    n = _count_writes(argv, stub)
    assert n >= 8  # result file: write, fsync, rename, folder fsync; manifest: the same; the folder's parent
    with open_session(path) as s:  # the complete write committed one new result
        assert s.results()[:-1] == results_before and s.results()[-1].startswith(
            {"identify": "identification", "reconstruct": "markers", "calibrate": "calibration"}[command])
    for k in range(1, n + 1):
        shutil.rmtree(_store.results_dir(path))
        path.unlink()
        shutil.copy(base, path)

        def kill_at_k(op, target, data=b"", _n=[0]):
            _n[0] += 1
            if _n[0] == k:
                os.kill(os.getpid(), signal.SIGKILL)
            return _REAL_IO(op, target, data)

        status = _run_child(argv, stub, kill_at_k)
        assert os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL, k
        assert main(["info", str(path), "--json"]) == 0, k
        assert path.read_bytes() == original, f"{command}: killed at write {k}/{n}: session changed"
        with open_session(path) as s:
            after = s.results()
            for name in after:
                s.result(name)  # every listed result reads
        committed = k >= n - 1  # killed at the fsyncs after the manifest's rename: the result is there
        assert after[:len(results_before)] == results_before and len(after) == len(results_before) + committed, k


@pytest.mark.parametrize("command", ["identify", "reconstruct", "calibrate"])
def test_disk_full_at_every_write_leaves_the_session_byte_identical(command, base, identify_result, calib_file,
                                                                    tmp_path, capsys):
    path = tmp_path / "s.h5"
    original = base.read_bytes()
    argv, stub = _commands(path, identify_result, calib_file)[command]
    shutil.copy(base, path)
    n = _count_writes(argv, stub)
    saved = {}
    stub_state = {}
    import identification
    import reconstruction as rp
    stub_state["identify"], stub_state["series"] = identification.identify, rp.reconstruct_series
    try:
        stub()
        for k in range(1, n + 1):
            shutil.rmtree(_store.results_dir(path), ignore_errors=True)
            path.unlink()
            shutil.copy(base, path)

            def full_from_k(op, target, data=b"", _n=[0]):
                _n[0] += 1
                if _n[0] >= k and op != "fsync_dir":
                    raise OSError(errno.ENOSPC, "No space left on device")
                return _REAL_IO(op, target, data)

            saved["io"] = _store._io
            _store._io = full_from_k
            try:
                rc = main(argv)
            finally:
                _store._io = saved["io"]
            err = capsys.readouterr().err
            if k >= n - 1:  # only the folder fsyncs are left: they do not fail on a full disk
                continue
            assert rc == 1, k
            assert "disk full while writing the result" in err and "more needed" in err, err
            assert "left exactly as it was before" in err
            assert path.read_bytes() == original, f"{command}: disk full at write {k}/{n}: session changed"
            assert not _store.results_dir(path).exists(), k  # nothing committed: no trace
    finally:
        identification.identify, rp.reconstruct_series = stub_state["identify"], stub_state["series"]
