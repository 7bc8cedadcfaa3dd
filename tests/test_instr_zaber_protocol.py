"""Zaber ASCII: byte-exact request/reply pairs, every reply kind, checksums, units and the stretch mapping.

The checksummed lines are the examples of Zaber's own libraries and manual (``/1 tools echo:BF``,
``/01 tools echo:8F``, ``/get maxspeed:49``, ``/2 0 5 get maxspeed:52``, ``@01 0 OK IDLE -- 0:8D``,
``@01 0 OK IDLE -- 7z:0C``, ``@1 3 9 OK IDLE -- 0:61``).
"""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from acquisition.instrument_errors import DeviceError, GarbledReply, InstrumentError, InstrumentTimeout
from acquisition.serial_link import SerialLink
from acquisition.stage import StretchStage, position_from_stretch, stretch_from_position
from acquisition.zaber import (StageFault, StageNotHomed, StageRejected, StageSettings, ZaberStage, check_reply,
                               checksum, encode_command, move_abs_command, parse_int, parse_reply, to_metres,
                               to_microsteps)
from instr_scripted_port import ScriptedPort

USTEP = 0.047625e-6  # m per microstep of a common Zaber lead-screw stage
OPEN = [(b"/1 1 get limit.min\n", b"@01 1 OK IDLE WR 0\r\n"),
        (b"/1 1 get limit.max\n", b"@01 1 OK IDLE WR 1066667\r\n")]
SETTINGS = StageSettings(microstep_m=USTEP, min_m=0.001, max_m=0.045)


class FakeClock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t

    def sleep(self, s):
        self.t += s


def make(script, settings_=SETTINGS, retries=0, clock=None):
    port = ScriptedPort(OPEN + script)
    link = SerialLink(port, name="stage", timeout=0.05)
    clock = clock or FakeClock()
    return ZaberStage(link, settings_, retries=retries, poll_s=0.06, clock=clock, sleep=clock.sleep), port


# -- encoding -------------------------------------------------------------------------------------
def test_commands_are_byte_exact():
    assert encode_command(1, 1, "home") == b"/1 1 home\n"
    assert encode_command(1, 1, move_abs_command(209974)) == b"/1 1 move abs 209974\n"
    assert encode_command(1, 1, "get pos") == b"/1 1 get pos\n"
    assert encode_command(1, 1, "get limit.max") == b"/1 1 get limit.max\n"
    assert encode_command(1, 1, "stop") == b"/1 1 stop\n"
    assert encode_command(1, 1) == b"/1 1\n"
    assert encode_command(1, 0, "warnings clear") == b"/1 0 warnings clear\n"


def test_documented_checksums():
    assert checksum("1 tools echo") == "BF"
    assert checksum("01 tools echo") == "8F"
    assert checksum("get maxspeed") == "49"
    assert checksum("1") == "CF"
    assert encode_command(1, None, "tools echo", with_checksum=True) == b"/1 tools echo:BF\n"
    assert encode_command(2, 0, "get maxspeed", message_id=5, with_checksum=True) == b"/2 0 5 get maxspeed:52\n"
    assert encode_command(1, None, with_checksum=True) == b"/1:CF\n"
    assert parse_reply(b"@01 0 OK IDLE -- 0:8D\r\n").data == "0"
    assert parse_reply(b"@01 0 OK IDLE -- 7z:0C\r\n").data == "7z"
    r = parse_reply(b"@1 3 9 OK IDLE -- 0:61\r\n")
    assert (r.device, r.axis, r.message_id, r.data) == (1, 3, 9, "0")


@pytest.mark.parametrize("raw", [b"@01 0 OK IDLE -- 0:8E\r\n", b"@01 0 OK IDLE -- 0:GG\r\n"])
def test_bad_checksum_is_a_garbled_reply(raw):
    with pytest.raises(GarbledReply, match="checksum"):
        parse_reply(raw)


def test_encoding_validation_names_the_parameter():
    with pytest.raises(ValueError, match="device"):
        encode_command(100, 1, "home")
    with pytest.raises(ValueError, match="axis"):
        encode_command(1, 10, "home")
    with pytest.raises(ValueError, match="message_id"):
        encode_command(1, None, "home", message_id=3)
    with pytest.raises(ValueError, match="command"):
        encode_command(1, 1, "HOME\r/2 stop")
    with pytest.raises(ValueError, match="microsteps"):
        move_abs_command(2**31)
    with pytest.raises(ValueError, match="microsteps"):
        move_abs_command(1.5)


