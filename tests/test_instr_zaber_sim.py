"""The Zaber driver against the simulated stage over a real pseudo-terminal.

The simulator's motion runs on a fake clock that the driver's own ``sleep`` advances, so moves of a
second or more take a few milliseconds of wall time and every position is deterministic.
"""

import os
import threading
import time

import numpy as np
import pytest

from acquisition.instrument_errors import Disconnected, GarbledReply, InstrumentTimeout
from acquisition.stage import StretchStage
from acquisition.zaber import (StageFault, StageNotHomed, StageRejected, StageSettings, StageTravelError,
                               open_zaber)
from rig_sim.zaber_sim import SimulatedStage, ZaberDevice

USTEP = 0.047625e-6
SETTINGS = StageSettings(microstep_m=USTEP, min_m=0.001, max_m=0.045)


class FakeClock:
    def __init__(self):
        self.t = 0.0
        self.lock = threading.Lock()

    def __call__(self):
        return self.t

    def sleep(self, s):
        with self.lock:
            self.t += s


@pytest.fixture
def clock():
    return FakeClock()


@pytest.fixture
def sim(clock):
    with SimulatedStage(ZaberDevice(clock=clock, speed=200_000.0, start=300_000),
                        rng=np.random.default_rng(11)) as s:
        yield s


def opened(sim, clock, settings=SETTINGS, **kw):
    kw.setdefault("timeout", 0.2)
    return open_zaber(sim.port, settings, clock=clock, sleep=clock.sleep, poll_s=0.05, **kw)


def test_port_is_a_real_pty_behind_a_stable_link(sim):
    assert os.path.islink(sim.port) and os.path.realpath(sim.port).startswith("/dev/pts/")


def test_home_then_move_at_finite_speed(sim, clock):
    with opened(sim, clock) as stage:
        assert stage.travel_m == pytest.approx((0.0, 1_066_667 * USTEP))
        with pytest.raises(StageNotHomed):
            stage.move_to(0.010)
        assert "move abs" not in " ".join(sim.device.commands)
        t0 = clock()
        stage.home()
        assert stage.homed and sim.device.homed and sim.device.position() == 0
        assert clock() - t0 == pytest.approx(300_000 / 200_000, abs=0.06)  # 1.5 s of travel to home
        t0 = clock()
        stage.move_to(0.010)
        assert clock() - t0 == pytest.approx(209_974 / 200_000, abs=0.06)
        assert sim.device.position() == 209_974
        assert stage.position() == pytest.approx(0.010, abs=USTEP)
        stage.move_to(0.002, wait=False)
        assert stage.is_busy()
        assert stage.wait_idle(5.0) == pytest.approx(0.002, abs=USTEP)


def test_limits_refused(sim, clock):
    with opened(sim, clock) as stage:
        stage.home()
        n = len(sim.device.commands)
        with pytest.raises(ValueError, match=r"position_m .*\[min_m, max_m\]"):
            stage.move_to(0.046)
        with pytest.raises(ValueError, match="position_m"):
            stage.move_to(0.0)
        assert len(sim.device.commands) == n  # nothing was sent
        with pytest.raises(StageRejected) as info:  # the device's own travel limit
            stage.request("move abs 2000000")
        assert info.value.code == "BADDATA"
        with pytest.raises(StageRejected) as info:
            stage.request("fly")
        assert info.value.code == "BADCOMMAND"
    with pytest.raises(ValueError, match="travel"):
        opened(sim, clock, StageSettings(microstep_m=USTEP, min_m=0.0, max_m=0.06))


def test_a_stall_raises_the_typed_fault_until_cleared(sim, clock):
    with opened(sim, clock) as stage:
        stage.home()
        sim.device.stall_at(100_000)
        with pytest.raises(StageFault) as info:
            stage.move_to(0.010)
        assert info.value.code == "FS"
        assert sim.device.position() == 100_000 and not sim.device.busy()
        with pytest.raises(StageFault):
            stage.position()
        assert stage.clear_warnings() == ["FS"]
        assert stage.position() == pytest.approx(100_000 * USTEP)
        stage.move_to(0.010)
        assert sim.device.position() == 209_974


def test_injected_device_error_stalls_a_moving_axis(sim, clock):
    with opened(sim, clock) as stage:
        stage.home()
        stage.move_to(0.040, wait=False)
        clock.sleep(0.5)
        sim.faults.device_error()
        with pytest.raises(StageFault, match="stalled"):
            stage.wait_idle(10.0)
        assert sim.device.position() == 100_000  # 0.5 s at 200000 microsteps/s


def test_wait_timeout_stops_the_stage(clock):
    with SimulatedStage(ZaberDevice(clock=clock, speed=1000.0, start=0)) as sim:
        with opened(sim, clock) as stage:
            sim.device.homed = True
            stage.move_to(0.005, wait=False)
            with pytest.raises(InstrumentTimeout, match="stop sent"):
                stage.wait_idle(1.0)
            assert not sim.device.busy() and 900 <= sim.device.position() <= 1200


def test_silence_and_garbage_are_retried_then_typed(sim, clock):
    with opened(sim, clock, retries=1, timeout=0.1) as stage:
        sim.faults.silence(1)
        stage.position()
        sim.faults.garble(1)
        stage.position()
        assert stage.n_retries == 2
        sim.faults.garble(2)
        with pytest.raises(GarbledReply):
            stage.position()
        sim.faults.silence(2)
        with pytest.raises(InstrumentTimeout):
            stage.position()
        stage.position()


def test_checksummed_link(clock):
    with SimulatedStage(ZaberDevice(clock=clock, reply_checksum=True)) as sim:
        cfg = StageSettings(microstep_m=USTEP, min_m=0.001, max_m=0.045, checksum=True)
        with opened(sim, clock, cfg) as stage:
            stage.home()
            stage.move_to(0.003)
            assert sim.device.position() == round(0.003 / USTEP)


def test_stretch_stage_drives_the_axial_stretch(sim, clock):
    with opened(sim, clock) as stage:
        stage.home()
        stage.move_to(0.010)
        stretch = StretchStage(stage, gauge_length_m=0.012)
        stretch.zero_here()
        stretch(1.25)
        assert stage.position() == pytest.approx(0.013, abs=USTEP)
        assert stretch.stretch() == pytest.approx(1.25, abs=1e-5)
        with pytest.raises(ValueError, match="out of reach"):
            stretch.check(4.0)
        assert stretch.settings()["stage"]["max_m"] == 0.045


def test_unplug_gives_disconnected_and_replug_re_reads_the_travel(sim, clock):
    with opened(sim, clock, reconnect_interval=0.0) as stage:
        stage.home()
        sim.faults.unplug()
        with pytest.raises(Disconnected):
            stage.position()
        sim.device.limit_max = 950_000
        sim.faults.replug()
        _position_after_reconnect(stage)
        assert stage.travel_m[1] == pytest.approx(950_000 * USTEP) and stage.link.n_connects == 2
        sim.faults.unplug()
        sim.device.limit_max = 900_000  # 0.0429 m: the soft limit max_m = 0.045 m is out of its travel
        sim.faults.replug()
        time.sleep(0.05)
        with pytest.raises(StageTravelError, match="travel"):
            _position_after_reconnect(stage)


def _position_after_reconnect(stage):
    deadline = time.monotonic() + 3.0
    while True:
        try:
            return stage.position()
        except Disconnected:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.02)
