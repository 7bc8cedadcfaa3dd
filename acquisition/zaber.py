"""Zaber ASCII protocol (linear stages, firmware 6/7): pure encode/parse + a thin motorised-stage driver.

Protocol (Zaber "ASCII Protocol Manual"): a command is ``/<device> [<axis> [<id>]] <command>[:CC]`` ended by
CR, LF or both (we send LF); a reply is ``@<device 2 digits> <axis> [<id>] <OK|RJ> <IDLE|BUSY> <flag> <data>``
ended by CR LF, e.g. ``@01 1 OK IDLE -- 0``. ``RJ`` replies carry the reason as data (``BADDATA``,
``BADCOMMAND``, ...). The two-character warning flag is the highest-priority active condition: ``--`` none,
``F?`` faults (``FS`` stalled and stopped, ``FD`` driver disabled, ...), ``W?`` warnings (``WR`` no reference
position: not homed, ``WL`` unexpected limit trigger, ...), ``N?`` notices. Info (``#``) and alert (``!``)
messages are recognised and skipped by the driver. The optional checksum ``:CC`` is the two's complement of
the byte sum of everything between the leading ``/``, ``@``, ``#`` or ``!`` and the colon, as two uppercase
hex digits (``/1 tools echo:BF``, ``@01 0 OK IDLE -- 0:8D``).

Positions on the wire are integers in microsteps; the driver converts with ``microstep_m`` (the size of one
microstep in m, from the stage's data sheet) so that everything it takes and returns is in metres.
"""

from __future__ import annotations

import logging
import math
import re
import time
from dataclasses import dataclass
from typing import Any, Callable

from acquisition.driver_base import RetryingDriver, decode_reply_line
from acquisition.instrument_errors import DeviceError, GarbledReply, InstrumentError, InstrumentTimeout
from acquisition.serial_link import SerialLink

log = logging.getLogger(__name__)

LINE_ENDING = b"\n"
#: ASCII default baud rate of Zaber devices (binary-protocol devices use 9600)
DEFAULT_BAUDRATE = 115200
#: the device's position register is a signed 32-bit integer
MAX_MICROSTEPS = 2**31 - 1
#: rejection reasons of ``RJ`` replies
REJECTION_REASONS = ("AGAIN", "BADAXIS", "BADCOMMAND", "BADDATA", "BADMESSAGEID", "DEVICEONLY", "FULL",
                     "LOCKSTEP", "NOACCESS", "PARKED", "STATUSBUSY")
#: warning flags the driver explains in its messages (all others are passed on by their code)
FLAG_MEANINGS = {
    "--": "no warning", "FD": "driver disabled (overheating)", "FQ": "encoder error", "FS": "stalled and stopped",
    "FT": "excessive twist", "FE": "limit error", "FB": "stream bounds error", "FP": "path deviation",
    "FF": "critical system error", "WH": "not homed (calibration disabled)", "WL": "unexpected limit trigger",
    "WV": "supply voltage out of range", "WT": "controller temperature high", "WM": "displaced when stationary",
    "WR": "no reference position (home the axis)", "NC": "manual control", "NI": "command interrupted",
    "NU": "setting update pending",
}
_COMMAND = re.compile(r"[a-z0-9][a-z0-9 ._+-]*")
_REPLY = re.compile(r"@(\d{1,2}) (\d+) (?:(\d{1,2}|--) )?(OK|RJ) (IDLE|BUSY) (\S\S) (.*\S.*)")
_INFO = re.compile(r"#(\d{1,2}) (\d+) ?(.*)")
_ALERT = re.compile(r"!(\d{1,2}) (\d+) (IDLE|BUSY) (\S\S)(?: (.*))?")
_CHECKSUM = re.compile(r":([^:\s]{2})$")


class StageRejected(DeviceError):
    """The stage rejected a command (``RJ``); ``code`` is the reason, e.g. ``"BADDATA"``."""


class StageFault(DeviceError):
    """The stage reports a fault flag (``F?``, e.g. ``FS`` stalled); ``code`` is the flag. Motion has stopped;
    :meth:`ZaberStage.clear_warnings` acknowledges it."""


class StageTravelError(DeviceError, ValueError):
    """The soft limits do not lie within the travel the device reports (at open, or after a reconnect to a
    reconfigured or different device)."""


class StageNotHomed(DeviceError):
    """A move was asked for while the axis has no reference position (flag ``WR``): home it first."""


