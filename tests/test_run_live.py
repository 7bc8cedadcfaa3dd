"""The live view: rendered to a string from a state, and driven by a real runner; the terminal operator."""

import io

import numpy as np
from rich.console import Console

from acquisition.cameras import FunctionCamera
from acquisition.protocol import MMHG, parse_protocol
from acquisition.runner import AutoOperator, RunnerState, SessionRunner
from acquisition.session import CameraSpec, SessionWriter, SpecimenInfo
from _run_fakes import FakeRig
from vfmlab.live import LiveView, TerminalOperator, format_duration, render_state


def _text(renderable, width=110):
    console = Console(record=True, file=io.StringIO(), width=width)
    console.print(renderable)
    return console.export_text()


def test_render_state_shows_readings_progress_markers_and_warnings():
    state = RunnerState(phase="stabilising", step=3, n_steps=16, steps_done=3, block=0, stretch=1.1,
                        target=60 * MMHG, pressure=59.5 * MMHG, force=1.2345, stable=False,
                        markers={"cam0": 41, "cam1": 38}, warnings=["camera 'cam2': no frame within 1 s"],
                        elapsed_s=75.0, remaining_s=125.0, message="waiting")
    text = _text(render_state(state, title="vfmlab run · a1.h5"))
    assert "59.50 mmHg" in text and "7.933 kPa" in text and "1.2345 N" in text
    assert "4 / 16" in text and "block 1" in text and "L/L0 = 1.100" in text and "target 60.0 mmHg" in text
    assert "settling" in text and "stabilising" in text
    assert "3/16" in text and "elapsed 1:15" in text and "remaining ~2:05" in text
    assert "cam0: 41" in text and "cam1: 38" in text
    assert "no frame within 1 s" in text and "vfmlab run · a1.h5" in text
    stable = _text(render_state(RunnerState(stable=True, phase="paused", n_steps=2)))
    assert "stable" in stable and "settling" not in stable and "paused" in stable and "—" in stable


def test_format_duration():
    assert (format_duration(5), format_duration(125.4), format_duration(3725), format_duration(float("nan"))) == \
           ("0:05", "2:05", "1:02:05", "--:--")


def test_live_view_driven_by_a_runner(tmp_path):
    rig = FakeRig()
    cams = [FunctionCamera(f"cam{i}", lambda s: np.zeros((s["height"], s["width"]), np.uint8),
                           {"width": 16, "height": 12}).open() for i in range(4)]
    w = SessionWriter.create(tmp_path / "s.h5", SpecimenInfo("s", 0.01, 0.035, 0.0013),
                             cameras=[CameraSpec(c.name, "sim", 16, 12) for c in cams])
    proto = parse_protocol("[stability]\nband_mmHg = 0.5\ndwell_s = 0.05\n[test]\nstretches = [1.1]\n"
                           "pressures_mmHg = [0, 40, 80]\n")
    out = io.StringIO()
    console = Console(file=out, force_terminal=True, width=110, color_system=None)
    view = LiveView(console, title="live test", max_fps=50)
    runner = SessionRunner(proto, w, pressure=rig, sampler=rig, cameras=cams, operator=AutoOperator(),
                           stage=lambda s: None, detector=lambda img: 7, on_update=view.update, tick_s=0.01)
    with view:
        assert runner.run() == "complete"
    text = out.getvalue()
    assert "live test" in text and "3/3" in text and "cam3: 7" in text and "mmHg" in text
    assert view.state.phase == "done" and view.state.steps_done == 3


def test_terminal_operator_prompts(monkeypatch):
    console = Console(file=io.StringIO(), width=100)
    op = TerminalOperator(console)
    monkeypatch.setattr("sys.stdin", io.StringIO("retake\n\n"))
    assert op.choose("Paused.", ["resume", "retake", "quit", "abort"]) == "retake"
    op.set_pressure(100 * MMHG)  # Enter
    assert "Paused." in console.file.getvalue()
