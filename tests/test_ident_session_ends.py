"""End conditions recorded in the session and used by ``identify`` by default (issue 10, part A)."""

import io
from pathlib import Path

import numpy as np
import pytest
from rich.console import Console

from acquisition.protocol import parse_rig, parse_specimen
from acquisition.session import SessionWriter, SpecimenInfo, StepRecord, open_session, write_result
from vfmlab.operate import run_session, specimen_ends
from vfmlab.pipeline import identify_stored, resolve_ends

ROOT = Path(__file__).resolve().parents[1]
RIG = (ROOT / "examples" / "sim-rig.toml").read_text().replace("width = 640, height = 480", "width = 160, height = 120")
TINY = """
[protocol]
name = "tiny"
[stability]
band_mmHg = 2.0
dwell_s = 0.05
timeout_s = 20
[test]
stretches = [1.1]
pressures_mmHg = [0, 150]
"""


def _session_from_sim(tmp_path, *, clamped: bool, recorded: str, seed: int = 0):
    """A session holding exact simulated markers (rig_sim) with ``recorded`` ends in its specimen record."""
    from rig_sim.mechanics import PAPER_PARAMETERS, simulate_test

    sim = simulate_test("fung", PAPER_PARAMETERS["fung"], clamped=clamped, n_markers=200, seed=seed,
                        pressures=np.linspace(0, 150, 5) * 133.322387415)
    path = tmp_path / f"s-{clamped}-{recorded or 'none'}.h5"
    spec = SpecimenInfo("A1", sim.reference_radius, sim.length, sim.thickness, "", recorded,
                        "test" if recorded else "")
    with SessionWriter.create(path, spec) as w:
        for i in range(sim.n_steps):
            w.add_step(StepRecord(0, float(sim.stretch[i]), float(sim.pressure[i]), float(sim.pressure[i]),
                                  float(sim.axial_force[i]), float(i), 1.7e9 + i))
    write_result(path, "markers", {"positions": sim.positions, "step_index": np.arange(sim.n_steps)},
                 {"method": "rig_sim exact"})
    return path, sim


def _errors(result, truth, names=("beta", "alpha11", "alpha22")):
    return {n: result.parameters[n] / truth[n] - 1 for n in names}


def test_sim_run_records_the_simulated_specimens_ends(tmp_path):
    proto = tmp_path / "tiny.toml"
    proto.write_text(TINY)
    for clamped in (False, True):
        rig = tmp_path / f"rig-{clamped}.toml"
        rig.write_text(RIG + f"\n[simulation]\nmaterial = \"fung\"\nclamped = {str(clamped).lower()}\n")
        out = tmp_path / f"s-{clamped}.h5"
        console = Console(file=io.StringIO(), width=100)
        outcome = run_session(str(proto), str(ROOT / "examples" / "specimen.toml"), str(out), rig_path=str(rig),
                              sim=True, yes=True, sim_speed=5.0, console=console)
        assert outcome.status == "complete", console.file.getvalue()
        with open_session(out) as s:
            assert s.specimen.ends == ("clamped" if clamped else "free")
            assert "simulated specimen" in s.specimen.ends_source


def test_specimen_and_rig_files_say_the_ends():
    rig = parse_rig(RIG.replace('name = "simulated rig"', 'name = "simulated rig"\nends = "clamped"'))
    spec = parse_specimen('[specimen]\nid = "a"\nradius_mm = 10\nlength_mm = 35\nthickness_mm = 1.3\nends = "free"\n')
    assert rig.ends == "clamped" and spec.ends == "free"
    assert specimen_ends(rig, spec, sim=False) == ("free", "specimen file")
    assert specimen_ends(rig, parse_specimen(spec_text()), sim=False) == ("clamped", "rig file")
    assert specimen_ends(rig, spec, sim=True)[0] == "free"  # the default [simulation] is a free homogeneous tube
    with pytest.raises(Exception, match="ends"):
        parse_specimen(spec_text() + 'ends = "glued"\n')


def spec_text():
    return '[specimen]\nid = "a"\nradius_mm = 10\nlength_mm = 35\nthickness_mm = 1.3\n'


def test_identify_uses_the_recorded_free_ends(tmp_path):
    path, sim = _session_from_sim(tmp_path, clamped=False, recorded="free")
    group, result, data = identify_stored(path, model="fung", wall="membrane")
    err = _errors(result, sim.params)
    assert max(abs(e) for e in err.values()) < 0.01, err
    assert not any("ends" in f for f in result.flags), result.flags
    with open_session(path) as s:
        settings = s.result(group)["parameters"]
    assert settings["ends"] == "free" and settings["ends_source"].startswith("session")


def test_contradicting_ends_option_warns_and_is_stored(tmp_path):
    path, _ = _session_from_sim(tmp_path, clamped=False, recorded="free")
    group, result, _ = identify_stored(path, model="fung", ends="clamped", wall="membrane")
    assert any("--ends clamped contradicts the session" in f for f in result.flags), result.flags
    with open_session(path) as s:
        stored = s.result(group)
    assert stored["parameters"]["ends"] == "clamped" and stored["parameters"]["ends_source"] == "--ends option"
    assert any("contradicts" in f for f in stored["attrs"]["flags"])


def test_unrecorded_ends_are_left_to_the_data_and_say_so():
    # issue 23: nothing assumed silently; the data decide (identification.identify with ends=None)
    ends, source, notes, warnings = resolve_ends({"ends": "", "source": ""}, None)
    assert (ends, source, warnings) == (None, "the data", [])
    assert "the data decide" in notes[0] and "--ends clamped|free" in notes[0]
    assert resolve_ends({"ends": "free", "source": "specimen file"}, "free")[3] == []