# -- parsing: every reply kind ----------------------------------------------------------------------
def test_reply_kinds():
    r = parse_reply(b"@01 1 OK IDLE -- 0\r\n")
    assert (r.kind, r.device, r.axis, r.flag, r.status, r.warning, r.data) == ("@", 1, 1, "OK", "IDLE", "--", "0")
    assert not (r.busy or r.rejected or r.fault or r.needs_homing) and r.message_id is None
    r = parse_reply(b"@01 1 OK BUSY WR 0\r\n")
    assert r.busy and r.needs_homing and not r.fault
    r = parse_reply(b"@01 1 RJ IDLE -- BADDATA\r\n")
    assert r.rejected and r.data == "BADDATA"
    r = parse_reply(b"@01 1 OK IDLE FS 0\r\n")
    assert r.fault and r.warning == "FS"
    r = parse_reply(b"@04 2 12 OK IDLE -- 123\r\n")
    assert (r.device, r.axis, r.message_id, parse_int(r)) == (4, 2, 12, 123)
    r = parse_reply(b"@01 0 OK IDLE -- 0 1  a b \r\n")
    assert r.data == "0 1  a b "
    r = parse_reply(b"!01 1 IDLE --\r\n")
    assert (r.kind, r.status, r.warning, r.flag) == ("!", "IDLE", "--", None)
    r = parse_reply(b"#01 0 Visit www.zaber.com for instruction manuals.\r\n")
    assert r.kind == "#" and r.data == "Visit www.zaber.com for instruction manuals."


@pytest.mark.parametrize("raw", [b"%33 A OK I AM A BANANA\r\n", b"4\r\n", b"@01 0 OK IDLE --\r\n",
                                 b"@01 0 OK IDLE -- \r\n", b"@01 0 OK WAIT -- 0\r\n", b"\xff@01\r\n", b"\r\n",
                                 b"@01 0 OK IDLE -- 0 \\\r\n"])
def test_malformed_replies_are_garbled(raw):
    with pytest.raises(GarbledReply):
        parse_reply(raw)


def test_check_reply_raises_typed_errors():
    with pytest.raises(StageRejected) as info:
        check_reply(parse_reply(b"@01 1 RJ IDLE -- BADDATA\r\n"), "move abs")
    assert info.value.code == "BADDATA" and isinstance(info.value, DeviceError)
    with pytest.raises(StageFault, match="stalled") as info:
        check_reply(parse_reply(b"@01 1 OK IDLE FS 0\r\n"), "get pos")
    assert info.value.code == "FS"
    assert check_reply(parse_reply(b"@01 1 OK IDLE FS 0\r\n"), "stop", faults=False).warning == "FS"
    with pytest.raises(GarbledReply):
        parse_int(parse_reply(b"@01 1 OK IDLE -- 1.5\r\n"))


# -- driver over a scripted port --------------------------------------------------------------------
def test_open_reads_the_travel_and_never_moves():
    stage, port = make([])
    assert port.done and stage.travel_m == pytest.approx((0.0, 1066667 * USTEP))
    assert stage.homed is False  # the last reply carried WR


def test_a_latched_fault_does_not_prevent_opening():
    port = ScriptedPort([(b"/1 1 get limit.min\n", b"@01 1 OK IDLE FS 0\r\n"),
                         (b"/1 1 get limit.max\n", b"@01 1 OK IDLE FS 1066667\r\n"),
                         (b"/1 1 warnings clear\n", b"@01 1 OK IDLE FS 01 FS\r\n")])
    stage = ZaberStage(SerialLink(port, name="stage", timeout=0.05), SETTINGS, retries=0)
    assert stage.last.fault and stage.clear_warnings() == ["FS"] and port.done


def test_soft_limits_outside_the_travel_are_refused_at_open():
    with pytest.raises(ValueError, match=r"max_m\].*travel"):
        make([], StageSettings(microstep_m=USTEP, min_m=0.0, max_m=0.06))


