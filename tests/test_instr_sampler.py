"""The background sampler: lossless, duplicate-free record; faults and recovery; stability test."""

import time

import numpy as np
import pytest

from acquisition import (Disconnected, InstrumentTimeout, Reading, Sampler, open_load_cell, open_pressure)
from rig_sim.instruments import SimulatedRig

MMHG = 133.322387415


class FakeClock:
    def __init__(self, t=100.0):
        self.t = t

    def __call__(self):
        return self.t


class FakeInstrument:
    """Returns scripted values; an exception instance in the script is raised instead."""

    def __init__(self, script, clock=None, read_time=0.0):
        self.script = list(script)
        self.clock = clock
        self.read_time = read_time

    def read(self):
        item = self.script.pop(0) if len(self.script) > 1 else self.script[0]
        if self.clock is not None:
            self.clock.t += self.read_time
        if isinstance(item, Exception):
            raise item
        return Reading(value=float(item), raw=f"{item}", unit="Pa")


def test_validation():
    with pytest.raises(ValueError, match="rate_hz"):
        Sampler(FakeInstrument([1]), None, rate_hz=0)
    with pytest.raises(ValueError, match="at least one instrument"):
        Sampler(None, None)
    s = Sampler(FakeInstrument([1]), None)
    with pytest.raises(ValueError, match="channel must be one of"):
        s.latest("force")


def test_drain_returns_every_sample_exactly_once_with_midpoint_timestamps():
    clock, wall = FakeClock(10.0), FakeClock(1.7e9)
    s = Sampler(FakeInstrument([1, 2, 3, 4, 5], clock, read_time=0.002), FakeInstrument([7.0]),
                clock=clock, wall_clock=wall)
    for _ in range(3):
        s.poll_once()
        clock.t += 0.02
    a = s.drain("pressure")
    assert a.seq.tolist() == [0, 1, 2] and a.value.tolist() == [1, 2, 3] and a.raw == ["1", "2", "3"]
    assert a.t_monotonic[0] == pytest.approx(10.001) and np.all(np.diff(a.t_monotonic) > 0)
    assert len(s.drain("pressure")) == 0
    s.poll_once()
    b = s.drain("pressure")
    assert b.seq.tolist() == [3] and b.lost == 0
    assert s.drain("force").seq.tolist() == [0, 1, 2, 3]
    assert s.latest("pressure").value == 4 and len(s.history("pressure")) == 4


def test_pending_overflow_is_counted_never_silent():
    s = Sampler(FakeInstrument([0, 1, 2, 3, 4]), None, max_pending=3)
    for _ in range(5):
        s.poll_once()
    rec = s.drain("pressure")
    assert rec.seq.tolist() == [2, 3, 4] and rec.lost == 2
    assert s.drain("pressure").lost == 0


def test_faults_do_not_consume_sequence_numbers_and_are_reported():
    calls = []
    inst = FakeInstrument([1, InstrumentTimeout("no reply"), InstrumentTimeout("no reply"), 2,
                           Disconnected("unplugged"), Disconnected("unplugged"), 3])
    s = Sampler(inst, None, on_status=lambda ch, st: calls.append((ch, st.state)))
    for _ in range(7):
        s.poll_once()
    assert s.drain("pressure").seq.tolist() == [0, 1, 2]
    kinds = [e.kind for e in s.drain_events()]
    assert kinds == ["fault", "fault", "recovered", "disconnected", "recovered"]
    assert [c[1] for c in calls] == ["ok", "fault", "ok", "disconnected", "ok"]
    assert s.status("pressure").n_faults == 2 and s.healthy


def test_is_stable_with_an_injected_clock():
    clock = FakeClock(0.0)
    values = [1000.0 + 5 * np.sin(i) for i in range(40)] + [1100.0] + [1000.0] * 40
    inst = FakeInstrument(values)
    s = Sampler(inst, None, rate_hz=10, clock=clock)

    def step(n):
        for _ in range(n):
            s.poll_once()
            clock.t += 0.1

    step(5)
    assert not s.is_stable(10.0, 1.0)          # window does not reach back 1 s yet
    step(35)
    assert s.is_stable(10.0, 1.0, target_pa=1000.0)
    assert not s.is_stable(2.0, 1.0, target_pa=1000.0)   # band too tight
    assert not s.is_stable(10.0, 1.0, target_pa=1050.0)  # wrong target
    step(1)                                    # the excursion to 1100 Pa
    assert not s.is_stable(10.0, 1.0, target_pa=1000.0)
    step(12)                                   # > 1 s after the excursion
    assert s.is_stable(10.0, 1.0, target_pa=1000.0)
    clock.t += 2.0                             # no fresh samples: not stable
    assert not s.is_stable(10.0, 1.0, target_pa=1000.0)


def test_a_fault_inside_the_dwell_window_breaks_stability():
    clock = FakeClock(0.0)
    inst = FakeInstrument([500.0] * 20 + [InstrumentTimeout("x")] + [500.0] * 30)
    s = Sampler(inst, None, rate_hz=10, clock=clock)
    for i in range(21):
        s.poll_once()
        clock.t += 0.1
    assert not s.is_stable(5.0, 1.0)
    for i in range(11):
        s.poll_once()
        clock.t += 0.1
    assert s.is_stable(5.0, 1.0)


