"""The real drivers against the simulated instruments over real pseudo-terminals (and a socket)."""

import os
import pty
import time

import numpy as np
import pytest

from acquisition import (DeviceError, Disconnected, GarbledReply, InstrumentTimeout, open_load_cell,
                         open_pressure)
from rig_sim.instruments import SimulatedRig

MMHG = 133.322387415


@pytest.fixture
def rig():
    with SimulatedRig(rng=np.random.default_rng(7), tau_s=0.05, pressure_noise_pa=1.0, force_noise_n=0.001) as r:
        yield r


@pytest.fixture
def manual_rig():
    with SimulatedRig(pressure_source="manual", rng=np.random.default_rng(8), tau_s=0.05) as r:
        yield r


def wait_for(pred, timeout=3.0):
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if pred():
            return True
        time.sleep(0.01)
    return False


def test_ports_are_real_ptys_behind_stable_links(rig):
    assert os.path.islink(rig.pressure_port)
    assert os.path.realpath(rig.pressure_port).startswith("/dev/pts/")
    assert rig.device_path("force").startswith("/dev/pts/")


def test_controller_setpoint_stable_and_readings(rig):
    with open_pressure(rig.pressure_port) as p, open_load_cell(rig.load_cell_port) as f:
        assert p.is_controller and p.unit == "mmHg" and p.ptype == "gauge"
        p.set_mode("control")
        p.set_setpoint(100 * MMHG)
        assert p.setpoint() == pytest.approx(100 * MMHG, rel=1e-6)
        assert wait_for(p.device_stable)
        r = p.read()
        assert r.unit == "mmHg" and r.value == pytest.approx(100 * MMHG, abs=25.0)
        assert float(r.raw) == pytest.approx(r.value / MMHG, rel=1e-6)
        rig.set_stretch(1.1)
        expected = rig.true_force()
        forces = [f.read().value for _ in range(20)]
        assert np.mean(forces) == pytest.approx(expected, abs=0.002)
        assert expected > 0.4  # tension positive in SI
        p.set_mode("vent")
        assert wait_for(lambda: abs(p.read().value) < 30.0)


def test_units_change_keeps_si_values(rig):
    rig.set_operator_pressure(50 * MMHG)
    with open_pressure(rig.pressure_port) as p, open_load_cell(rig.load_cell_port) as f:
        assert wait_for(lambda: abs(p.read().value - 50 * MMHG) < 10)
        time.sleep(0.3)  # > 5 time constants: settled
        p.set_unit("kPa")
        r = p.read()
        assert r.unit == "kPa" and r.value == pytest.approx(50 * MMHG, abs=10.0)
        assert float(r.raw) == pytest.approx(r.value / 1e3, abs=1e-5)
        rig.set_stretch(1.2)
        n = np.mean([f.read().value for _ in range(10)])
        f.set_unit("lbF")
        r = f.read()
        assert r.unit == "lbF" and r.raw.endswith(" lbF")
        assert r.value == pytest.approx(n, abs=0.01)


def test_zero_tares_the_load_cell_only_when_asked(rig):
    rig.set_stretch(1.15)
    with open_load_cell(rig.load_cell_port) as f:
        before = np.mean([f.read().value for _ in range(10)])
        assert before > 0.5
        f.zero()
        after = np.mean([f.read().value for _ in range(10)])
        assert abs(after) < 0.005


def test_manual_indicator_follows_operator_and_refuses_controller_commands(manual_rig):
    with open_pressure(manual_rig.pressure_port) as p:
        assert not p.is_controller and "CPG2500" in p.identity
        manual_rig.set_operator_pressure(80 * MMHG)
        assert wait_for(lambda: abs(p.read().value - 80 * MMHG) < 10)
        time.sleep(0.3)
        with pytest.raises(DeviceError) as info:
            p.set_mode("control")
        assert any("Mode" in m for m in info.value.messages)
        assert p.read().value == pytest.approx(80 * MMHG, abs=10)  # queue drained: next reading clean


@pytest.mark.parametrize("channel", ["pressure", "force"])
def test_garbled_and_truncated_replies_are_retried(rig, channel):
    opener = open_pressure if channel == "pressure" else open_load_cell
    port = rig.pressure_port if channel == "pressure" else rig.load_cell_port
    with opener(port, retries=2, timeout=0.1) as dev:
        rig.fault(channel).garble(1)
        dev.read()
        rig.fault(channel).truncate(1)
        dev.read()
        assert dev.n_retries == 2
        rig.fault(channel).garble(3)
        with pytest.raises(GarbledReply):
            dev.read()
        dev.read()  # recovered


