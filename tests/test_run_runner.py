"""The session runner on test doubles: full run, pause/retake/quit/abort, capture failure, faults, safety."""

import threading
import time

import numpy as np
import pytest

from acquisition.cameras import FunctionCamera
from acquisition.protocol import MMHG, SafetyLimits, parse_protocol
from acquisition.runner import AutoOperator, SessionRunner, completed_steps
from acquisition.session import CameraSpec, SessionWriter, SpecimenInfo, open_session
from _run_fakes import FakeRig

PROTO = """
[preconditioning]
pressure_cycles = 2
pressure_max_mmHg = 80
stretch_cycles = 2
stretch_max = 1.4
cycle_s = 0.1
[stability]
band_mmHg = 0.5
dwell_s = 0.05
timeout_s = 2
[test]
stretches = [1.1, 1.2]
pressures_mmHg = [0, 60, 120]
[capture]
timeout_s = 1
"""


class Scripted(AutoOperator):
    def __init__(self, answers, **kw):
        super().__init__(**kw)
        self.answers = list(answers)
        self.asked = []

    def choose(self, reason, options):
        self.asked.append((reason, list(options)))
        if self.answers:
            return self.answers.pop(0)
        return super().choose(reason, options)


def _cams(rig, n=4):
    def render(settings):
        level = int(round(rig.true_pressure() / MMHG)) % 256
        return np.full((settings["height"], settings["width"]), level, np.uint8)

    return [FunctionCamera(f"cam{i}", render, {"width": 16, "height": 12}).open() for i in range(n)]


def _writer(path, cams):
    return SessionWriter.create(path, SpecimenInfo("s1", 0.01, 0.035, 0.0013),
                                cameras=[CameraSpec(c.name, "sim", 16, 12) for c in cams], protocol_text=PROTO)


def _runner(tmp_path, operator=None, proto=PROTO, stage=True, **kw):
    rig = FakeRig()
    cams = _cams(rig)
    w = _writer(tmp_path / "s.h5", cams)
    states = []
    runner = SessionRunner(parse_protocol(proto), w, pressure=rig, sampler=rig, cameras=cams,
                           operator=operator or AutoOperator(),
                           stage=(lambda s: setattr(rig, "stretch", s)) if stage else None,
                           on_update=states.append, tick_s=0.01, **kw)
    return runner, rig, cams, states


def test_full_run_writes_every_step_and_vents(tmp_path):
    runner, rig, cams, states = _runner(tmp_path)
    t0 = time.monotonic()
    assert runner.run() == "complete"
    assert time.monotonic() - t0 < 10
    with open_session(tmp_path / "s.h5") as s:
        assert s.status == "complete" and s.n_steps == 6
        st = s.steps
        assert st["block"].tolist() == [0, 0, 0, 1, 1, 1]
        assert st["stretch"].tolist() == [1.1] * 3 + [1.2] * 3
        np.testing.assert_allclose(st["target_pressure"], np.tile([0, 60, 120], 2) * MMHG)
        # captured at a stable pressure: within the band of the target
        assert np.all(np.abs(st["pressure"] - st["target_pressure"]) < 0.5 * MMHG)
        assert np.all(np.diff(st["t_monotonic"]) > 0)
        assert int(s.image("cam2", 2)[0, 0]) == 120  # the image shows the pressure of its step
        lg = s.log("pressure")
        assert np.array_equal(lg["seq"], np.arange(lg["seq"].size))  # every sample, exactly once
        kinds = [e["kind"] for e in s.events()]
        assert "preconditioning_done" in kinds and kinds.count("stretch") >= 2 + 4
        # preconditioning reached the top pressure
        assert lg["value"].max() > 70 * MMHG
    assert rig.modes[-1] == "vent"
    assert states[-1].phase == "done" and states[-1].steps_done == 6 and not any(c.is_open for c in cams)


def test_retake_supersedes_without_deleting(tmp_path):
    op = Scripted(["note", "retake"])
    op.ask_text = lambda prompt: "bubble in the cannula, retaking"
    runner, rig, cams, states = _runner(tmp_path, op)
    fired = []

    def on_update(state):
        states.append(state)
        if state.steps_done == 2 and not fired:
            fired.append(1)
            runner.request_pause()

    runner.on_update = on_update
    assert runner.run() == "complete"
    assert op.asked and op.asked[0][1] == ["resume", "retake", "note", "quit", "abort"]
    assert len(op.asked) == 2  # the note, then the menu again
    with open_session(tmp_path / "s.h5") as s:
        st = s.steps
        assert s.n_steps == 7 and st["supersedes"].tolist().count(1) == 1
        assert int(np.count_nonzero(st["active"])) == 6 and not st["active"][1]
        retake = int(np.flatnonzero(st["supersedes"] == 1)[0])
        assert st["target_pressure"][retake] == st["target_pressure"][1]
        assert completed_steps(st) == 6
        assert "retake" in [e["kind"] for e in s.events()]
        assert {"kind": "note", "message": "bubble in the cannula, retaking"}.items() <= \
            next(e for e in s.events() if e["kind"] == "note").items()