# ------------------------------------------------------------------------------------------------
# encoding
# ------------------------------------------------------------------------------------------------
def checksum(body: str | bytes) -> str:
    """Zaber message checksum of ``body`` (the text between the type character and the colon).

    ``checksum("1 tools echo") -> "BF"``: the byte sum's two's complement, low 8 bits, two uppercase hex digits.
    """
    data = body.encode("ascii") if isinstance(body, str) else bytes(body)
    return format((-sum(data)) & 0xFF, "02X")


def encode_command(device: int, axis: int | None, command: str = "", *, message_id: int | None = None,
                   with_checksum: bool = False) -> bytes:
    """One command line: ``encode_command(1, 1, "move abs 1000") -> b"/1 1 move abs 1000\\n"``.

    Parameters
    ----------
    device : int
        Device address 0..99 (0 = all devices).
    axis : int or None
        Axis 0..9 (0 = the whole device); None omits it (device scope, no message id possible).
    command : str
        Lower-case words and numbers (``"home"``, ``"get pos"``, ``"move abs 1000"``); ``""`` asks for status.
    message_id : int, optional
        0..99, echoed by the reply.
    with_checksum : bool
        Append ``:CC``.
    """
    if isinstance(device, bool) or not isinstance(device, int) or not 0 <= device <= 99:
        raise ValueError(f"device must be an int in 0..99; got {device!r}")
    if axis is not None and (isinstance(axis, bool) or not isinstance(axis, int) or not 0 <= axis <= 9):
        raise ValueError(f"axis must be an int in 0..9 or None; got {axis!r}")
    if message_id is not None:
        if isinstance(message_id, bool) or not isinstance(message_id, int) or not 0 <= message_id <= 99:
            raise ValueError(f"message_id must be an int in 0..99 or None; got {message_id!r}")
        if axis is None:
            raise ValueError("message_id needs an axis (use axis=0 for the whole device)")
    if not isinstance(command, str) or (command and not _COMMAND.fullmatch(command)):
        raise ValueError(f"command must be lower-case ASCII words/numbers; got {command!r}")
    parts = [str(device)] + ([str(axis)] if axis is not None else []) \
        + ([str(message_id)] if message_id is not None else []) + ([command] if command else [])
    body = " ".join(parts)
    if with_checksum:
        body += ":" + checksum(body)
    return b"/" + body.encode("ascii") + LINE_ENDING


def move_abs_command(microsteps: int) -> str:
    """``move_abs_command(1000) -> "move abs 1000"`` (a signed 32-bit integer)."""
    if isinstance(microsteps, bool) or not isinstance(microsteps, int) or abs(microsteps) > MAX_MICROSTEPS:
        raise ValueError(f"microsteps must be an int within +-{MAX_MICROSTEPS}; got {microsteps!r}")
    return f"move abs {microsteps}"


# ------------------------------------------------------------------------------------------------
# parsing
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ZaberReply:
    """A decoded message from a device.

    Attributes
    ----------
    kind : {"@", "#", "!"}
        Reply, info or alert.
    device, axis : int
    message_id : int or None
    flag : {"OK", "RJ"} or None (info, alert)
    status : {"IDLE", "BUSY"} or None (info)
    warning : str or None
        Two-character warning flag, ``"--"`` when none; None for info messages.
    data : str
        The data field (``"0"``, a position, an ``RJ`` reason, info text).
    raw : str
        The line as received without CR LF.
    """

    kind: str
    device: int
    axis: int
    message_id: int | None
    flag: str | None
    status: str | None
    warning: str | None
    data: str
    raw: str

    @property
    def rejected(self) -> bool:
        return self.flag == "RJ"

    @property
    def busy(self) -> bool:
        return self.status == "BUSY"

    @property
    def fault(self) -> bool:
        """A fault flag (``F?``) is active."""
        return self.warning is not None and self.warning.startswith("F")

    @property
    def needs_homing(self) -> bool:
        """No reference position (``WR``)."""
        return self.warning == "WR"


