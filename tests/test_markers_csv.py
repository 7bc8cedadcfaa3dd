import json

import numpy as np
import pytest

from acquisition.markers_csv import CsvFormatError, read_loads_csv, read_markers_csv
from vfmlab.cli import main


def _write_inputs(tmp_path, n_markers=40, n_steps=4, pressure_column="pressure_mmHg", missing=True):
    rng = np.random.default_rng(1)
    theta = rng.uniform(-np.pi, np.pi, n_markers)
    z = rng.uniform(-15, 15, n_markers)
    lines = ["marker_id,step,x_mm,y_mm,z_mm"]
    for step in range(n_steps):
        r, s = 10.0 * (1 + 0.05 * step), 1 + 0.03 * step
        for m in range(n_markers):
            if missing and step == 2 and m == 3:
                lines.append(f"M{m:03d},{step},,,")  # not measured at this step
                continue
            lines.append(f"M{m:03d},{step},{r * np.cos(theta[m]):.6f},{r * np.sin(theta[m]):.6f},{z[m] * s:.6f}")
    markers = tmp_path / "markers.csv"
    markers.write_text("\n".join(lines) + "\n")
    loads = tmp_path / "loads.csv"
    scale = {"pressure_Pa": 133.322387415, "pressure_kPa": 0.133322387415, "pressure_mmHg": 1.0}[pressure_column]
    loads.write_text(f"step,{pressure_column},axial_force_N,stretch\n" + "".join(
        f"{s},{20 * s * scale:.6f},{0.5 * s:.4f},{1 + 0.03 * s:.4f}\n" for s in range(n_steps)))
    return markers, loads


