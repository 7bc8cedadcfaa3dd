"""The motorised axial stage in ``vfmlab run`` (issue 27): the rig file's [stage], homing, every protocol stretch
checked against the soft limits, each stretch of a two-stretch protocol reached with no operator action, and a
stage fault mid-run that pauses the session and resumes it."""

import pytest
from rich.console import Console

from acquisition.protocol import ConfigError, parse_rig
from acquisition.session import open_session
from vfmlab.operate import DEFAULT_SIM_RIG, OperateError, run_session

STAGE = """
[stage]
port = "sim"
microstep_um = 0.047625
min_mm = 2.0
max_mm = 30.0
x0_mm = 10.0
direction = 1
"""
PROTOCOL = """
[protocol]
name = "two stretches"
[preconditioning]
pressure_cycles = 0
stretch_cycles = 1
stretch_max = 1.25
cycle_s = 0.2
[stability]
band_mmHg = 2.0
dwell_s = 0.1
[test]
stretches = [1.1, 1.2]
pressures_mmHg = [0, 40]
"""
SPECIMEN = "[specimen]\nid = 's'\nradius_mm = 10.0\nlength_mm = 35.0\nthickness_mm = 1.3\n"


def _files(tmp_path, stage=STAGE, protocol=PROTOCOL):
    (tmp_path / "rig.toml").write_text(DEFAULT_SIM_RIG + stage)
    (tmp_path / "p.toml").write_text(protocol)
    (tmp_path / "s.toml").write_text(SPECIMEN)
    return str(tmp_path / "p.toml"), str(tmp_path / "s.toml"), str(tmp_path / "rig.toml")


def test_stage_table_is_parsed_in_si_and_checked():
    rig = parse_rig(DEFAULT_SIM_RIG + STAGE)
    s = rig.stage
    assert (s.port, s.microstep_m, s.min_m, s.max_m, s.x0_m, s.direction) == ("sim", 0.047625e-6, 2e-3, 30e-3, 10e-3, 1)
    assert rig.simulated
    with pytest.raises(ConfigError, match="x0_mm"):
        parse_rig(DEFAULT_SIM_RIG + STAGE.replace("x0_mm = 10.0", "x0_mm = 40.0"))
    with pytest.raises(ConfigError, match="direction"):
        parse_rig(DEFAULT_SIM_RIG + STAGE.replace("direction = 1", "direction = 2"))


def test_two_stretches_on_the_simulated_stage_with_no_operator_action(tmp_path):
    p, s, rig = _files(tmp_path)
    seen = {}

    def observer(state, bench):
        seen["device"] = bench.sim.stage.device

    out = tmp_path / "a.h5"
    outcome = run_session(p, s, str(out), rig_path=rig, sim=True, yes=True, sim_speed=10.0, console=Console(quiet=True),
                          observer=observer)
    assert outcome.status == "complete"
    device = seen["device"]
    assert device.homed and "home" in device.commands
    # the last stretch of the protocol, 1.2 of L0 = 35 mm from x0 = 10 mm: 17 mm
    assert device.position() * 0.047625e-6 == pytest.approx(10e-3 + 0.2 * 35e-3, abs=0.1e-6)
    with open_session(out) as sess:
        stretches = sorted({round(float(x), 6) for x in sess.steps["stretch"]})
        assert stretches == [1.1, 1.2]
        assert sess.rig_settings["stage"]["gauge_length_m"] == pytest.approx(35e-3)
        kinds = [e["kind"] for e in sess.events()]
    assert "fault" not in kinds


def test_a_protocol_stretch_beyond_the_soft_limits_is_refused_before_anything_moves(tmp_path):
    # max_mm = 20: L/L0 up to 1 + 10/35 = 1.286 (the rig's safety limit is 1.5)
    p, s, rig = _files(tmp_path, stage=STAGE.replace("max_mm = 30.0", "max_mm = 20.0"),
                       protocol=PROTOCOL.replace("[1.1, 1.2]", "[1.1, 1.4]"))
    with pytest.raises(OperateError, match="soft limits") as info:
        run_session(p, s, str(tmp_path / "b.h5"), rig_path=rig, sim=True, yes=True, sim_speed=10.0,
                    console=Console(quiet=True))
    assert info.value.exit_code == 2
    assert not (tmp_path / "b.h5").exists()


def test_a_stage_fault_mid_run_pauses_and_resumes_after_clearing(tmp_path):
    p, s, rig = _files(tmp_path)
    phases = []
    armed = {"done": False}

    def observer(state, bench):
        phases.append(state.phase)
        # once the first test block has been captured, stall the carriage on its way to L/L0 = 1.2
        if not armed["done"] and state.steps_done >= 2:
            armed["done"] = True
            bench.sim.stage.device.stall_at(round((10e-3 + 0.15 * 35e-3) / 0.047625e-6))

    out = tmp_path / "c.h5"
    outcome = run_session(p, s, str(out), rig_path=rig, sim=True, yes=True, sim_speed=10.0, console=Console(quiet=True),
                          observer=observer)
    assert outcome.status == "complete"
    assert "paused" in phases
    with open_session(out) as sess:
        events = sess.events()
        assert sorted({round(float(x), 6) for x in sess.steps["stretch"]}) == [1.1, 1.2]
    messages = [(e["kind"], e["message"]) for e in events]
    fault = next(i for i, (k, m) in enumerate(messages) if k == "fault" and "stage" in m)
    assert any(k == "recovered" and "stage fault cleared" in m for k, m in messages[fault:])
    assert any(k == "stretch" and "1.2000" in m for k, m in messages[fault:])