def parse_reply(raw: bytes) -> ZaberReply:
    """Decode one message line (with or without CR LF); a trailing ``:CC`` checksum is verified and removed.

    Raises
    ------
    GarbledReply
        Not ASCII, control characters, wrong checksum, or not a reply/info/alert message.
    """
    text = decode_reply_line(raw, "Zaber")
    line = text
    m = _CHECKSUM.search(line)
    if m and line[:1] in "@#!":
        body = line[1:m.start()]
        if checksum(body) != m.group(1).upper():
            raise GarbledReply(f"Zaber reply checksum {m.group(1)} != {checksum(body)} computed: {text!r}",
                               raw=text)
        line = line[:m.start()]
    if line.endswith("\\"):
        raise GarbledReply(f"Zaber multi-packet replies (trailing '\\') are not supported: {text!r}", raw=text)
    if m := _REPLY.fullmatch(line):
        mid = None if m.group(3) in (None, "--") else int(m.group(3))
        return ZaberReply("@", int(m.group(1)), int(m.group(2)), mid, m.group(4), m.group(5), m.group(6),
                          m.group(7), text)
    if m := _ALERT.fullmatch(line):
        return ZaberReply("!", int(m.group(1)), int(m.group(2)), None, None, m.group(3), m.group(4),
                          m.group(5) or "", text)
    if m := _INFO.fullmatch(line):
        return ZaberReply("#", int(m.group(1)), int(m.group(2)), None, None, None, None, m.group(3), text)
    raise GarbledReply(f"not a Zaber reply (expected '@NN A OK|RJ IDLE|BUSY FF data'): {text!r}", raw=text)


def parse_int(reply: ZaberReply) -> int:
    """The data field as one integer (``get pos``, ``get limit.max``)."""
    try:
        return int(reply.data.strip())
    except ValueError as exc:
        raise GarbledReply(f"expected one integer in Zaber reply {reply.raw!r}", raw=reply.raw) from exc


def describe_flag(flag: str | None) -> str:
    """``describe_flag("FS") -> "FS (stalled and stopped)"``."""
    return f"{flag} ({FLAG_MEANINGS.get(flag or '', 'see the Zaber protocol manual')})"


def check_reply(reply: ZaberReply, what: str, *, faults: bool = True) -> ZaberReply:
    """Raise :class:`StageRejected` for ``RJ`` and, if ``faults``, :class:`StageFault` for an ``F?`` flag."""
    if reply.rejected:
        raise StageRejected(f"{what} rejected: {reply.data}", raw=reply.raw, code=reply.data.strip())
    if faults and reply.fault:
        raise StageFault(f"{what}: stage fault {describe_flag(reply.warning)}", raw=reply.raw, code=reply.warning)
    return reply


# ------------------------------------------------------------------------------------------------
# units
# ------------------------------------------------------------------------------------------------
def to_microsteps(position_m: float, microstep_m: float) -> int:
    """Metres -> nearest microstep."""
    _check_positive("microstep_m", microstep_m)
    if not math.isfinite(position_m):
        raise ValueError(f"position_m must be finite; got {position_m}")
    return int(round(position_m / microstep_m))


def to_metres(microsteps: int, microstep_m: float) -> float:
    """Microsteps -> metres."""
    _check_positive("microstep_m", microstep_m)
    return float(microsteps) * microstep_m


def _check_positive(name: str, value: float) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a finite number > 0; got {value!r}")


@dataclass(frozen=True)
class StageSettings:
    """How the stage is addressed and where it may go (SI).

    Attributes
    ----------
    microstep_m : float
        Size of one microstep, m (data sheet: e.g. 0.047625 um for many lead-screw stages).
    min_m, max_m : float
        Soft limits of the carriage position, m; every move is checked against them before it is sent.
    device, axis : int
        Device address and axis number.
    tolerance_m : float
        A finished move must end within this of its target (default: one microstep).
    checksum : bool
        Send commands with a checksum.
    """

    microstep_m: float
    min_m: float
    max_m: float
    device: int = 1
    axis: int = 1
    tolerance_m: float | None = None
    checksum: bool = False

    def __post_init__(self) -> None:
        _check_positive("microstep_m", self.microstep_m)
        for name in ("min_m", "max_m"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"{name} must be a finite position in m; got {v!r}")
        if not self.min_m < self.max_m:
            raise ValueError(f"min_m must be < max_m; got min_m={self.min_m} m, max_m={self.max_m} m")
        if self.tolerance_m is not None:
            _check_positive("tolerance_m", self.tolerance_m)
        encode_command(self.device, self.axis)  # validates device and axis

    @property
    def tolerance(self) -> float:
        return self.tolerance_m if self.tolerance_m is not None else self.microstep_m

    def check_position(self, position_m: float) -> None:
        """Raise ValueError (naming ``position_m`` and the limits) if the position is outside the soft limits."""
        if isinstance(position_m, bool) or not isinstance(position_m, (int, float)) or not math.isfinite(position_m):
            raise ValueError(f"position_m must be a finite position in m; got {position_m!r}")
        if not self.min_m <= position_m <= self.max_m:
            raise ValueError(f"position_m must be within the soft limits [min_m, max_m] = [{self.min_m:.6g}, "
                             f"{self.max_m:.6g}] m; got {position_m:.6g} m")


