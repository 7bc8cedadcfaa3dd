"""Offline reprocessing: new results appended with their settings, failures isolated, parallel runs, summary CSV."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from rig_sim.synthetic_session import make_session
from acquisition.session import open_session
from vfmlab.cli import main
from vfmlab.pipeline import STAGES, identify_session
from vfmlab.reprocess import plan_runs, reprocess, write_summary


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    """Three small sessions (markers only) and a corrupt file."""
    d = tmp_path_factory.mktemp("batch")
    paths = [make_session(d / f"s{i}.h5", seed=i, n_markers=120, specimen_id=f"tube-{i}") for i in range(3)]
    bad = d / "corrupt.h5"
    bad.write_bytes(paths[0].read_bytes()[:4096])  # a truncated copy: HDF5 signature, no usable content
    return paths, bad


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_reprocess_twice_keeps_both_results_readable(tmp_path, capsys):
    session = make_session(tmp_path / "s.h5", n_markers=120)
    with open_session(session) as s:
        before = s.results("identification")
    # the paper's cost for both, so that only the optimiser differs
    assert main(["reprocess", str(session), "--model", "delfino", "--optimizer", "lsq", "--weighting", "paper"]) == 0
    assert main(["reprocess", str(session), "--model", "delfino", "--optimizer", "nelder-mead"]) == 0
    capsys.readouterr()
    with open_session(session) as s:
        new = [n for n in s.results("identification") if n not in before]
        assert len(new) == 2
        a, b = (s.result(n) for n in new)
    assert a["parameters"]["optimizer"] == "lsq" and b["parameters"]["optimizer"] == "nelder-mead"
    for r in (a, b):
        assert r["attrs"]["version"] and r["attrs"]["invoked_by"] == "reprocess"
        assert r["arrays"]["parameters"].shape == (2,) and np.all(np.isfinite(r["arrays"]["parameters"]))
    # the earlier results are untouched
    with open_session(session) as s:
        assert s.result(before[0])["arrays"]["parameters"][1] == 14.5
    assert main(["results", str(session), "--compare", *new, "--json"]) == 0
    cmp = json.loads(capsys.readouterr().out)
    assert cmp["settings_diff"] == {"optimizer": {"a": "lsq", "b": "nelder-mead"}}
    assert set(cmp["parameters"]) == {"beta", "alpha"}
    # same data, same model: both optimisers land on the same minimum
    assert abs(cmp["parameters"]["alpha"]["rel_diff"]) < 0.05
    assert main(["results", str(session)]) == 0
    out = capsys.readouterr().out
    assert new[1] in out and "nelder-mead" in out
    # noise weighting on request is recorded (smoothed markers: it was used)
    assert main(["reprocess", str(session), "--model", "delfino", "--weighting", "noise"]) == 0
    with open_session(session) as s:
        latest = s.result(s.results("identification")[-1])
    assert latest["parameters"]["weighting"] == "noise" and a["parameters"]["weighting"] == "paper"


def test_stage_registry_is_the_identify_function():
    assert STAGES["identify"] is identify_session
    with pytest.raises(ValueError, match="stages must be among"):
        plan_runs(["calibrate"])


def test_corrupt_session_is_reported_and_skipped(batch, tmp_path, capsys):
    paths, bad = batch
    summary = tmp_path / "summary.csv"
    rc = main(["reprocess", str(paths[0]), str(bad), str(paths[1]), "--model", "delfino", "--summary", str(summary)])
    assert rc == 1
    captured = capsys.readouterr()
    assert "corrupt.h5" in captured.err and "1 of 3 session(s) failed" in captured.err
    rows = _rows(summary)
    ok = [r for r in rows if r["status"] == "ok"]
    assert {r["specimen"] for r in ok} == {"tube-0", "tube-1"}
    assert all(float(r["alpha"]) > 0 and r["alpha_stderr"] != "" for r in ok)
    # SI with the unit in the header; dimensionless parameters without a suffix
    assert all(float(r["beta_Pa"]) > 0 and float(r["beta_stderr_Pa"]) >= 0 for r in ok)
    failed = [r for r in rows if r["status"] == "failed"]
    assert len(failed) == 1 and "corrupt.h5" in failed[0]["session"] and failed[0]["error"]


def test_missing_markers_is_a_reported_failure(tmp_path):
    bare = make_session(tmp_path / "bare.h5", with_results=False)
    (out,) = reprocess([bare], plan_runs(["identify"], models=["delfino"]))
    assert not out.ok and "no marker tracks" in out.errors[0]


def test_process_pool_workers(batch, tmp_path):
    paths, bad = batch
    runs = plan_runs(["identify"], models=["delfino"])
    outcomes = reprocess([*paths, bad], runs, workers=2)
    assert [o.ok for o in outcomes] == [True, True, True, False]
    summary = write_summary(outcomes, tmp_path / "pool.csv")
    rows = _rows(summary)
    assert sorted(r["specimen"] for r in rows if r["status"] == "ok") == ["tube-0", "tube-1", "tube-2"]


def test_dask_local_cluster(batch, tmp_path, capsys):
    distributed = pytest.importorskip("dask.distributed")
    paths, bad = batch
    summary = tmp_path / "dask.csv"
    # dashboard on a free port: 8787 may be taken by another cluster on this machine
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                                  silence_logs=40) as cluster:
        rc = main(["reprocess", *map(str, paths), str(bad), "--model", "delfino", "--scheduler",
                   cluster.scheduler_address, "--summary", str(summary)])
    assert rc == 1  # the corrupt file
    assert "corrupt.h5" in capsys.readouterr().err
    rows = _rows(summary)
    assert sorted(r["specimen"] for r in rows if r["status"] == "ok") == ["tube-0", "tube-1", "tube-2"]
    assert sum(r["status"] == "failed" for r in rows) == 1


def test_reconstruct_failure_skips_identify(tmp_path, capsys):
    """Without a calibration the reconstruct stage fails; identify is then skipped, not run on stale tracks."""
    from rig_sim.synthetic_session import make_session as make

    bare = make(tmp_path / "bare.h5", with_results=False)
    (out,) = reprocess([bare], plan_runs(["reconstruct", "identify"], models=["delfino"]))
    assert not out.ok and not out.results
    assert "no calibration" in out.errors[0] and "skipped because reconstruct failed" in out.errors[1]
    assert main(["reprocess", str(bare), "--stages", "identify,reconstruct", "--model", "delfino"]) == 1
    assert "no calibration" in capsys.readouterr().err


def test_identify_stage_matches_identify_command(tmp_path, capsys):
    """The reprocess stage and 'vfmlab identify' store the same result (guards against the two drifting apart)."""
    from rig_sim.synthetic_session import make_session as make

    session = make(tmp_path / "s.h5", n_markers=120)
    assert main(["identify", str(session), "--model", "delfino", "--json"]) == 0
    capsys.readouterr()
    name = identify_session(session, model="delfino", invoked_by="test")
    with open_session(session) as s:
        cli, stage = s.result(s.results("identification")[-2]), s.result(name)
    assert cli["parameters"] == stage["parameters"]
    assert set(cli["arrays"]) == set(stage["arrays"])
    for key, value in cli["arrays"].items():
        if value.dtype.kind == "f":
            np.testing.assert_allclose(stage["arrays"][key], value, rtol=1e-9, err_msg=key)
        else:
            np.testing.assert_array_equal(stage["arrays"][key], value, err_msg=key)
    for key in ("model", "wall", "cost", "converged", "flags", "field_names"):
        assert stage["attrs"][key] == cli["attrs"][key], key


def test_unknown_reconstruct_setting_is_refused(tmp_path, capsys):
    session = make_session(tmp_path / "s.h5", with_results=False)
    assert main(["reprocess", str(session), "--stages", "reconstruct", "--set", "epipolar=3"]) == 1
    err = capsys.readouterr().err
    assert "unknown ['epipolar']" in err and "epipolar_px" in err


def test_smooth_grammar_is_the_same_as_identify(tmp_path, capsys):
    """--smooth takes AXIAL,HARMONICS or auto, as 'vfmlab identify --smooth' does."""
    bare = make_session(tmp_path / "bare.h5", with_results=False)
    assert main(["reprocess", str(bare), "--smooth", "4,x"]) == 2  # bad input (decision 0007)
    assert "--smooth must be 'auto', 'none' or two non-negative integers" in capsys.readouterr().err
    assert main(["reprocess", str(bare), "--smooth", "auto", "--json"]) == 1  # no markers: fails, but parsed
    out = json.loads(capsys.readouterr().out)
    assert "no marker tracks" in out["outcomes"][0]["errors"][0]
