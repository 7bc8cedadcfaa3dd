"""The rig file's [window] table: parsed to SI, recorded in the session's rig record, bad input named."""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from acquisition.protocol import ConfigError, parse_rig
from reconstruction.refraction import Window

RIG = (Path(__file__).resolve().parents[1] / "examples" / "sim-rig.toml").read_text()
WINDOW = """
[window]
glass_thickness_mm = 6
glass_index = 1.52
bath_index = 1.333
plane_distance_mm = -131
normal = [0, 0, 2]
"""


def test_window_table_in_si_and_recorded():
    from vfmlab.bench import Bench

    rig = parse_rig(RIG + WINDOW, source="r.toml")
    w = rig.window
    assert (w.glass_thickness, w.glass_index, w.bath_index, w.air_index) == (6e-3, 1.52, 1.333, 1.0)
    assert w.plane_distance == pytest.approx(-0.131) and w.normal == (0.0, 0.0, 1.0)
    record = Bench.rig_record(SimpleNamespace(config=rig, sim=None, cameras=[], motor=None, stage=None))
    win = Window.from_dict(record["window"])  # what the session stores reads back as the reconstruction's window
    assert win.thicknesses == (6e-3,) and win.indices == (1.52,) and win.n_bath == 1.333
    assert win.offset == pytest.approx(-0.131) and np.allclose(win.normal, [0, 0, 1])
    assert parse_rig(RIG, source="r.toml").window is None
    bench = SimpleNamespace(config=parse_rig(RIG, source="r.toml"), sim=None, cameras=[], motor=None, stage=None)
    assert "window" not in Bench.rig_record(bench)


@pytest.mark.parametrize("old,new,fragments", [
    ("glass_thickness_mm = 6", "glass_thickness_mm = -1", ["[window].glass_thickness_mm", ">= 0", "-1"]),
    ("glass_index = 1.52", "glass_index = 0.9", ["[window].glass_index", ">= 1", "0.9"]),
    ("bath_index = 1.333", "bath_index = 0.5", ["[window].bath_index", ">= 1", "0.5"]),
    ("normal = [0, 0, 2]", "normal = [0, 0, 0]", ["[window].normal", "non-zero", "[0, 0, 0]"]),
    ("normal = [0, 0, 2]", "normal = [0, 1]", ["[window].normal", "3 finite numbers", "[0, 1]"]),
    ("plane_distance_mm = -131", "plane_distance = -131", ["plane_distance", "unknown key"]),
    ("glass_thickness_mm = 6", "glass_thickness = 6", ["glass_thickness", "unknown key"]),
])
def test_window_table_errors_name_the_key(old, new, fragments):
    with pytest.raises(ConfigError) as info:
        parse_rig(RIG + WINDOW.replace(old, new), source="r.toml")
    for frag in fragments:
        assert frag in str(info.value), (frag, str(info.value))


def test_simulated_rig_refuses_a_window_it_does_not_render():
    from acquisition.errors import InputError
    from vfmlab.simrig import SimBench

    rig = parse_rig(RIG + WINDOW, source="r.toml")
    with pytest.raises(InputError, match=r"\[window\].*--sim.*6 mm glass"):
        SimBench(rig, None, None)