def test_home_then_move_byte_exact():
    stage, port = make([(b"/1 1 home\n", b"@01 1 OK BUSY WR 0\r\n"),
                        (b"/1 1 get pos\n", b"@01 1 OK BUSY WR 5000\r\n"),
                        (b"/1 1 get pos\n", b"@01 1 OK IDLE -- 0\r\n"),
                        (b"/1 1\n", b"@01 1 OK IDLE -- 0\r\n"),
                        (b"/1 1 move abs 209974\n", b"@01 1 OK BUSY -- 0\r\n"),
                        (b"/1 1 get pos\n", b"@01 1 OK BUSY -- 100000\r\n"),
                        (b"/1 1 get pos\n", b"@01 1 OK IDLE -- 209974\r\n"),
                        (b"/1 1 get pos\n", b"@01 1 OK IDLE -- 209974\r\n"),
                        (b"/1 1 get pos\n", b"@01 1 OK IDLE -- 209974\r\n")])
    stage.home()
    assert stage.homed
    stage.move_to(0.010)
    assert stage.position() == pytest.approx(0.010, abs=USTEP)
    assert port.done


def test_checksummed_commands_and_replies():
    cfg = StageSettings(microstep_m=USTEP, min_m=0.001, max_m=0.045, checksum=True)
    script = [(encode_command(1, 1, "get limit.min", with_checksum=True), b"@01 1 OK IDLE -- 0:8C\r\n"),
              (encode_command(1, 1, "get limit.max", with_checksum=True), b"@01 1 OK IDLE -- 1066667\r\n"),
              (b"/1 1 get pos:AC\n", b"@01 1 OK IDLE -- 42:" + checksum("01 1 OK IDLE -- 42").encode() + b"\r\n")]
    port = ScriptedPort(script)
    stage = ZaberStage(SerialLink(port, name="stage", timeout=0.05), cfg, retries=0)
    assert checksum("01 1 OK IDLE -- 0") == "8C"
    assert stage.position_microsteps() == 42 and port.done


def test_soft_limit_is_checked_before_anything_is_sent():
    stage, port = make([])
    for bad in (0.05, 0.0005, math.nan):
        with pytest.raises(ValueError, match="position_m"):
            stage.move_to(bad)
    assert port.done  # ScriptedPort would have failed on any write


def test_move_without_reference_is_refused():
    stage, port = make([(b"/1 1\n", b"@01 1 OK IDLE WR 0\r\n")])
    with pytest.raises(StageNotHomed, match="home"):
        stage.move_to(0.01)
    assert port.done


def test_rejected_move_and_fault_during_motion():
    stage, _ = make([(b"/1 1\n", b"@01 1 OK IDLE -- 0\r\n"),
                     (b"/1 1 move abs 209974\n", b"@01 1 RJ IDLE -- BADDATA\r\n")])
    with pytest.raises(StageRejected) as info:
        stage.move_to(0.010)
    assert info.value.code == "BADDATA"
    stage, _ = make([(b"/1 1\n", b"@01 1 OK IDLE -- 0\r\n"),
                     (b"/1 1 move abs 209974\n", b"@01 1 OK BUSY -- 0\r\n"),
                     (b"/1 1 get pos\n", b"@01 1 OK IDLE FS 1234\r\n")])
    with pytest.raises(StageFault) as info:
        stage.move_to(0.010)
    assert info.value.code == "FS"


def test_move_ending_short_of_its_target_is_a_device_error():
    stage, port = make([(b"/1 1\n", b"@01 1 OK IDLE -- 0\r\n"),
                        (b"/1 1 move abs 209974\n", b"@01 1 OK BUSY -- 0\r\n"),
                        (b"/1 1 get pos\n", b"@01 1 OK IDLE WL 100000\r\n"),
                        (b"/1 1 get pos\n", b"@01 1 OK IDLE WL 100000\r\n")])
    with pytest.raises(DeviceError, match="unexpected limit trigger") as info:
        stage.move_to(0.010)
    assert info.value.value == pytest.approx(100000 * USTEP) and port.done


def test_wait_timeout_sends_stop():
    stage, port = make([(b"/1 1 get pos\n", b"@01 1 OK BUSY -- 10\r\n"),
                        (b"/1 1 get pos\n", b"@01 1 OK BUSY -- 20\r\n"),
                        (b"/1 1 get pos\n", b"@01 1 OK BUSY -- 30\r\n"),
                        (b"/1 1 stop\n", b"@01 1 OK BUSY -- 0\r\n")])
    with pytest.raises(InstrumentTimeout, match="stop sent"):
        stage.wait_idle(0.1)
    assert port.done


