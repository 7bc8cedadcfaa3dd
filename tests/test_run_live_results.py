"""Results while the test runs (vfmlab.live_results): a simulated session identifies Fung in the
background and stores the final parameters; a worker that fails never stops the test."""

import io
import logging

import numpy as np
import pytest
from rich.console import Console

from acquisition.session import open_session
from rig_sim.mechanics import PAPER_PARAMETERS
from test_run_session_sim import FAST, ROOT, SPECIMEN
from vfmlab.live import render_live_results
from vfmlab.operate import run_session

SIZE = (816, 680)

# the fast two-stretch protocol of the session tests, with one preconditioning cycle and 3 loaded levels
PROTOCOL = (FAST.replace("pressure_cycles = 8", "pressure_cycles = 1").replace("stretch_cycles = 8", "stretch_cycles = 1")
            .replace("[0, 20, 40, 60, 80, 100, 125, 150]", "[0, 50, 100, 150]")
            + "[reference]\ncapture = true\n[calibration]\nviews = 0\n")


def _files(tmp_path, size=SIZE, pressures="[0, 50, 100, 150]"):
    (tmp_path / "p.toml").write_text(PROTOCOL.replace("[0, 50, 100, 150]", pressures))
    rig = (ROOT / "examples" / "sim-rig.toml").read_text().replace("width = 640, height = 480",
                                                                   f"width = {size[0]}, height = {size[1]}")
    rig += '\n[simulation]\nmaterial = "fung"\nn_markers = 120\nclamped = false\nseed = 0\n'
    (tmp_path / "rig.toml").write_text(rig)
    return str(tmp_path / "p.toml"), str(tmp_path / "rig.toml")


def _true_cameras():
    """The simulated ring's true calibration (the test has no board views to calibrate from)."""
    from rig_sim import camera_ring

    return camera_ring(4, image_size=SIZE, seed=0)


@pytest.mark.timeout(300)
def test_run_identifies_while_running_and_stores_the_result(tmp_path):
    protocol, rig = _files(tmp_path)
    out = tmp_path / "s.h5"
    console = Console(file=io.StringIO(), width=120)
    outcome = run_session(protocol, str(SPECIMEN), str(out), rig_path=rig, sim=True, yes=True, sim_speed=10.0,
                          console=console, live_models=("fung",), live_options={"cameras": _true_cameras()})
    assert outcome.status == "complete"
    with open_session(out) as s:
        assert s.status == "complete"
        names = s.results("identification")
        assert len(names) == 1
        result = s.result(names[0])
        assert result["attrs"]["invoked_by"] == "run (live)"
        # every step, or a step the live tracker saw only in part left out and said so (identify's rule)
        rows = np.asarray(result["arrays"]["step_index"])
        assert rows[0] == 0 and rows.size >= 3 and set(rows.tolist()) <= set(range(s.n_steps)), rows
        if rows.size < s.n_steps:
            assert any("were left out" in fl for fl in result["attrs"]["flags"]), result["attrs"]["flags"]
        values = dict(zip(result["arrays"]["parameter_names"], result["arrays"]["parameters"]))
        stderr = dict(zip(result["arrays"]["parameter_names"], result["arrays"]["stderr"]))
        # reproducible from the session: the markers and calibration it came from are stored with it
        markers = s.result(result["parameters"]["markers_result"])
        assert markers["arrays"]["step_index"].tolist() == rows.tolist()
        assert s.result(result["parameters"]["calibration_result"])["kind"] == "calibration"
    truth = PAPER_PARAMETERS["fung"]
    # 120 markers, 4 cameras at 0.55 Mpx, 2 x 3 loaded levels: beta, alpha11, alpha22 within a few %
    # (the demo's own reconstruction of the same kind of session is within ~2-6 %)
    for name in ("beta", "alpha11", "alpha22"):
        assert abs(values[name] / truth[name] - 1) < 0.1, (name, values[name], truth[name])
        assert stderr[name] > 0
    text = console.file.getvalue()
    assert "live results stored as identification_001" in text and "beta [kPa]" in text, text


@pytest.mark.timeout(300)
def test_a_failing_worker_never_stops_the_run(tmp_path, caplog):
    protocol, rig = _files(tmp_path, (320, 240), "[0, 100]")
    out = tmp_path / "s.h5"

    def broken():
        raise RuntimeError("calibration exploded")

    console = Console(file=io.StringIO(), width=120)
    with caplog.at_level(logging.WARNING, logger="vfmlab.live_results"):
        outcome = run_session(protocol, str(SPECIMEN), str(out), rig_path=rig, sim=True, yes=True, sim_speed=10.0,
                              console=console, live_models=("fung",), live_options={"calibrate": broken})
    assert outcome.status == "complete"
    with open_session(out) as s:
        assert s.status == "complete" and s.n_steps == 5
        assert s.results("identification") == []
    assert "calibration exploded" in caplog.text


def test_live_panel_shows_parameters_with_units():
    from vfmlab.live_results import LiveEstimate, LiveStatus

    est = LiveEstimate("fung", ("beta", "alpha11"), np.array([5000.0, 14.5]), np.array([60.0, 0.07]),
                       np.arange(4), 1e-3, ())
    status = LiveStatus(steps_reconstructed=4, tracked=118, estimates={"fung": est}, message="ok")
    console = Console(file=io.StringIO(), width=100)
    console.print(render_live_results(status))
    text = console.file.getvalue()
    assert "beta [kPa]" in text and "5 " in text and "± std. err." in text and "118 markers tracked" in text
