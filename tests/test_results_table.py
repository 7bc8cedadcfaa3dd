"""`vfmlab results`: the models side by side, units in the keys, no float noise stored."""

from __future__ import annotations

import json

import numpy as np

from acquisition.session import open_session, write_result
from rig_sim.synthetic_session import make_session
from vfmlab.cli import main
from vfmlab.results import round_floats, side_by_side, unit_keys


def test_round_floats_removes_conversion_noise_only():
    assert round_floats(1.3 * 1e-3) == 0.0013
    assert round_floats({"a": [np.float64(0.1 + 0.2), 2, "x"], "b": (float("nan"),)})["a"] == [0.3, 2, "x"]
    assert np.isnan(round_floats((float("nan"),))[0])
    assert round_floats(123456.7891234567) == 123456.789123  # 12 significant digits
    assert unit_keys({"thickness": 0.0013000000000000002, "model": "fung"}) == {"thickness_m": 0.0013, "model": "fung"}


def test_side_by_side_with_and_without_verdicts(tmp_path, capsys):
    session = make_session(tmp_path / "s.h5")
    write_result(session, "identification",
                 {"parameters": np.array([1200.0, 3.1]), "stderr": np.array([50.0, 0.4]),
                  "parameter_names": np.array(["beta", "alpha"])},
                 {"model": "delfino", "wall": "thick"},
                 attrs={"model": "delfino", "wall": "thick", "cost": 0.002, "converged": True, "flags": [],
                        "verdict": "doubtful", "verdict_reasons": ["alpha: interval spans a factor of 3"],
                        "parameter_verdicts": {"beta": "trusted", "alpha": "doubtful"},
                        "parameter_reasons": {"alpha": "interval spans a factor of 3"}})
    assert main(["results", str(session), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    table = side_by_side(rows)
    assert [p["name"] for p in table["parameters"]] == ["beta", "alpha11", "alpha22", "alpha12", "alpha"]
    assert [p["unit"] for p in table["parameters"]][:2] == ["Pa", "1"]
    models = [(r["model"], r["wall"]) for r in table["rows"]]
    assert models == [("fung", "membrane"), ("delfino", "membrane"), ("delfino", "thick")]
    assert [r["verdict"] for r in table["rows"]] == [None, None, "doubtful"]  # older results: none stored
    assert table["rows"][2]["values"]["alpha"] == {"value": 3.1, "stderr": 0.4, "verdict": "doubtful"}
    assert main(["results", str(session)]) == 0
    out = capsys.readouterr().out
    assert "Models side by side" in out and "beta (Pa)" in out and "doubtful" in out
    assert "verdict: doubtful (alpha: interval spans a factor of 3)" in out
    line = next(ln for ln in out.splitlines() if "identification_003" in ln and "delfino (thick)" in ln)
    assert "3.1 ± 0.4 ?" in line and "1.2 kPa ± 0.05 kPa" in line


def test_import_stores_lengths_without_float_noise_and_settings_with_units(tmp_path, capsys):
    session = make_session(tmp_path / "s.h5")
    assert main(["export-markers", str(session), "-o", str(tmp_path / "m.csv")]) == 0
    assert main(["export-loads", str(session), "-o", str(tmp_path / "l.csv")]) == 0
    copy = tmp_path / "copy.h5"
    assert main(["import-markers", str(tmp_path / "m.csv"), str(tmp_path / "l.csv"), "-o", str(copy),
                 "--thickness-mm", "1.3", "--radius-mm", "10.1", "--length-mm", "35", "--ends", "clamped"]) == 0
    with open_session(copy) as s:
        assert s.specimen.thickness == 0.0013 and s.specimen.radius == 0.0101 and s.specimen.length == 0.035
    assert main(["identify", str(copy), "--model", "delfino", "--uncertainty", "gauss-newton"]) == 0
    capsys.readouterr()
    assert main(["results", str(copy), "--kind", "identification", "--json"]) == 0
    settings = json.loads(capsys.readouterr().out)[0]["settings"]
    assert settings["thickness_m"] == 0.0013 and "thickness" not in settings
    with open_session(copy) as s:
        assert s.latest("identification")["parameters"]["thickness_m"] == 0.0013  # stored so
