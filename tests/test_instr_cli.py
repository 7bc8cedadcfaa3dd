"""``vfmlab monitor`` and ``vfmlab sim-rig`` against the simulated instruments."""

import json
import time

import numpy as np
import pytest

from rig_sim.instruments import SimulatedRig
from vfmlab.cli import main


@pytest.fixture
def rig():
    with SimulatedRig(rng=np.random.default_rng(5), pressure_source="manual", tau_s=0.01) as r:
        r.set_operator_pressure(100 * 133.322387415)
        r.set_stretch(1.1)
        time.sleep(0.1)  # ten time constants: the pressure (and so the force) has settled
        yield r


def test_monitor_json_lines_and_never_zeroes_unasked(rig, capsys):
    rc = main(["monitor", "--pressure", rig.pressure_port, "--load-cell", rig.load_cell_port,
               "--count", "5", "--json", "--rate", "50"])
    assert rc == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    for channel, unit in (("pressure", "Pa"), ("force", "N")):
        mine = [r for r in rows if r["channel"] == channel]
        assert [r["seq"] for r in mine] == [0, 1, 2, 3, 4]
        assert all(r["unit"] == unit for r in mine)
        assert np.all(np.diff([r["t_monotonic"] for r in mine]) > 0)
    p = [r for r in rows if r["channel"] == "pressure"]
    assert p[-1]["mmHg"] == pytest.approx(100, abs=0.2) and p[-1]["kPa"] == pytest.approx(13.33, abs=0.03)
    assert p[-1]["device_unit"] == "mmHg" and float(p[-1]["raw"]) == pytest.approx(p[-1]["mmHg"], rel=1e-6)
    f = [r for r in rows if r["channel"] == "force"]
    assert f[-1]["value"] == pytest.approx(rig.true_force(), abs=0.01)
    assert rig.mark10.tare_n == 0.0 and rig.mensor.unit == "mmHg"  # nothing zeroed or reconfigured


def test_monitor_zero_only_when_asked(rig, capsys):
    rc = main(["monitor", "--load-cell", rig.load_cell_port, "--count", "3", "--json", "--zero"])
    assert rc == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert rig.mark10.tare_n != 0.0
    assert all(abs(r["value"]) < 0.01 for r in rows), rows


def test_monitor_live_display(rig, capsys):
    assert main(["monitor", "--pressure", rig.pressure_port, "--load-cell", rig.load_cell_port,
                 "--count", "3"]) == 0
    out = capsys.readouterr().out
    assert "mmHg" in out and "kPa" in out and " N" in out


def test_monitor_errors_are_readable(capsys, tmp_path):
    assert main(["monitor"]) == 1
    assert "at least one instrument" in capsys.readouterr().err
    assert main(["monitor", "--pressure", str(tmp_path / "nope")]) == 1
    assert "cannot open the pressure transducer" in capsys.readouterr().err


def test_sim_rig_prints_ports(capsys):
    assert main(["sim-rig", "--duration", "0.1", "--json"]) == 0
    ports = json.loads(capsys.readouterr().out)
    assert ports["pressure"].endswith("SIM0001") and ports["load_cell_device"].startswith("/dev/pts/")
    assert main(["sim-rig", "--duration", "0.1", "--socket", "--manual", "--pressure-mmhg", "80"]) == 0
    out = capsys.readouterr().out
    assert "socket://127.0.0.1:" in out and "vfmlab monitor --pressure" in out