@pytest.fixture
def rig():
    with SimulatedRig(rng=np.random.default_rng(11), tau_s=0.05) as r:
        yield r


def test_threads_keep_a_gapless_record_through_faults(rig):
    statuses = []
    with open_pressure(rig.pressure_port, timeout=0.05, retries=1) as p, \
            open_load_cell(rig.load_cell_port, timeout=0.05, retries=1) as f:
        s = Sampler(p, f, rate_hz=100, on_status=lambda ch, st: statuses.append((ch, st.state)))
        chunks = {"pressure": [], "force": []}
        with s:
            for k in range(6):
                time.sleep(0.1)
                if k == 1:
                    rig.fault("pressure").garble(1)
                    rig.fault("force").device_error()
                if k == 3:
                    rig.fault("pressure").silence(2)  # exhausts the retry: one fault event
                for ch in chunks:
                    chunks[ch].append(s.drain(ch))
        for ch in chunks:
            chunks[ch].append(s.drain(ch))
            seq = np.concatenate([c.seq for c in chunks[ch]])
            t = np.concatenate([c.t_monotonic for c in chunks[ch]])
            assert seq.tolist() == list(range(len(seq))), ch       # no loss, no duplicate
            assert np.all(np.diff(t) > 0)
            assert len(seq) > 30, (ch, len(seq))
            assert sum(c.lost for c in chunks[ch]) == 0
        events = s.drain_events()
        assert ("force", "fault") in [(e.channel, e.kind) for e in events]
        assert ("pressure", "fault") in [(e.channel, e.kind) for e in events]
        assert p.n_retries >= 2


def test_sampler_pauses_on_unplug_and_resumes_on_replug(rig):
    statuses = []
    with open_load_cell(rig.load_cell_port, reconnect_interval=0.02) as f:
        s = Sampler(None, f, rate_hz=100, on_status=lambda ch, st: statuses.append(st.state))
        with s:
            time.sleep(0.1)
            rig.fault("force").unplug()
            time.sleep(0.15)
            assert s.status("force").state == "disconnected" and not s.healthy
            n_during = s.status("force").n_ok
            rig.fault("force").replug()
            t_end = time.monotonic() + 2.0
            while s.status("force").state != "ok" and time.monotonic() < t_end:
                time.sleep(0.01)
            time.sleep(0.1)
        rec = s.drain("force")
        assert rec.seq.tolist() == list(range(len(rec)))
        assert len(rec) > n_during
        assert statuses[:3] == ["ok", "disconnected", "ok"]
        kinds = [e.kind for e in s.drain_events()]
        assert kinds == ["disconnected", "recovered"]


def test_wait_stable_against_the_controller(rig):
    with open_pressure(rig.pressure_port) as p:
        p.set_mode("control")
        with Sampler(p, None, rate_hz=100) as s:
            assert not s.is_stable(20.0, 0.2, target_pa=120 * MMHG)
            p.set_setpoint(120 * MMHG)
            assert s.wait_stable(20.0, 0.2, target_pa=120 * MMHG, timeout_s=3.0)
            assert abs(s.latest("pressure").value - 120 * MMHG) < 20.0


def test_dwell_longer_than_the_ring_buffer_is_refused():
    s = Sampler(FakeInstrument([1.0]), None, rate_hz=50, ring_size=100)
    with pytest.raises(ValueError, match="ring_size"):
        s.is_stable(1.0, 3.0)


def test_simulated_rig_exposes_controller_state_and_takes_any_mechanics():
    with SimulatedRig(rng=np.random.default_rng(1), tau_s=0.01, force_noise_n=0.0) as rig:
        rig.set_mechanics(lambda p, stretch: 2.0 * stretch + p * 1e-4)
        rig.set_stretch(1.5)
        with open_pressure(rig.pressure_port) as p, open_load_cell(rig.load_cell_port) as f:
            p.set_mode("control")
            p.set_setpoint(10_000.0)
            assert rig.controller_mode == "CONTROL" and rig.setpoint_pa == pytest.approx(10_000.0, rel=1e-6)
            assert rig.target_pa == pytest.approx(10_000.0, rel=1e-6)
            time.sleep(0.1)
            assert f.read().value == pytest.approx(3.0 + 1.0, abs=0.002)


def test_total_force_cell_reads_wall_force_minus_pressure_end_load():
    with SimulatedRig(rng=np.random.default_rng(2), tau_s=0.01, force_noise_n=0.0, load_cell_measures="total",
                      cannula_radius_m=2e-3, pressure_source="manual") as rig:
        rig.set_operator_pressure(16_000.0)
        rig.set_stretch(1.2)
        time.sleep(0.1)
        with open_load_cell(rig.load_cell_port) as f:
            expected = rig.true_wall_force() - 16_000.0 * np.pi * 2e-3**2
            assert f.read().value == pytest.approx(expected, abs=0.0015)
