"""The line-oriented serial link: terminators, partial reads, stale input, spec resolution."""

from types import SimpleNamespace

import numpy as np
import pytest

from acquisition import Disconnected, GarbledReply, InstrumentTimeout, find_port_by_serial, open_pressure
from acquisition.serial_link import SerialLink
from rig_sim.instruments import SimulatedRig
from instr_scripted_port import ScriptedPort


def test_stale_input_is_flushed_before_a_query():
    port = ScriptedPort([(b"?\r\n", b" +1.0E+02\r\n")])
    port.rx += b" +9.9E+01\r\n"  # a late reply from an earlier exchange
    link = SerialLink(port, name="x", timeout=0.05)
    assert link.query(b"?\r\n") == b" +1.0E+02\r\n"


def test_partial_reply_is_a_timeout_keeping_the_bytes():
    link = SerialLink(ScriptedPort([(b"?\r\n", b" +1.0E+0")]), name="x", timeout=0.03)
    with pytest.raises(InstrumentTimeout, match="partial reply") as info:
        link.query(b"?\r\n")
    assert info.value.raw == b" +1.0E+0"


def test_no_reply_is_a_timeout():
    link = SerialLink(ScriptedPort([(b"?\r\n", None)]), name="x", timeout=0.02)
    with pytest.raises(InstrumentTimeout, match="no reply"):
        link.query(b"?\r\n")


def test_endless_line_is_garbled():
    link = SerialLink(ScriptedPort([(b"?\r\n", b"x" * 600)]), name="x", timeout=0.05, max_line=512)
    with pytest.raises(GarbledReply, match="without terminator"):
        link.query(b"?\r\n")


def test_collect_lines_is_a_bounded_tolerant_read():
    link = SerialLink(ScriptedPort([(b"Z\r\n", b"R\r\n*1")]), name="x", timeout=0.05)
    link.send(b"Z\r\n")
    assert link.collect_lines(0.01) == [b"R\r\n"]


def test_find_port_by_serial():
    ports = [SimpleNamespace(device="/dev/ttyUSB0", serial_number="A"),
             SimpleNamespace(device="/dev/ttyUSB1", serial_number="B"),
             SimpleNamespace(device="/dev/ttyS0", serial_number=None)]
    assert find_port_by_serial("B", lambda: ports) == "/dev/ttyUSB1"
    with pytest.raises(Disconnected, match="'C'.*present"):
        find_port_by_serial("C", lambda: ports)


def test_spec_validation_and_unopenable_port(tmp_path):
    with pytest.raises(TypeError, match="spec must be"):
        SerialLink(42, name="x")
    with pytest.raises(ValueError, match="timeout must be > 0"):
        SerialLink("/dev/null", name="x", timeout=0)
    with pytest.raises(Disconnected, match="cannot open port"):
        SerialLink(str(tmp_path / "missing"), name="x")


def test_resolver_callable_is_called_on_every_connect():
    with SimulatedRig(rng=np.random.default_rng(4)) as rig:
        calls = []

        def resolver():
            calls.append(1)
            return rig.device_path("pressure")

        with open_pressure(resolver, reconnect_interval=0.0) as p:
            p.read()
            rig.fault("pressure").unplug()
            with pytest.raises(Disconnected):
                p.read()
            with pytest.raises(Disconnected, match="resolver found no device"):
                p.read()
            rig.fault("pressure").replug()
            p.read()
        assert len(calls) == 3


def test_an_open_pyserial_port_can_be_injected():
    import serial

    with SimulatedRig(rng=np.random.default_rng(6)) as rig:
        port = serial.Serial(rig.device_path("force"), timeout=0.1)
        from acquisition import open_load_cell

        with open_load_cell(port) as f:
            assert f.read().unit == "N"
        assert not port.is_open


# -- through the whole driver: random replies give a reading or a typed error; cut replies time out ----
from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from acquisition import InstrumentError, Mark10ForceGauge, MensorPressure  # noqa: E402

M_OPEN = [(b"ID?\r\n", b" MENSOR, CPG2500, 1, 1.00\r\n"), (b"Units?\r\n", b" mmHg\r\n"), (b"Ptype?\r\n", b" GAUGE\r\n")]
K_OPEN = [(b"LIST\r\n", b"V1.00;N;CUR;FLTC8;FLTP1;B0\r\n"), (b"RM\r\n", b"M5-20\r\n"), (b"RS\r\n", b"1\r\n"),
          (b"RV\r\n", b"1.00\r\n")]


def _driver(kind, reply):
    if kind == "mensor":
        port = ScriptedPort(M_OPEN + [(b"?\r\n", reply), (b"Error?\r\n", b" NO ERROR\r\n")])
        return MensorPressure(SerialLink(port, name="m", timeout=0.01), retries=0)
    port = ScriptedPort(K_OPEN + [(b"?\r\n", reply)])
    return Mark10ForceGauge(SerialLink(port, name="k", timeout=0.01), retries=0)


@settings(max_examples=60, deadline=None)
@given(st.sampled_from(["mensor", "mark10"]), st.binary(max_size=30))
def test_random_replies_through_the_driver(kind, body):
    dev = _driver(kind, body + b"\r\n")
    try:
        r = dev.read()
    except InstrumentError:
        return
    assert np.isfinite(r.value)


@settings(max_examples=40, deadline=None)
@given(st.sampled_from([("mensor", b" +1.234560E+02\r\n"), ("mark10", b"-18.78 lbF\r\n")]),
       st.integers(min_value=1, max_value=12))
def test_replies_cut_before_the_terminator_time_out(case, cut):
    kind, full = case
    dev = _driver(kind, full[: min(cut, len(full) - 2)])
    with pytest.raises(InstrumentTimeout):
        dev.read()
