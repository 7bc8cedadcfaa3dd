"""Mark-10 command set: byte-exact request/reply pairs, and parsers that never crash on bad input."""

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from acquisition.instrument_errors import DeviceError, GarbledReply, InstrumentError
from acquisition.mark10 import (Mark10ForceGauge, decode_line, encode, filter_command, parse_force, parse_list,
                                unit_command)
from acquisition.serial_link import SerialLink
from instr_scripted_port import ScriptedPort

LBF = 4.4482216152605
LIST_N = b"V1.00;N;CUR;FLTC8;FLTP1;AOUT00;AOFF5;FULL;MIT;POL;B0\r\n"
OPEN = [(b"LIST\r\n", LIST_N), (b"RM\r\n", b"M5-20\r\n"), (b"RS\r\n", b"1234567\r\n"), (b"RV\r\n", b"1.00\r\n")]


def make(script, **kw):
    port = ScriptedPort(OPEN + script)
    link = SerialLink(port, name="mark10", timeout=0.05)
    return Mark10ForceGauge(link, retries=0, ack_window=0.005, **kw), port


def test_encoding_is_byte_exact():
    assert encode("?") == b"?\r\n"
    assert encode("LIST") == b"LIST\r\n"
    assert encode(unit_command("lbF")) == b"LB\r\n"
    assert encode(unit_command("N")) == b"N\r\n"
    assert encode(unit_command("kN")) == b"KN\r\n"
    assert filter_command("current", 4) == "FLTP4" and filter_command("displayed", 10) == "FLTC10"
    with pytest.raises(ValueError, match="0..10"):
        filter_command("current", 11)
    with pytest.raises(ValueError, match="uppercase"):
        encode("z")


def test_open_reads_list_and_identity_without_changing_anything():
    f, port = make([])
    assert port.done
    assert f.unit == "N" and f.config["mode"] == "CUR" and f.config["filter_current"] == 1
    assert f.identity == "Mark-10 model M5-20 s/n 1234567 fw 1.00"


def test_reading_compression_positive_on_the_wire_tension_positive_in_si():
    f, port = make([(b"?\r\n", b"4.285 N\r\n"), (b"?\r\n", b"-18.78 lbF\r\n")])
    r = f.read()
    assert r.value == pytest.approx(-4.285) and r.raw == "4.285 N" and r.unit == "N"
    r = f.read()
    assert r.value == pytest.approx(18.78 * LBF) and r.unit == "lbF"
    assert port.done


def test_compression_positive_option():
    f, _ = make([(b"?\r\n", b"4.285 N\r\n")], tension_positive=False)
    assert f.read().value == pytest.approx(4.285)


def test_reading_without_unit_uses_the_listed_unit():
    f, _ = make([(b"?\r\n", b"-1.5\r\n")])
    assert f.read().value == pytest.approx(1.5)


def test_zero_unit_mode_filter_byte_exact_and_confirmed_by_list():
    list_lbf = b"V1.00;LBF;PT;FLTC8;FLTP4;AOUT00;AOFF5;FULL;MIT;POL;B0\r\n"
    f, port = make([(b"Z\r\n", None), (b"LB\r\n", None), (b"LIST\r\n", list_lbf),
                    (b"PT\r\n", None), (b"LIST\r\n", list_lbf), (b"FLTP4\r\n", None), (b"LIST\r\n", list_lbf)])
    f.zero()
    f.set_unit("lbF")
    f.set_mode("PT")
    f.set_filter("current", 4)
    assert f.unit == "lbF" and port.done


def test_setting_not_confirmed_is_a_device_error():
    f, _ = make([(b"KN\r\n", None), (b"LIST\r\n", LIST_N)])
    with pytest.raises(DeviceError, match="LIST reports 'N'"):
        f.set_unit("kN")


def test_acknowledgement_lines_after_a_set_are_tolerated():
    f, port = make([(b"Z\r\n", b"R\r\n"), (b"?\r\n", b"0.000 N\r\n")])
    f.zero()
    assert f.read().value == 0.0 and port.done


@pytest.mark.parametrize("code, meaning", [("*10", "illegal command"), ("*11", "not applicable"),
                                           ("*12", "invalid specifier"), ("*22", "value too large")])
def test_error_codes_are_typed(code, meaning):
    f, _ = make([(b"?\r\n", code.encode() + b"\r\n")])
    with pytest.raises(DeviceError, match=meaning) as info:
        f.read()
    assert info.value.code == code


def test_error_code_after_a_set_command_is_raised():
    f, _ = make([(b"FLTC9\r\n", b"*22\r\n")])
    with pytest.raises(DeviceError) as info:
        f.set_filter("displayed", 9)
    assert info.value.code == "*22"


def test_parse_list_fields():
    cfg = parse_list(b"V1.00;LBF;CUR;FLTC8;FLTP1;AOUT00;AOFF5;FULL;MIT;POL;B3\r\n")
    assert cfg["version"] == "1.00" and cfg["unit"] == "lbF" and cfg["mode"] == "CUR"
    assert cfg["filter_displayed"] == 8 and cfg["filter_current"] == 1 and cfg["battery"] == 3
    with pytest.raises(GarbledReply):
        parse_list(b"4.285 N\r\n")


@pytest.mark.parametrize("raw", [b"4.285 furlongs\r\n", b"N 4.2\r\n", b"\xfe\xff\r\n", b"\r\n", b"4.2.1 N\r\n"])
def test_bad_readings_are_garbled(raw):
    with pytest.raises(GarbledReply):
        parse_force(raw, "N")


VALID = [b"4.285 N\r\n", b"-18.78 lbF\r\n", LIST_N, b"*10\r\n", b"M5-20\r\n", b"0.0012 kN\r\n"]


def _all_parsers(raw: bytes) -> None:
    for fn in (lambda r: parse_force(r, "N"), lambda r: parse_force(r, None), parse_list, decode_line):
        try:
            fn(raw)
        except InstrumentError:
            pass


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=60))
def test_random_bytes_never_crash_the_parsers(raw):
    _all_parsers(raw)


@settings(max_examples=200, deadline=None)
@given(st.sampled_from(VALID), st.integers(min_value=0, max_value=60))
def test_truncated_replies_give_a_value_or_a_typed_error(raw, cut):
    _all_parsers(raw[:cut])


@settings(max_examples=200, deadline=None)
@given(st.floats(min_value=-1e4, max_value=1e4, allow_nan=False), st.sampled_from(["N", "lbF", "kgF", "mN"]))
def test_reading_round_trip(value, unit):
    v, u, _ = parse_force(f"{value:.4f} {unit}\r\n".encode(), None)
    assert u == unit and v == pytest.approx(round(value, 4), abs=1e-9)