# ------------------------------------------------------------------------------------------------
# driver
# ------------------------------------------------------------------------------------------------
class ZaberStage(RetryingDriver):
    """One axis of a Zaber motorised stage on a serial port, in metres.

    Parameters
    ----------
    link : SerialLink
        The opened transport (CR LF terminated replies).
    settings : StageSettings
    retries : int
        Retries of a timed-out or garbled exchange (all commands used are safe to repeat).
    poll_s : float
        Polling period of :meth:`wait_idle`, s.
    clock, sleep : callable
        Time source and sleep of :meth:`wait_idle` (injectable for tests).

    Notes
    -----
    Opening reads the axis' travel (``get limit.min``, ``get limit.max``) and refuses soft limits outside it;
    it never moves the stage. After a reconnect the travel and the homing state are read again.
    """

    MAX_SKIPPED = 8  # info/alert lines skipped while waiting for a reply

    def __init__(self, link: SerialLink, settings: StageSettings, *, retries: int = 2, poll_s: float = 0.05,
                 clock: Callable[[], float] = time.monotonic, sleep: Callable[[float], None] = time.sleep) -> None:
        super().__init__(link, retries=retries)
        self.config = settings
        self.poll_s = float(poll_s)
        self.clock, self.sleep = clock, sleep
        self.travel_m: tuple[float, float] = (math.nan, math.nan)
        self.last: ZaberReply | None = None
        self._refresh()

    # -- low level -----------------------------------------------------------------------------
    def _refresh(self) -> None:
        s = self.config
        # faults=False: a stage with a latched fault must still open, so that clear_warnings() can be called
        lo = to_metres(parse_int(self.request("get limit.min", faults=False)), s.microstep_m)
        hi = to_metres(parse_int(self.request("get limit.max", faults=False)), s.microstep_m)
        self.travel_m = (lo, hi)
        half = 0.5 * s.microstep_m
        if s.min_m < lo - half or s.max_m > hi + half:
            raise StageTravelError(f"{self.name}: soft limits [min_m, max_m] = [{s.min_m:.6g}, {s.max_m:.6g}] m "
                                   f"must lie within the stage travel [{lo:.6g}, {hi:.6g}] m "
                                   f"(limit.min/limit.max x microstep_m)", code="travel")
        log.info("%s: travel %.6g..%.6g m, soft limits %.6g..%.6g m, %s", self.name, lo, hi, s.min_m, s.max_m,
                 describe_flag(self.last.warning if self.last else None))

    def _parse_for(self, raw: bytes) -> ZaberReply:
        """Parse the reply to our command, skipping info/alert lines and replies of other devices/axes."""
        s = self.config
        for _ in range(self.MAX_SKIPPED):
            reply = parse_reply(raw)
            if reply.kind == "@" and reply.device == s.device and reply.axis == s.axis:
                return reply
            log.debug("%s: skipping %r", self.name, reply.raw)
            raw = self.link.read_line()
        raise GarbledReply(f"{self.name}: no reply from device {s.device} axis {s.axis} among "
                           f"{self.MAX_SKIPPED} messages", raw=reply.raw)

    def request(self, command: str, *, faults: bool = True) -> ZaberReply:
        """Send ``command`` to the axis and return its checked reply (``RJ`` and fault flags raised)."""
        s = self.config
        line = encode_command(s.device, s.axis, command, with_checksum=s.checksum)
        with self.link.lock:
            self._ensure()
            reply = self._query(line, self._parse_for)
        self.last = reply
        return check_reply(reply, f"{self.name}: {command or 'status'!r}", faults=faults)

    # -- state ---------------------------------------------------------------------------------
    def position_microsteps(self) -> int:
        """Current position in microsteps (``get pos``)."""
        return parse_int(self.request("get pos"))

    def position(self) -> float:
        """Current carriage position, m."""
        return to_metres(self.position_microsteps(), self.config.microstep_m)

    def is_busy(self) -> bool:
        """True while the axis moves (faults raised)."""
        return self.request("").busy

    @property
    def homed(self) -> bool | None:
        """False if the last reply said ``WR`` (no reference position), None before any reply."""
        return None if self.last is None else not self.last.needs_homing

    # -- motion --------------------------------------------------------------------------------
    def home(self, *, wait: bool = True, timeout: float = 60.0) -> None:
        """Home the axis (it moves to its home sensor and sets its reference position)."""
        self.request("home")
        if wait:
            self.wait_idle(timeout)
            if self.last is not None and self.last.needs_homing:
                raise StageNotHomed(f"{self.name}: still no reference position after homing", raw=self.last.raw,
                                    code="WR")

    def move_to(self, position_m: float, *, wait: bool = True, timeout: float = 60.0) -> None:
        """Move the carriage to ``position_m`` (m), checked against the soft limits first.

        Raises
        ------
        ValueError
            ``position_m`` outside ``[min_m, max_m]`` (nothing is sent).
        StageNotHomed
            The axis has no reference position (nothing is sent).
        StageRejected, StageFault, InstrumentTimeout, DeviceError
            The device refused, faulted, did not finish within ``timeout`` s (a stop is sent), or stopped away
            from the target.
        """
        s = self.config
        s.check_position(position_m)
        target = to_microsteps(position_m, s.microstep_m)
        status = self.request("")
        if status.needs_homing:
            raise StageNotHomed(f"{self.name}: axis not homed (flag WR): call home() before move_to("
                                f"{position_m:.6g} m)", raw=status.raw, code="WR")
        self.request(move_abs_command(target))
        if not wait:
            return
        self.wait_idle(timeout)
        got = self.position()
        if abs(got - position_m) > s.tolerance + 0.5 * s.microstep_m:
            last = self.last
            raise DeviceError(f"{self.name}: stopped at {got:.6g} m, target {position_m:.6g} m (tolerance "
                              f"{s.tolerance:.3g} m; {describe_flag(last.warning if last else None)})",
                              raw=last.raw if last else None, value=got)

    def wait_idle(self, timeout: float = 60.0) -> float:
        """Poll until the axis is idle; returns the position (m).

        Raises
        ------
        StageFault
            A fault flag appeared (the device has stopped itself).
        InstrumentTimeout
            Still moving after ``timeout`` s; a ``stop`` is sent first.
        """
        if not timeout > 0:
            raise ValueError(f"timeout must be > 0 s; got {timeout}")
        deadline = self.clock() + timeout
        while True:
            reply = self.request("get pos")
            if not reply.busy:
                return to_metres(parse_int(reply), self.config.microstep_m)
            if self.clock() >= deadline:
                try:
                    self.stop()
                except InstrumentError as exc:  # the timeout is the news; the failed stop is logged
                    log.error("%s: stop after the wait timeout failed: %s", self.name, exc)
                raise InstrumentTimeout(f"{self.name}: still moving after {timeout:g} s (at "
                                        f"{to_metres(parse_int(reply), self.config.microstep_m):.6g} m); stop sent",
                                        raw=reply.raw)
            self.sleep(self.poll_s)

    def stop(self) -> None:
        """Decelerate to a stop (never refused for a fault flag)."""
        self.request("stop", faults=False)

    def clear_warnings(self) -> list[str]:
        """Acknowledge and clear latched warnings/faults (``warnings clear``); returns the flags that were set."""
        reply = self.request("warnings clear", faults=False)
        fields = reply.data.split()
        return fields[1:] if fields and fields[0].isdigit() else []

    def settings(self) -> dict[str, Any]:
        """JSON-able description for the session file (SI)."""
        s = self.config
        return {"model": "Zaber (ASCII)", "device": s.device, "axis": s.axis, "microstep_m": s.microstep_m,
                "min_m": s.min_m, "max_m": s.max_m, "travel_m": list(self.travel_m), "port": self.link.device,
                "timeout_s": self.link.timeout, "retries": self.retries, "checksum": s.checksum}


def open_zaber(spec: Any, settings: StageSettings, *, baudrate: int = DEFAULT_BAUDRATE, timeout: float = 0.25,
               retries: int = 2, list_ports: Callable[[], list] | None = None, reconnect_interval: float = 0.5,
               poll_s: float = 0.05, clock: Callable[[], float] = time.monotonic,
               sleep: Callable[[float], None] = time.sleep) -> ZaberStage:
    """Open a Zaber stage from a port spec (see :mod:`acquisition.serial_link`); never moves it."""
    link = SerialLink(spec, name="stage (Zaber)", baudrate=baudrate, timeout=timeout, line_ending=LINE_ENDING,
                      list_ports=list_ports, reconnect_interval=reconnect_interval)
    try:
        return ZaberStage(link, settings, retries=retries, poll_s=poll_s, clock=clock, sleep=sleep)
    except BaseException:
        link.close()
        raise
