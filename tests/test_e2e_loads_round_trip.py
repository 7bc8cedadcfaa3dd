"""export-markers + export-loads -> import-markers rebuilds a session that gives the same identification."""

from __future__ import annotations

import numpy as np

from acquisition.markers_csv import read_loads_csv
from acquisition.session import open_session
from rig_sim.synthetic_session import make_session
from vfmlab.cli import main
from vfmlab.stages.identify import identify


def test_export_loads_writes_what_import_reads(tmp_path, capsys):
    session = make_session(tmp_path / "s.h5")
    assert main(["export-loads", str(session), "-o", str(tmp_path / "loads.csv")]) == 0
    assert "7 steps" in capsys.readouterr().out
    loads = read_loads_csv(tmp_path / "loads.csv")
    with open_session(session) as s:
        steps = s.steps
    np.testing.assert_array_equal(loads["step"], np.arange(7))
    np.testing.assert_array_equal(loads["pressure"], steps["pressure"])  # full precision: bit-identical
    np.testing.assert_array_equal(loads["axial_force"], steps["force"])
    np.testing.assert_array_equal(loads["stretch"], steps["stretch"])
    assert main(["export-loads", str(session), "-o", str(tmp_path / "loads.csv")]) == 1  # exists: --force
    assert "pass --force" in capsys.readouterr().err
    assert main(["export-loads", str(session), "-o", str(tmp_path / "x.csv"), "--result", "markers_009"]) == 2
    assert "no markers result 'markers_009'" in capsys.readouterr().err


def test_round_trip_gives_the_same_identification(tmp_path, capsys):
    session = make_session(tmp_path / "s.h5")
    markers, loads, copy = tmp_path / "m.csv", tmp_path / "l.csv", tmp_path / "copy.h5"
    assert main(["export-markers", str(session), "-o", str(markers)]) == 0
    assert main(["export-loads", str(session), "-o", str(loads)]) == 0
    with open_session(session) as s:
        spec, measures = s.specimen, s.load_cell_measures
    assert main(["import-markers", str(markers), str(loads), "-o", str(copy),
                 "--thickness-mm", repr(spec.thickness * 1e3), "--radius-mm", repr(spec.radius * 1e3),
                 "--length-mm", repr(spec.length * 1e3), "--force-is", measures, "--ends", "clamped"]) == 0
    capsys.readouterr()
    with open_session(session) as s, open_session(copy) as c:
        np.testing.assert_array_equal(c.steps["pressure"], s.steps["pressure"])
        np.testing.assert_array_equal(c.steps["force"], s.steps["force"])
        np.testing.assert_array_equal(c.steps["stretch"], s.steps["stretch"])
        np.testing.assert_allclose(c.latest("markers")["arrays"]["positions"],
                                   s.latest("markers")["arrays"]["positions"], rtol=0, atol=1e-9, equal_nan=True)
    a = identify(session, model="fung", ends="clamped", uncertainty="gauss-newton")
    b = identify(copy, model="fung", ends="clamped", uncertainty="gauss-newton")
    assert a.parameters.keys() == b.parameters.keys()
    for name, value in a.parameters.items():  # markers are exported to 1 nm: the same fit to 1e-5
        assert abs(b.parameters[name] - value) <= 1e-5 * abs(value) + 1e-9, (name, value, b.parameters[name])