@pytest.mark.parametrize("channel", ["pressure", "force"])
def test_silence_is_retried_then_a_timeout(rig, channel):
    opener = open_pressure if channel == "pressure" else open_load_cell
    port = rig.pressure_port if channel == "pressure" else rig.load_cell_port
    with opener(port, retries=1, timeout=0.1) as dev:
        rig.fault(channel).silence(1)
        dev.read()
        rig.fault(channel).silence(2)
        with pytest.raises(InstrumentTimeout):
            dev.read()
        dev.read()


def test_device_errors_are_reported_not_dropped(rig):
    with open_pressure(rig.pressure_port) as p, open_load_cell(rig.load_cell_port) as f:
        rig.fault("pressure").device_error()
        with pytest.raises(DeviceError) as info:
            p.read()
        assert info.value.messages == ["Simulated device error: over pressure"]
        assert info.value.value is not None
        p.read()
        rig.fault("force").device_error()
        with pytest.raises(DeviceError) as info:
            f.read()
        assert info.value.code == "*10"
        f.read()


def test_slow_device_within_and_beyond_the_timeout(rig):
    with open_pressure(rig.pressure_port, timeout=0.3, retries=0) as p:
        rig.fault("pressure").slow(0.05)
        t0 = time.monotonic()
        p.read()
        assert time.monotonic() - t0 >= 0.05
        rig.fault("pressure").slow(0.6)
        with pytest.raises(InstrumentTimeout):
            p.read()
        rig.fault("pressure").slow(0.0)
        time.sleep(0.4)  # the late reply arrives; it must not be taken for the next answer
        p.set_unit("kPa")
        assert p.unit == "kPa"


@pytest.mark.parametrize("channel", ["pressure", "force"])
def test_unplug_gives_disconnected_and_replug_reconnects(rig, channel):
    opener = open_pressure if channel == "pressure" else open_load_cell
    port = rig.pressure_port if channel == "pressure" else rig.load_cell_port
    with opener(port, reconnect_interval=0.05) as dev:
        dev.read()
        old = rig.device_path(channel)
        rig.fault(channel).unplug()
        with pytest.raises(Disconnected):
            dev.read()
        time.sleep(0.06)
        with pytest.raises(Disconnected):  # still gone: fails fast, no hang
            dev.read()
        if channel == "pressure":
            rig.mensor.unit = "kPa"  # changed while unplugged: must be re-read after the reconnect
        rig.fault(channel).replug()
        assert rig.device_path(channel) is not None and old is not None
        time.sleep(0.06)
        r = dev.read()
        assert dev.link.n_connects == 2
        if channel == "pressure":
            assert r.unit == "kPa" and dev.unit == "kPa"


def test_lookup_by_usb_serial_number_follows_re_enumeration(rig):
    with open_pressure(f"usb-serial:{rig.pressure_serial}", list_ports=rig.list_ports,
                       reconnect_interval=0.0) as p:
        first = p.link.device
        assert first == rig.device_path("pressure")
        rig.fault("pressure").unplug()
        with pytest.raises(Disconnected):
            p.read()
        with pytest.raises(Disconnected, match="no serial port with USB serial number"):
            p.read()
        squatter = pty.openpty()  # takes the freed /dev/pts number: the device re-enumerates elsewhere
        try:
            rig.fault("pressure").replug()
            p.read()
            assert p.link.device == rig.device_path("pressure") != first
        finally:
            for fd in squatter:
                os.close(fd)


def test_socket_transport_and_reconnect():
    with SimulatedRig(transport="socket", rng=np.random.default_rng(3)) as rig:
        assert rig.pressure_port.startswith("socket://127.0.0.1:")
        with open_pressure(rig.pressure_port, reconnect_interval=0.0) as p, \
                open_load_cell(rig.load_cell_port, reconnect_interval=0.0) as f:
            p.read()
            f.read()
            rig.fault("force").unplug()
            with pytest.raises(Disconnected):
                f.read()
            rig.fault("force").replug()
            assert wait_for(lambda: _ok(f))
            p.read()


def _ok(dev) -> bool:
    try:
        dev.read()
        return True
    except Disconnected:
        return False