def test_import_export_round_trip_is_exact(tmp_path, capsys):
    markers, loads = _write_inputs(tmp_path)
    out = tmp_path / "s.h5"
    assert main(["import-markers", str(markers), str(loads), "--thickness-mm", "1.3", "-o", str(out)]) == 0
    back = tmp_path / "back.csv"
    assert main(["export-markers", str(out), "-o", str(back), "--units", "mm"]) == 0
    assert back.read_text() == markers.read_text()
    # default: SI, the unit in the header; it reads back to the same positions
    si = tmp_path / "si.csv"
    assert main(["export-markers", str(out), "-o", str(si)]) == 0
    assert si.read_text().splitlines()[0] == "marker_id,step,x_m,y_m,z_m"
    np.testing.assert_allclose(read_markers_csv(si).positions, read_markers_csv(markers).positions, atol=1e-12)
    # an existing output is overwritten only with --force
    assert main(["export-markers", str(out), "-o", str(si)]) == 1
    assert "pass --force" in capsys.readouterr().err
    assert main(["export-markers", str(out), "-o", str(si), "--force"]) == 0
    # never the session itself, even with --force
    assert main(["export-markers", str(out), "-o", str(out), "--force"]) == 1
    assert "refusing to overwrite it" in capsys.readouterr().err
    capsys.readouterr()
    assert main(["info", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["schema_version"] == "1.0"
    assert info["status"] == "complete"
    assert (info["n_steps"], info["n_markers"]) == (4, 40)
    assert [r["kind"] for r in info["results"]] == ["markers"]
    assert info["max_pressure_Pa"] == pytest.approx(60 * 133.322387415)
    assert info["specimen"]["radius_m"] == pytest.approx(10e-3, rel=2e-3)
    assert main(["info", str(out)]) == 0
    assert "Derived results" in capsys.readouterr().out


@pytest.mark.parametrize("column,factor", [("pressure_Pa", 1.0), ("pressure_kPa", 1e3), ("pressure_mmHg", 133.322387415)])
def test_pressure_units(tmp_path, column, factor):
    _, loads = _write_inputs(tmp_path, pressure_column=column)
    table = read_loads_csv(loads)
    np.testing.assert_allclose(table["pressure"], 20 * np.arange(4) * 133.322387415, rtol=1e-6)


def test_missing_markers_are_nan(tmp_path):
    markers, _ = _write_inputs(tmp_path)
    table = read_markers_csv(markers)
    assert table.positions.shape == (4, 40, 3)
    assert np.isnan(table.positions[2, 3]).all()
    assert np.isfinite(np.delete(table.positions[2], 3, axis=0)).all()


@pytest.mark.parametrize(
    "content,match",
    [
        ("marker_id,step,x_mm,y_mm\nA,0,1,2\n", r"line 1: expected exactly one of the columns z_m, z_mm"),
        ("marker_id,step,x_mm,y_mm,z_m\nA,0,1,2,3\n", r"line 1: x, y and z must be in the same unit"),
        ("marker_id,step,x_mm,y_mm,z_mm\nA,0,1,2,3\nA,0,1,2,3\n", r"line 3: duplicate marker 'A' at step 0 \(first on line 2\)"),
        ("marker_id,step,x_mm,y_mm,z_mm\nA,0,1,abc,3\n", r"line 2, column y_mm: 'abc' is not a number"),
        ("marker_id,step,x_mm,y_mm,z_mm\nA,1.5,1,2,3\n", r"line 2, column step"),
        ("marker_id,step,x_mm,y_mm,z_mm\nA,1,1,2,3\n", r"no rows for step 0"),
        ("marker_id,step,x_mm,y_mm,z_mm\nA,0,1,,3\n", r"line 2: marker 'A' has some coordinates missing"),
        ("", r"empty"),
    ],
)
def test_malformed_markers(tmp_path, content, match):
    path = tmp_path / "m.csv"
    path.write_text(content)
    with pytest.raises(CsvFormatError, match=match):
        read_markers_csv(path)


@pytest.mark.parametrize(
    "content,match",
    [
        ("step,pressure_psi,axial_force_N,stretch\n0,1,2,1\n", r"pressure_Pa, pressure_kPa, pressure_mmHg.*unknown unit column 'pressure_psi'"),
        ("step,pressure_Pa,pressure_kPa,axial_force_N,stretch\n0,1,2,3,1\n", r"exactly one"),
        ("step,pressure_Pa,stretch\n0,1,1\n", r"missing column\(s\) axial_force_N"),
        ("step,pressure_Pa,axial_force_N,stretch\n0,1,2,1\n0,1,2,1\n", r"line 3: duplicate step 0"),
        ("step,pressure_Pa,axial_force_N,stretch\n0,x,2,1\n", r"line 2, column pressure_Pa: 'x' is not a number"),
        ("step,pressure_Pa,axial_force_N,stretch\n0,1,2,-1\n", r"line 2, column stretch: must be positive"),
    ],
)
def test_malformed_loads(tmp_path, content, match):
    path = tmp_path / "l.csv"
    path.write_text(content)
    with pytest.raises(CsvFormatError, match=match):
        read_loads_csv(path)


def test_cli_reports_csv_errors_without_traceback(tmp_path, capsys):
    markers, loads = _write_inputs(tmp_path)
    loads.write_text("step,pressure_bar,axial_force_N,stretch\n0,1,1,1\n")
    rc = main(["import-markers", str(markers), str(loads), "--thickness-mm", "1.3", "-o", str(tmp_path / "s.h5")])
    err = capsys.readouterr().err
    assert rc == 2
    assert "pressure_bar" in err and "Traceback" not in err
    assert not (tmp_path / "s.h5").exists()


def test_cli_missing_loads_for_a_step(tmp_path, capsys):
    markers, loads = _write_inputs(tmp_path)
    loads.write_text("step,pressure_Pa,axial_force_N,stretch\n0,0,0,1\n1,10,1,1\n")
    rc = main(["import-markers", str(markers), str(loads), "--thickness-mm", "1.3", "-o", str(tmp_path / "s.h5")])
    assert rc == 2
    assert "no loads for step(s) [2, 3]" in capsys.readouterr().err


def test_info_on_bad_file_is_one_message(tmp_path, capsys):
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"not hdf5 at all")
    assert main(["info", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "not HDF5" in err and "Traceback" not in err


def test_json_output_is_not_mixed_with_log_messages(tmp_path, capsys):
    """Warnings are logged to stderr, so stdout of --json stays parseable."""
    import logging

    markers, loads = _write_inputs(tmp_path)
    out = tmp_path / "s.h5"
    assert main(["import-markers", str(markers), str(loads), "--thickness-mm", "1.3", "-o", str(out)]) == 0
    capsys.readouterr()
    assert main(["-v", "info", str(out), "--json"]) == 0
    logging.getLogger("vfmlab.test").warning("a warning during a --json command")
    captured = capsys.readouterr()
    json.loads(captured.out)
    assert "a warning during a --json command" in captured.err