@pytest.mark.parametrize("answer,status,recorded", [("abort", "aborted", "aborted"),
                                                     ("quit", "interrupted", "running")])
def test_pause_abort_or_quit_always_vents(tmp_path, monkeypatch, answer, status, recorded):
    runner, rig, cams, states = _runner(tmp_path, Scripted([answer]))
    orig = runner.on_update

    def on_update(state):
        orig(state)
        if state.steps_done == 3:
            runner.request_pause()

    runner.on_update = on_update
    assert runner.run() == status
    assert rig.modes[-1] == "vent"
    with open_session(tmp_path / "s.h5") as s:
        assert s.n_steps == 3 and s.recorded_status == recorded
    if answer == "quit":  # resumable: reopen and finish; every step exactly once
        # the quitting process normally exits; here it lives on, so tell the reader its writer is gone
        import acquisition.session._guards as session_mod
        monkeypatch.setattr(session_mod, "_writer_alive", lambda pid, host, *identity: False)
        w = SessionWriter.resume(tmp_path / "s.h5")
        rig2 = FakeRig()
        cams2 = _cams(rig2)
        with open_session(tmp_path / "s.h5") as s:
            start = completed_steps(s.steps)
        r2 = SessionRunner(parse_protocol(PROTO), w, pressure=rig2, sampler=rig2, cameras=cams2,
                           operator=AutoOperator(), stage=lambda x: None, tick_s=0.01)
        assert r2.run(start_step=start, precondition=False) == "complete"
        with open_session(tmp_path / "s.h5") as s:
            assert s.status == "complete" and s.n_steps == 6
            assert s.steps["target_pressure"].tolist() == pytest.approx((np.tile([0, 60, 120], 2) * MMHG).tolist())


def test_failed_camera_is_reported_and_retried(tmp_path):
    class FixesCable(Scripted):
        def choose(self, reason, options):
            cams[2].unplugged = False  # the operator plugs the camera back, then says retry
            return super().choose(reason, options)

    op = FixesCable(["retry"])
    runner, rig, cams, states = _runner(tmp_path, op, capture_retries=1, retry_delay_s=0.2)
    cams[2].unplugged = True
    assert runner.run() == "complete"
    # one automatic retry, then the operator is asked
    assert op.asked[0][1] == ["retry", "abort"] and "camera 'cam2'" in op.asked[0][0]
    assert any("cam2" in w for st in states for w in st.warnings)
    with open_session(tmp_path / "s.h5") as s:
        assert s.n_steps == 6
        failed = [e for e in s.events() if e["kind"] == "capture_failed"]
        assert len(failed) >= 2 and all("cam2" in e["message"] and "unplugged" in e["message"] for e in failed)


def test_camera_that_never_comes_back_aborts(tmp_path):
    runner, rig, cams, _ = _runner(tmp_path, AutoOperator(), capture_retries=1, retry_delay_s=0.05)
    cams[0].stalled = True
    assert runner.run() == "aborted"
    assert rig.modes[-1] == "vent"
    with open_session(tmp_path / "s.h5") as s:
        # a camera that timed out can be fixed: the session stays resumable (issue 28)
        assert s.status == "interrupted" and s.n_steps == 0
        assert any("resumable" in e["message"] for e in s.events() if e["kind"] == "abort")
    SessionWriter.resume(tmp_path / "s.h5").close(status="aborted")  # resume accepts it


def test_instrument_fault_pauses_then_resumes(tmp_path):
    op = AutoOperator()
    runner, rig, cams, states = _runner(tmp_path, op)
    orig = runner.on_update
    done = []

    def on_update(state):
        orig(state)
        if state.steps_done == 2 and not done:
            done.append(1)
            rig.set_fault("force", "port /dev/pts/9 vanished")
            threading.Timer(0.3, rig.clear_fault, args=("force",)).start()

    runner.on_update = on_update
    assert runner.run() == "complete"
    assert any(st.phase == "paused" and "load cell disconnected" in st.message for st in states)
    with open_session(tmp_path / "s.h5") as s:
        kinds = [e["kind"] for e in s.events()]
        assert "fault" in kinds and "recovered" in kinds and s.n_steps == 6
        f = s.log("force")["t_monotonic"]
        assert np.max(np.diff(f)) > 0.25  # the gap of the fault is visible, not papered over


def test_safety_limit_aborts(tmp_path):
    runner, rig, cams, _ = _runner(tmp_path, safety=SafetyLimits(max_force=0.5))
    assert runner.run() == "aborted"  # 120 mmHg -> 1.6 N > 0.5 N
    assert runner.resumable and rig.modes[-1] == "vent"
    with open_session(tmp_path / "s.h5") as s:
        assert s.status == "interrupted"  # vented, every completed step sound: resumable
        assert any("exceeds the safety limit" in e["message"] and "resumable" in e["message"] for e in s.events())


