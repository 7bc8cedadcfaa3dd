"""``vfmlab check-rig`` (issue 27): a healthy simulated rig passes; each injected fault (a defocused camera, a
saturated camera, a marker-less camera, a drifting load cell) is flagged on its own device and no other."""

import json

import numpy as np
import pytest

from acquisition.protocol import ConfigError, parse_rig
from reconstruction import detect_markers, image_quality
from vfmlab.cli import main
from vfmlab.operate import DEFAULT_SIM_RIG
from vfmlab.preflight import judge_channel
from vfmlab.stages.check import check_rig

FAULTS = """
[simulation.faults]
defocus = ["cam1"]
saturate = ["cam2"]
no_markers = ["cam3"]
force_drift_N_per_s = 0.01
"""


@pytest.fixture(scope="module")
def faulty(tmp_path_factory):
    path = tmp_path_factory.mktemp("rig") / "faulty-rig.toml"
    path.write_text(DEFAULT_SIM_RIG + FAULTS)
    return check_rig(rig=str(path), sim=True, seconds=1.5)


def test_a_healthy_rig_passes_and_keeps_its_images(tmp_path, capsys):
    out = tmp_path / "check"
    rc = main(["check-rig", "--sim", "--seconds", "1.5", "-o", str(out), "--json"])
    report = json.loads(capsys.readouterr().out)
    assert rc == 0 and report["passed"]
    assert [d["verdict"] for d in report["devices"]] == ["OK"] * 6
    assert "not checked" not in report["views"]
    assert sorted(p.name for p in out.iterdir()) == ["cam0.png", "cam1.png", "cam2.png", "cam3.png", "check.json"]


@pytest.mark.parametrize("device, words", [("camera cam1", "blurred"), ("camera cam2", "saturated"),
                                           ("camera cam3", "sees"), ("load cell", "drifting")],
                         ids=["defocused", "saturated", "marker-less", "drifting"])
def test_each_injected_fault_is_flagged_on_its_device(faulty, device, words):
    assert not faulty.passed
    assert faulty.verdict(device) == "FAULT"
    line = next(d.line for d in faulty.devices if d.device == device)
    assert words in line


def test_the_healthy_devices_of_a_faulty_rig_stay_ok(faulty):
    assert faulty.verdict("camera cam0") == "OK"
    assert faulty.verdict("pressure") == "OK"


def test_a_faulty_rig_exits_1(tmp_path):
    (tmp_path / "rig.toml").write_text(DEFAULT_SIM_RIG + FAULTS.replace('defocus = ["cam1"]\n', ""))
    assert main(["check-rig", "--rig", str(tmp_path / "rig.toml"), "--sim", "--seconds", "1"]) == 1


def test_fault_names_must_be_cameras_of_the_rig():
    with pytest.raises(ConfigError, match="defocus"):
        parse_rig(DEFAULT_SIM_RIG + FAULTS.replace('"cam1"', '"cam9"'))


def test_judge_channel_tells_drift_from_noise():
    rng = np.random.default_rng(1)
    t = np.linspace(0, 3, 150)
    noisy = judge_channel("force", t, 0.002 * rng.standard_normal(t.size))
    drifting = judge_channel("force", t, 0.01 * t + 0.002 * rng.standard_normal(t.size))
    assert noisy.verdict == "OK" and drifting.verdict == "FAULT"
    assert drifting.metrics["drift_per_s"] == pytest.approx(0.01, rel=0.1)
    assert judge_channel("pressure", t[:3], t[:3]).verdict == "FAULT"  # too few readings


def test_image_quality_of_a_blank_image_has_no_markers():
    q = image_quality(np.full((60, 80), 120, np.uint8), detect_markers(np.full((60, 80), 120, np.uint8)))
    assert q.n_markers == 0 and q.saturated_fraction == 0 and np.isnan(q.contrast)


def test_run_checks_the_rig_first_and_keeps_the_check_in_the_session(tmp_path):
    from rich.console import Console

    from acquisition.session import open_session
    from vfmlab.operate import run_session

    (tmp_path / "p.toml").write_text("[protocol]\nname = 'one'\n[stability]\nband_mmHg = 2.0\ndwell_s = 0.1\n"
                                     "[test]\nstretches = [1.1]\npressures_mmHg = [0, 40]\n")
    (tmp_path / "s.toml").write_text("[specimen]\nid = 's'\nradius_mm = 10.0\nlength_mm = 35.0\nthickness_mm = 1.3\n")
    out = tmp_path / "a.h5"
    outcome = run_session(str(tmp_path / "p.toml"), str(tmp_path / "s.toml"), str(out), sim=True, yes=True,
                          sim_speed=10.0, console=Console(quiet=True), check_seconds=1.0)
    assert outcome.status == "complete"
    with open_session(out) as s:
        checks = [e["message"] for e in s.events() if e["kind"] == "check"]
        (name,) = s.results("rig_check")
        result = s.result(name)
    assert len(checks) == 7 and checks[0].startswith("camera cam0: OK")
    assert result["arrays"]["image_cam0"].shape == (480, 640)
    assert result["arrays"]["centres_cam0"].shape[1] == 2 and result["attrs"]["passed"]


def test_a_rig_calibration_that_does_not_exist_is_refused():
    text = DEFAULT_SIM_RIG.replace('name = "simulated rig"', 'name = "simulated rig"\ncalibration = "nowhere.toml"')
    with pytest.raises(ConfigError, match="calibration"):
        parse_rig(text)