def test_alert_in_place_of_the_reply_is_skipped_and_retried():
    stage, port = make([(b"/1 1 get pos\n", b"!01 1 IDLE --\r\n"),
                        (b"/1 1 get pos\n", b"@01 1 OK IDLE -- 42\r\n")], retries=1)
    assert stage.position_microsteps() == 42 and port.done and stage.n_retries == 1


def test_clear_warnings_returns_the_flags():
    stage, port = make([(b"/1 1 warnings clear\n", b"@01 1 OK IDLE FS 02 FS WR\r\n")])
    assert stage.clear_warnings() == ["FS", "WR"] and port.done


# -- units and stretch ----------------------------------------------------------------------------
def test_units_and_settings_validation():
    assert to_microsteps(0.010, USTEP) == 209974
    assert to_metres(209974, USTEP) == pytest.approx(0.010, abs=USTEP)
    with pytest.raises(ValueError, match="microstep_m"):
        to_microsteps(0.01, 0.0)
    with pytest.raises(ValueError, match="min_m must be < max_m"):
        StageSettings(microstep_m=USTEP, min_m=0.02, max_m=0.01)
    with pytest.raises(ValueError, match="microstep_m"):
        StageSettings(microstep_m=-1e-6, min_m=0.0, max_m=0.01)


def test_stretch_position_pair():
    assert stretch_from_position(0.013, gauge_length_m=0.010, x0_m=0.010) == pytest.approx(1.3)
    assert position_from_stretch(1.3, gauge_length_m=0.010, x0_m=0.010) == pytest.approx(0.013)
    assert position_from_stretch(1.3, gauge_length_m=0.010, x0_m=0.030, direction=-1) == pytest.approx(0.027)
    with pytest.raises(ValueError, match="gauge_length_m"):
        stretch_from_position(0.01, gauge_length_m=0.0, x0_m=0.0)
    with pytest.raises(ValueError, match="stretch"):
        position_from_stretch(-1.0, gauge_length_m=0.01, x0_m=0.0)


@settings(max_examples=200, deadline=None)
@given(st.floats(0.2, 5.0), st.floats(1e-3, 0.2), st.floats(-0.1, 0.1), st.sampled_from([1, -1]))
def test_stretch_round_trip(stretch, L0, x0, direction):
    x = position_from_stretch(stretch, gauge_length_m=L0, x0_m=x0, direction=direction)
    assert stretch_from_position(x, gauge_length_m=L0, x0_m=x0, direction=direction) == pytest.approx(stretch)


def test_stretch_stage_checks_reach_before_moving():
    stage, port = make([(b"/1 1 get pos\n", b"@01 1 OK IDLE -- 209974\r\n")])
    s = StretchStage(stage, gauge_length_m=0.02)
    with pytest.raises(RuntimeError, match="x0_m"):
        s.position_for(1.1)
    assert s.zero_here() == pytest.approx(0.010, abs=USTEP)
    s.check(1.5)  # 0.020 m: within the soft limits
    with pytest.raises(ValueError, match=r"stretch 2.8 .*position_m"):
        s.check(2.8)  # 0.046 m > max_m
    assert port.done


# -- property tests: any bytes -> a reply or a typed error, never a crash -------------------------------
VALID = [b"@01 1 OK IDLE -- 0\r\n", b"@01 1 RJ IDLE -- BADDATA\r\n", b"@01 0 OK IDLE -- 0:8D\r\n",
         b"!01 1 IDLE --\r\n", b"#01 0 hello\r\n"]


def _parse_all(raw: bytes) -> None:
    try:
        parse_int(check_reply(parse_reply(raw), "x"))
    except InstrumentError:
        pass


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=40))
def test_random_bytes_never_crash_the_parser(raw):
    _parse_all(raw)


@settings(max_examples=200, deadline=None)
@given(st.sampled_from(VALID), st.integers(min_value=0, max_value=30))
def test_truncated_replies_give_a_reply_or_a_typed_error(raw, cut):
    _parse_all(raw[:cut])


@settings(max_examples=200, deadline=None)
@given(st.integers(-2**31 + 1, 2**31 - 1), st.sampled_from(["IDLE", "BUSY"]), st.sampled_from(["--", "WR", "FS"]))
def test_reply_checksum_round_trip(pos, status, flag):
    body = f"01 1 OK {status} {flag} {pos}"
    r = parse_reply(f"@{body}:{checksum(body)}\r\n".encode())
    assert parse_int(r) == pos and r.status == status and r.warning == flag
