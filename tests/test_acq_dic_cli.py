"""The DIC readers on the command line: ``vfmlab import-dic`` builds a session from another lab's points as
``import-markers`` does from a marker CSV, and ``vfmlab calibrate --import calibrationSession.mat`` stores MATLAB's
stereo cameras. Real DuoDIC files from tests/data, and a small table written here."""

import json

import numpy as np
import pytest

from _data import data_path
from acquisition.dic import read_duodic_points, read_point_table
from acquisition.session import open_session
from vfmlab.cli import main

DUODIC = "duodic-sample/uniaxial_tension/DIC3Dstereo.mat"
CALIBRATION = "duodic-sample/calibration_11_18_10mm/calibrationSession.mat"


def _loads(tmp_path, n_steps):
    path = tmp_path / "loads.csv"
    path.write_text("step,pressure_kPa,axial_force_N,stretch\n" + "".join(
        f"{s},{2 + 0.5 * s:.3f},{0.1 + 0.01 * s:.3f},{1 + 0.005 * s:.4f}\n" for s in range(n_steps)))
    return path


def _markers(path):
    with open_session(path) as s:
        return s.latest("markers")


def test_import_dic_duodic_points_are_the_markers(tmp_path, capsys):
    mat = data_path(DUODIC)
    points = read_duodic_points(mat)
    out = tmp_path / "duo.h5"
    rc = main(["import-dic", str(mat), "--format", "duodic", "--loads", str(_loads(tmp_path, points.n_steps)),
               "--thickness-mm", "1.0", "--ends", "free", "-o", str(out), "--json"])
    assert rc == 0
    summary = json.loads(capsys.readouterr().out)
    assert (summary["n_markers"], summary["n_steps"], summary["ends"]) == (435, 20, "free")
    markers = _markers(out)
    np.testing.assert_array_equal(markers["arrays"]["positions"], points.points)  # m, NaN where DuoDIC left a point out
    assert np.isnan(points.points).any()
    np.testing.assert_array_equal(markers["arrays"]["visible"], ~np.isnan(points.points).any(axis=2))
    assert markers["parameters"]["source"] == "import-dic"


def test_import_dic_table_with_column_mapping(tmp_path, capsys):
    rng = np.random.default_rng(3)
    theta, z = rng.uniform(-np.pi, np.pi, 40), rng.uniform(-15, 15, 40)
    rows = ["pt;frame;X;Y;Z"]
    for step in range(3):
        r = 10.0 * (1 + 0.05 * step)
        rows += [f"{100 + m};{step};{r * np.cos(theta[m]):.6f};{r * np.sin(theta[m]):.6f};{z[m] * (1 + 0.03 * step):.6f}"
                 for m in range(40) if not (step == 2 and m == 5)]  # point 105 lost at step 2
    table = tmp_path / "points.csv"
    table.write_text("\n".join(rows) + "\n")
    columns = "id=pt,step=frame,x=X,y=Y,z=Z"
    out = tmp_path / "t.h5"
    assert main(["import-dic", str(table), "--format", "table", "--columns", columns, "--unit", "mm",
                 "--loads", str(_loads(tmp_path, 3)), "--thickness-mm", "1.3", "-o", str(out)]) == 0
    assert "Imported 40 markers × 3 steps" in capsys.readouterr().out
    expected = read_point_table(table, columns, unit="mm").points
    positions = _markers(out)["arrays"]["positions"]
    np.testing.assert_array_equal(positions, expected)
    assert np.isnan(positions[2]).any(axis=1).sum() == 1


@pytest.mark.parametrize("fmt, content", [("duodic", b"not a MATLAB file\n"), ("vic3d", b"x,y\n1,2\n"),
                                          ("table", b"a,b,c\n1,2,3\n")])
def test_import_dic_bad_file_is_one_line_exit_2(tmp_path, capsys, fmt, content):
    bad = tmp_path / ("bad.mat" if fmt == "duodic" else "bad.csv")
    bad.write_bytes(content)
    extra = ["--columns", "x=X,y=Y,z=Z"] if fmt == "table" else []
    out = tmp_path / "s.h5"
    rc = main(["import-dic", str(bad), "--format", fmt, *extra, "--loads", str(_loads(tmp_path, 2)),
               "--thickness-mm", "1", "-o", str(out)])
    err = capsys.readouterr().err
    assert rc == 2
    assert str(bad) in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_calibrate_import_matlab_session_stores_two_cameras(tmp_path, capsys):
    mat = data_path(DUODIC)
    out = tmp_path / "duo.h5"
    assert main(["import-dic", str(mat), "--format", "duodic", "--loads", str(_loads(tmp_path, 20)),
                 "--thickness-mm", "1.0", "-o", str(out)]) == 0
    capsys.readouterr()
    assert main(["calibrate", str(out), "--import", str(data_path(CALIBRATION)), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["cameras"] == ["cam1", "cam2"] and summary["stored_as"]
    with open_session(out) as s:
        stored = s.result(summary["stored_as"])
    assert [n.decode() if isinstance(n, bytes) else n for n in stored["arrays"]["camera_names"]] == ["cam1", "cam2"]
    assert stored["arrays"]["image_size"].tolist() == [[2448, 2048], [2448, 2048]]
    assert np.linalg.norm(stored["arrays"]["tvec"][1]) == pytest.approx(0.16, rel=0.2)  # m: camera 2 ~160 mm away


def test_calibrate_import_bad_mat_is_exit_2(tmp_path, capsys):
    bad = tmp_path / "calibrationSession.mat"
    bad.write_text("step,x\n0,1\n")
    assert main(["calibrate", "--import", str(bad), "-o", str(tmp_path / "c.toml")]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "Traceback" not in err


def test_a_dense_cloud_is_checked_on_a_subsample_to_full_precision():
    """The import's cylinder (plausibility, recorded radius and length) is fitted to ``FIT_POINTS`` of a dense
    cloud's points, the radius and length then from all of them: 50,000 points took 20 s an import before; the
    radius is still the cloud's to a few micrometres at 0.17 mm noise, and the length its full extent."""
    from vfmlab.stages.imports import FIT_POINTS, estimate_geometry

    rng = np.random.default_rng(7)
    n = 20 * FIT_POINTS
    theta, z = rng.uniform(-np.pi, np.pi, n), rng.uniform(0.0, 35e-3, n)
    cloud = np.stack([10e-3 * np.cos(theta), 10e-3 * np.sin(theta), z], -1) + rng.normal(0.0, 0.17e-3, (n, 3))
    radius, length = estimate_geometry(cloud)
    assert abs(radius - np.mean(np.hypot(cloud[:, 0], cloud[:, 1]))) < 5e-6
    assert abs(length - np.ptp(cloud[:, 2])) < 1e-3  # the axis is tilted by at most ~1e-3 rad over 35 mm