def test_unstable_pressure_times_out_and_manual_mode(tmp_path):
    proto = PROTO.replace("timeout_s = 2", "timeout_s = 0.2").replace("pressure_cycles = 2", "pressure_cycles = 0")
    set_calls = []
    op = Scripted([], set_pressure=set_calls.append)
    runner, rig, cams, _ = _runner(tmp_path, op, proto=proto, pressure_mode="manual")
    # nobody turns the valve: the pressure stays at 0, the 60 and 120 mmHg levels never settle
    assert runner.run() == "complete"
    assert len(set_calls) == 6 and rig.modes == []  # manual: the controller is never commanded
    assert sum("not stable" in r for r, _ in op.asked) == 4
    with open_session(tmp_path / "s.h5") as s:
        assert sum(e["kind"] == "warning" for e in s.events()) == 4


def test_imaged_preconditioning_rows_do_not_count_as_protocol_steps(tmp_path):
    proto = PROTO.replace("cycle_s = 0.1", "cycle_s = 0.1\nimaged = true").replace("[1.1, 1.2]", "[1.1]")
    runner, rig, cams, _ = _runner(tmp_path, proto=proto)
    assert runner.run() == "complete"
    with open_session(tmp_path / "s.h5") as s:
        st = s.steps
        assert st["block"].tolist() == [-1] * 4 + [0, 0, 0]  # 2 pressure + 2 stretch cycles, imaged at the top
        np.testing.assert_allclose(st["target_pressure"][:2], 80 * MMHG)
        assert st["stretch"][2:4].tolist() == [1.4, 1.4]
        assert completed_steps(st) == 3


def test_calibration_views_are_captured_first(tmp_path):
    placed = []
    op = AutoOperator(place_board=lambda k, n: placed.append((k, n)), remove_board=lambda: placed.append("off"))
    proto = PROTO.replace("[capture]", "[calibration]\nviews = 3\nboard = \"test board\"\n[capture]")
    runner, rig, cams, _ = _runner(tmp_path, op, proto=proto)
    assert runner.run() == "complete"
    assert placed == [(0, 3), (1, 3), (2, 3), "off"]
    with open_session(tmp_path / "s.h5") as s:
        assert s.calibration_images("cam1").shape == (3, 12, 16) and s.n_steps == 6
        kinds = [e["kind"] for e in s.events()]
        assert kinds.index("calibration_done") < kinds.index("preconditioning_done")


def test_pressure_controller_unplugged_while_commanding(tmp_path):
    """The controller's port vanishes just as the next setpoint is sent: pause, then resend when back."""
    runner, rig, cams, states = _runner(tmp_path, retry_delay_s=0.05)
    orig = runner.on_update
    done = []

    def on_update(state):
        orig(state)
        if state.steps_done == 4 and not done:
            done.append(time.monotonic())
            rig.set_fault("pressure", "controller port vanished")
            threading.Timer(0.4, rig.clear_fault, args=("pressure",)).start()

    runner.on_update = on_update
    assert runner.run() == "complete"
    with open_session(tmp_path / "s.h5") as s:
        assert s.n_steps == 6 and s.status == "complete"
        faults = [e["message"] for e in s.events() if e["kind"] == "fault"]
        assert any("pressure controller: command failed (Disconnected" in m for m in faults)
        st = s.steps
        assert st["t_monotonic"][4] > done[0] + 0.4  # step 5 waited for the controller
        assert np.all(np.abs(st["pressure"] - st["target_pressure"]) < 0.5 * MMHG)


def test_readings_come_after_the_stage_moved(tmp_path):
    """Pressure already stable at 0 when the stage moves to the next stretch: the step's force must be
    the one at the new stretch, not an average reaching back before the move (fake force law:
    F = 1e-4 * p + (stretch - 1))."""
    class SamplerLikeRig(FakeRig):
        """Stability judged on the samples alone, as acquisition.sampler.Sampler does (the plain fake
        also waits a dwell after every set-point, which would hide the fault)."""

        def is_stable(self, band, dwell, target=None):
            self._gen()
            now = time.monotonic()
            win = np.array([s[3] for s in self._ring["pressure"] if s[1] >= now - dwell])
            return bool(win.size >= 2 and np.all(np.abs(win - (win.mean() if target is None else target)) <= band))

    rig = SamplerLikeRig()
    cams = _cams(rig)

    def stage(stretch):
        rig._gen()  # samples up to the move were taken at the old stretch (the fake generates lazily)
        rig.stretch = stretch

    runner = SessionRunner(parse_protocol(PROTO.replace("dwell_s = 0.05", "dwell_s = 0.2")),
                           _writer(tmp_path / "s.h5", cams), pressure=rig, sampler=rig, cameras=cams,
                           operator=AutoOperator(), stage=stage, tick_s=0.01)
    assert runner.run() == "complete"
    with open_session(tmp_path / "s.h5") as s:
        st = s.steps
    expected = rig.force_per_pa * st["pressure"] + (st["stretch"] - 1.0)
    np.testing.assert_allclose(st["force"], expected, atol=2e-3)
