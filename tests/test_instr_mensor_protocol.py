"""Mensor command set: byte-exact request/reply pairs, and parsers that never crash on bad input."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from acquisition.driver_base import Reading
from acquisition.instrument_errors import DeviceError, GarbledReply, InstrumentError
from acquisition.mensor import (MensorPressure, encode_command, encode_query, is_no_error, parse_choice,
                                parse_pressure, parse_reply, parse_unit_name, parse_yes_no, PTYPES, MODES)
from acquisition.serial_link import SerialLink
from instr_scripted_port import ScriptedPort

MMHG = 133.322387415
OPEN = [(b"ID?\r\n", b" MENSOR, CPC6050, 610123, 1.00\r\n"), (b"Units?\r\n", b" mmHg\r\n"),
        (b"Ptype?\r\n", b" GAUGE\r\n")]


def make(script):
    port = ScriptedPort(OPEN + script)
    link = SerialLink(port, name="mensor", timeout=0.05)
    return MensorPressure(link, retries=0), port


def test_encoding_is_byte_exact():
    assert encode_query("") == b"?\r\n"
    assert encode_query("Units") == b"Units?\r\n"
    assert encode_command("Units", 19) == b"Units 19\r\n"
    assert encode_command("Setpt", 100.0) == b"Setpt 100\r\n"
    assert encode_command("Setpt", 12.5) == b"Setpt 12.5\r\n"
    assert encode_command("Mode", "CONTROL") == b"Mode CONTROL\r\n"
    with pytest.raises(ValueError, match="finite"):
        encode_command("Setpt", math.nan)
    with pytest.raises(ValueError, match="keyword"):
        encode_query("Units 1")


def test_open_reads_identity_unit_and_ptype_without_changing_anything():
    p, port = make([])
    assert port.done
    assert p.identity == "MENSOR, CPC6050, 610123, 1.00" and p.is_controller
    assert p.unit == "mmHg" and p.ptype == "gauge"


def test_reading_is_converted_to_pa_and_keeps_raw():
    p, port = make([(b"?\r\n", b" +1.000000E+02\r\n")])
    r = p.read()
    assert r == Reading(value=pytest.approx(100 * MMHG), raw=" +1.000000E+02", unit="mmHg")
    assert port.done


def test_output_format_2_carries_its_own_unit():
    p, _ = make([(b"?\r\n", b" 1.5, kPa, CONTROL\r\n")])
    r = p.read()
    assert r.value == pytest.approx(1500.0) and r.unit == "kPa"


def test_set_unit_sends_code_19_and_confirms_by_query():
    p, port = make([(b"Units 22\r\n", None), (b"Units?\r\n", b" kPa\r\n"),
                    (b"Units 19\r\n", None), (b"Units?\r\n", b" 19\r\n")])
    p.set_unit("kPa")
    assert p.unit == "kPa"
    p.set_unit("mmHg")
    assert p.unit == "mmHg" and port.done


def test_set_unit_not_confirmed_is_a_device_error():
    p, _ = make([(b"Units 22\r\n", None), (b"Units?\r\n", b" PSI\r\n")])
    with pytest.raises(DeviceError, match="device reports 'psi'"):
        p.set_unit("kPa")
    assert p.unit == "psi"  # the driver converts with what the device reports


def test_controller_commands_byte_exact():
    p, port = make([(b"Mode CONTROL\r\n", None), (b"Mode?\r\n", b" CONTROL\r\n"),
                    (b"Setpt 100\r\n", None), (b"Setpt?\r\n", b" +1.000000E+02\r\n"),
                    (b"Stable?\r\n", b" NO\r\n"), (b"Stable?\r\n", b" YES\r\n"),
                    (b"Ptype ABSOLUTE\r\n", None), (b"Ptype?\r\n", b" ABSOLUTE\r\n"),
                    (b"Mode VENT\r\n", None), (b"Mode?\r\n", b" VENT\r\n")])
    p.set_mode("control")
    p.set_setpoint(100 * MMHG)
    assert p.device_stable() is False
    assert p.device_stable() is True
    p.set_ptype("absolute")
    assert p.ptype == "absolute"
    p.set_mode("vent")
    assert port.done


def test_error_flag_reads_the_queue_and_raises_with_the_value():
    p, port = make([(b"?\r\n", b"E+1.000000E+02\r\n"), (b"Error?\r\n", b"E Over pressure\r\n"),
                    (b"Error?\r\n", b" Setpt out of range\r\n")])
    with pytest.raises(DeviceError) as info:
        p.read()
    assert info.value.messages == ["Over pressure", "Setpt out of range"]
    assert info.value.value == pytest.approx(100 * MMHG)
    assert port.done


def test_errors_stops_at_no_error():
    p, port = make([(b"Error?\r\n", b" NO ERROR\r\n")])
    assert p.errors() == [] and port.done


def test_validation_names_the_parameter():
    p, _ = make([])
    with pytest.raises(ValueError, match="unit must be one of"):
        p.set_unit("furlong")
    with pytest.raises(ValueError, match="mode must be one of"):
        p.set_mode("fast")


@pytest.mark.parametrize("raw, ok", [(b" +1.2E+01\r\n", True), (b"E-3.5\r\n", True), (b"+1.2\r\n", False),
                                     (b"\xff 1\r\n", False), (b"\r\n", False), (b" 1\x002\r\n", False)])
def test_parse_reply_framing(raw, ok):
    if ok:
        parse_reply(raw)
    else:
        with pytest.raises(GarbledReply):
            parse_reply(raw)


def test_parse_helpers():
    assert parse_unit_name("19") == "mmHg" and parse_unit_name("MMHG") == "mmHg"
    assert parse_unit_name("mmHg @0C") == "mmHg" and parse_unit_name("kPa") == "kPa"
    assert parse_yes_no(parse_reply(b" YES\r\n")) and not parse_yes_no(parse_reply(b" NO\r\n"))
    assert parse_choice(parse_reply(b" CONTROL\r\n"), MODES) == "control"
    assert is_no_error(parse_reply(b" NO ERROR\r\n")) and not is_no_error(parse_reply(b" Over pressure\r\n"))
    with pytest.raises(GarbledReply):
        parse_unit_name("99")


# -- property tests: any bytes, any truncation -> a value or a typed error, never a crash ----------
VALID = [b" +1.234560E+02\r\n", b" mmHg\r\n", b" YES\r\n", b" CONTROL\r\n", b" GAUGE\r\n", b"E NO ERROR\r\n",
         b" 1.5, kPa, CONTROL\r\n"]


def _all_parsers(raw: bytes) -> None:
    for fn in (lambda r: parse_pressure(parse_reply(r), "mmHg"), lambda r: parse_yes_no(parse_reply(r)),
               lambda r: parse_choice(parse_reply(r), PTYPES), lambda r: parse_unit_name(parse_reply(r).text),
               lambda r: is_no_error(parse_reply(r))):
        try:
            fn(raw)
        except InstrumentError:
            pass


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=40))
def test_random_bytes_never_crash_the_parsers(raw):
    _all_parsers(raw)


@settings(max_examples=200, deadline=None)
@given(st.sampled_from(VALID), st.integers(min_value=0, max_value=20))
def test_truncated_replies_give_a_value_or_a_typed_error(raw, cut):
    _all_parsers(raw[:cut])


@settings(max_examples=200, deadline=None)
@given(st.floats(min_value=-1e6, max_value=1e6, allow_nan=False))
def test_reading_round_trip(value):
    raw = f" {value:+.6E}\r\n".encode()
    pa, unit = parse_pressure(parse_reply(raw), "kPa")
    assert pa == pytest.approx(value * 1e3, rel=1e-6, abs=1e-9) and unit == "kPa"


def test_units_that_can_only_be_read_still_convert():
    assert parse_unit_name("inH2O @4C") == "inH2O" and parse_unit_name("HPA") == "hPa"
    value, unit = parse_pressure(parse_reply(b" +1.000000E+01\r\n"), "cmH2O")
    assert value == pytest.approx(980.638) and unit == "cmH2O"
