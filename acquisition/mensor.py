"""Mensor command set (CPG2500 indicators, CPC pressure controllers): pure encode/parse + a thin driver.

Protocol (Mensor operating instructions, "Mensor Command Set"): ASCII, case insensitive, commands end with
CR, LF or both (we send CR LF); ``keyword?`` is a query, ``keyword<SP>data`` a command. Every *query*
gets one reply that begins with a space, or with ``E`` when the device's error queue is not empty, and ends
with CR LF. Commands (no ``?``) are not promised a reply, so the driver never waits for one: it confirms a
setting by querying it back, and an error raised by a command shows as the ``E`` flag of that query.
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass
from typing import Any, Callable

from acquisition.driver_base import Reading, RetryingDriver, decode_reply_line
from acquisition.instrument_errors import DeviceError, GarbledReply, InstrumentError
from acquisition.serial_link import SerialLink

log = logging.getLogger(__name__)

LINE_ENDING = b"\r\n"

#: Mensor measurement-unit codes accepted by ``Units <code>`` -> (canonical name, Pa per unit).
#: 19 = mmHg (0 degC) is the code the rig uses. The driver never trusts a code blindly: after
#: ``Units <code>`` it reads ``Units?`` back and converts with the unit the device *reports*.
UNIT_CODES: dict[int, tuple[str, float]] = {
    1: ("psi", 6894.757293168361),
    13: ("atm", 101325.0),
    14: ("bar", 1.0e5),
    15: ("mbar", 100.0),
    19: ("mmHg", 133.322387415),
    21: ("Torr", 101325.0 / 760.0),
    22: ("kPa", 1.0e3),
    23: ("Pa", 1.0),
}
#: Units the driver can *read* (a device left in one of these still converts correctly); only the coded
#: ones above can be *set*. Water columns at 4 degC, mercury at 0 degC.
PA_PER_UNIT: dict[str, float] = {name: f for name, f in UNIT_CODES.values()} | {
    "hPa": 100.0, "MPa": 1.0e6, "mTorr": 101325.0 / 760.0e3, "inHg": 3386.389, "cmHg": 1333.22387415,
    "inH2O": 249.08891, "cmH2O": 98.0638, "mmH2O": 9.80638, "mH2O": 9806.38,
}
CODE_OF_UNIT: dict[str, int] = {name: code for code, (name, _) in UNIT_CODES.items()}
_UNIT_ALIASES = {name.lower(): name for name in PA_PER_UNIT} | {"mm hg": "mmHg", "mmhg0c": "mmHg",
                                                                 "torr": "Torr", "psig": "psi", "psia": "psi"}
MODES = ("standby", "measure", "control", "vent")
PTYPES = ("gauge", "absolute")


# ------------------------------------------------------------------------------------------------
# encoding
# ------------------------------------------------------------------------------------------------
def encode_query(keyword: str) -> bytes:
    """``encode_query("Units") -> b"Units?\\r\\n"``; ``encode_query("") -> b"?\\r\\n"`` (the reading)."""
    _check_keyword(keyword, allow_empty=True)
    return f"{keyword}?".encode("ascii") + LINE_ENDING


def encode_command(keyword: str, data: str | float | int) -> bytes:
    """``encode_command("Setpt", 120.0) -> b"Setpt 120\\r\\n"`` (numbers in shortest exact repr)."""
    _check_keyword(keyword)
    if isinstance(data, bool):
        raise TypeError(f"data for {keyword!r} must be a str or a number; got bool")
    if isinstance(data, (int, float)):
        if not math.isfinite(data):
            raise ValueError(f"data for {keyword!r} must be finite; got {data}")
        text = format(data, ".10g") if isinstance(data, float) else str(data)
    else:
        text = str(data)
        if not text or any(c in text for c in "\r\n?") or not text.isascii():
            raise ValueError(f"data for {keyword!r} must be non-empty printable ASCII without '?'; got {text!r}")
    return f"{keyword} {text}".encode("ascii") + LINE_ENDING


def _check_keyword(keyword: str, allow_empty: bool = False) -> None:
    if not isinstance(keyword, str) or (not keyword and not allow_empty) or not re.fullmatch(r"[A-Za-z_]*", keyword):
        raise ValueError(f"Mensor keyword must be letters/underscores; got {keyword!r}")


# ------------------------------------------------------------------------------------------------
# parsing
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class MensorReply:
    """A decoded reply line: ``error_flag`` (leading ``E``), ``text`` (after the flag, stripped), ``raw``."""

    error_flag: bool
    text: str
    raw: str

    @property
    def fields(self) -> list[str]:
        return [f.strip() for f in self.text.split(",")]


def parse_reply(raw: bytes) -> MensorReply:
    """Decode one reply line (with or without its CR LF).

    Raises
    ------
    GarbledReply
        Not ASCII, control characters inside, or a first character other than space or ``E``.
    """
    text = decode_reply_line(raw, "Mensor")
    flag = text[0]
    if flag not in (" ", "E", "e"):
        raise GarbledReply(f"Mensor reply must start with a space or 'E'; got {bytes(raw)!r}", raw=bytes(raw))
    return MensorReply(error_flag=flag in "Ee", text=text[1:].strip(), raw=text)


def _float(field: str, reply: MensorReply) -> float:
    try:
        value = float(field)
    except ValueError as exc:
        raise GarbledReply(f"expected a number in Mensor reply {reply.raw!r}", raw=reply.raw) from exc
    if not math.isfinite(value):
        raise GarbledReply(f"non-finite number in Mensor reply {reply.raw!r}", raw=reply.raw)
    return value


def parse_unit_name(text: str) -> str:
    """Canonical unit name from a ``Units?`` answer: a unit code (``"19"``) or a name (``"MMHG"``, ``"mmHg @0C"``).

    Raises
    ------
    GarbledReply
        Unknown unit.
    """
    t = text.strip()
    if re.fullmatch(r"\d{1,3}", t):
        code = int(t)
        if code in UNIT_CODES:
            return UNIT_CODES[code][0]
        raise GarbledReply(f"unknown Mensor unit code {code}; known {sorted(UNIT_CODES)}", raw=text)
    key = re.split(r"[@ ,]", t.lower().replace("°", ""), maxsplit=1)[0] if t else ""
    key = key.strip()
    if key in _UNIT_ALIASES:
        return _UNIT_ALIASES[key]
    if t.lower().replace(" ", "") in _UNIT_ALIASES:
        return _UNIT_ALIASES[t.lower().replace(" ", "")]
    raise GarbledReply(f"unknown Mensor unit {text!r}; known {sorted(PA_PER_UNIT)}", raw=text)


def parse_pressure(reply: MensorReply, unit: str | None) -> tuple[float, str]:
    """Pressure of a reading reply in Pa, and the unit it was expressed in.

    Output format 1 is ``" <value>"``; format 2 ``" <value>, <units>, <mode>"`` carries its unit, which then
    wins over ``unit`` (the unit last confirmed with ``Units?``).
    """
    fields = reply.fields
    value = _float(fields[0], reply)
    if len(fields) >= 2 and fields[1]:
        try:
            unit = parse_unit_name(fields[1])
        except GarbledReply:
            pass
    if unit is None or unit not in PA_PER_UNIT:
        raise GarbledReply(f"cannot convert Mensor reading {reply.raw!r}: unit {unit!r} unknown", raw=reply.raw)
    return value * PA_PER_UNIT[unit], unit


def parse_yes_no(reply: MensorReply) -> bool:
    """``" YES"`` -> True, ``" NO"`` -> False (also 1/0, ON/OFF, TRUE/FALSE)."""
    t = reply.fields[0].upper()
    if t in ("YES", "Y", "1", "ON", "TRUE", "STABLE"):
        return True
    if t in ("NO", "N", "0", "OFF", "FALSE", "SLEWING"):
        return False
    raise GarbledReply(f"expected YES or NO in Mensor reply {reply.raw!r}", raw=reply.raw)


def parse_choice(reply: MensorReply, choices: tuple[str, ...]) -> str:
    """A keyword answer (``Mode?``, ``Ptype?``) matched case-insensitively, by prefix, against ``choices``."""
    t = reply.fields[0].lower()
    for c in choices:
        if t and (t == c or c.startswith(t) or t.startswith(c)):
            return c
    raise GarbledReply(f"expected one of {choices} in Mensor reply {reply.raw!r}", raw=reply.raw)


def is_no_error(reply: MensorReply) -> bool:
    """True if an ``Error?`` answer says the queue is empty (``"NO ERROR"``, ``"0"``, empty)."""
    t = reply.text.strip().upper()
    return t in ("", "0", "NONE") or "NO ERR" in t or t.startswith("0,")


# ------------------------------------------------------------------------------------------------
# driver
# ------------------------------------------------------------------------------------------------
class MensorPressure(RetryingDriver):
    """Mensor CPG2500 indicator or CPC controller on a serial port.

    Parameters
    ----------
    link : SerialLink
        The opened transport.
    retries : int
        Retries of a timed-out or garbled query.
    max_error_reads : int
        At most this many ``Error?`` queries to drain the queue (the device holds the last 10).

    Notes
    -----
    Opening reads ``ID?``, ``Units?`` and ``Ptype?`` and never changes a setting. Readings are converted
    to Pa with the unit the device reports; after a reconnect ``Units?`` is read again.
    """

    def __init__(self, link: SerialLink, *, retries: int = 2, max_error_reads: int = 10) -> None:
        super().__init__(link, retries=retries)
        self.max_error_reads = max_error_reads
        self.identity = ""
        self.unit: str | None = None
        self.ptype: str | None = None
        self.is_controller = False
        self._refresh()

    def _refresh(self) -> None:
        """Re-read identity, unit and pressure type (at open and after a reconnect)."""
        self.identity = self._checked(encode_query("ID")).text
        self.unit = parse_unit_name(self._checked(encode_query("Units")).text)
        try:
            self.ptype = parse_choice(self._checked(encode_query("Ptype")), PTYPES)
        except DeviceError:  # not every model knows Ptype
            self.ptype = None
        self.is_controller = "CPC" in self.identity.upper()
        log.info("%s: %s, unit %s, %s", self.name, self.identity, self.unit, self.ptype)

    # -- low level -----------------------------------------------------------------------------
    def _checked(self, command: bytes) -> MensorReply:
        """Query; on an ``E`` flag drain the error queue and raise :class:`DeviceError` with its entries."""
        with self.link.lock:
            self._ensure()
            reply = self._query(command, parse_reply)
            if reply.error_flag:
                messages = self.errors()
                value = None
                try:
                    value = _float(reply.fields[0], reply) * PA_PER_UNIT.get(self.unit or "", math.nan)
                except GarbledReply:
                    pass
                raise DeviceError(f"{self.name}: device error flag on {command.strip()!r}: "
                                  f"{'; '.join(messages) or 'queue empty'}", raw=reply.raw,
                                  messages=messages, value=value)
            return reply

    def query_text(self, keyword: str) -> str:
        """The text of the answer to ``keyword?`` (device errors raised)."""
        return self._checked(encode_query(keyword)).text

    def errors(self) -> list[str]:
        """Drain the device error queue with ``Error?``; returns the entries, oldest first."""
        out: list[str] = []
        with self.link.lock:
            for _ in range(self.max_error_reads):
                reply = self._query(encode_query("Error"), parse_reply)
                if is_no_error(reply):
                    break
                out.append(reply.text)
                if not reply.error_flag:
                    break
        for m in out:
            log.warning("%s: device error: %s", self.name, m)
        return out

    def _send(self, keyword: str, data: str | float | int) -> None:
        self.link.send(encode_command(keyword, data))

    # -- readings ------------------------------------------------------------------------------
    def read(self) -> Reading:
        """One pressure reading (``?``), in Pa."""
        reply = self._checked(encode_query(""))
        value, unit = parse_pressure(reply, self.unit)
        return Reading(value=value, raw=reply.raw, unit=unit)

    # -- settings (always confirmed by a query) ------------------------------------------------
    def set_unit(self, unit: str) -> None:
        """Select the device unit (``Units <code>``) and confirm with ``Units?``."""
        if unit not in CODE_OF_UNIT:
            raise ValueError(f"unit must be one of {sorted(CODE_OF_UNIT)}; got {unit!r}")
        with self.link.lock:
            self._send("Units", CODE_OF_UNIT[unit])
            got = parse_unit_name(self._checked(encode_query("Units")).text)
            self.unit = got
            if got != unit:
                raise DeviceError(f"{self.name}: asked for unit {unit!r} (code {CODE_OF_UNIT[unit]}), "
                                  f"device reports {got!r}")

    def set_ptype(self, ptype: str) -> None:
        """``Ptype GAUGE|ABSOLUTE``, confirmed with ``Ptype?``."""
        if ptype not in PTYPES:
            raise ValueError(f"ptype must be one of {PTYPES}; got {ptype!r}")
        with self.link.lock:
            self._send("Ptype", ptype.upper())
            got = parse_choice(self._checked(encode_query("Ptype")), PTYPES)
            self.ptype = got
            if got != ptype:
                raise DeviceError(f"{self.name}: asked for Ptype {ptype!r}, device reports {got!r}")

    def mode(self) -> str:
        """Controller mode (``Mode?``): one of ``standby, measure, control, vent``."""
        return parse_choice(self._checked(encode_query("Mode")), MODES)

    def set_mode(self, mode: str) -> None:
        """``Mode STANDBY|MEASURE|CONTROL|VENT``, confirmed with ``Mode?`` (controllers only)."""
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}; got {mode!r}")
        with self.link.lock:
            self._send("Mode", mode.upper())
            got = self.mode()
            if got != mode:
                raise DeviceError(f"{self.name}: asked for mode {mode!r}, device reports {got!r}")

    def setpoint(self) -> float:
        """Control set-point (``Setpt?``) in Pa."""
        reply = self._checked(encode_query("Setpt"))
        return parse_pressure(MensorReply(reply.error_flag, reply.fields[0], reply.raw), self.unit)[0]

    def set_setpoint(self, pa: float) -> None:
        """``Setpt <value in device unit>``, confirmed with ``Setpt?`` (to 1e-6 relative or 1e-3 unit)."""
        if not math.isfinite(pa):
            raise ValueError(f"set-point must be a finite pressure in Pa; got {pa}")
        with self.link.lock:
            if self.unit is None:
                raise InstrumentError(f"{self.name}: unit unknown; cannot send a set-point")
            value = pa / PA_PER_UNIT[self.unit]
            self._send("Setpt", round(value, 6))
            got = self.setpoint()
            tol = max(1e-6 * abs(pa), 1e-3 * PA_PER_UNIT[self.unit])
            if abs(got - pa) > tol:
                raise DeviceError(f"{self.name}: asked for set-point {pa:.6g} Pa, device reports {got:.6g} Pa")

    def device_stable(self) -> bool:
        """The controller's own stability flag (``Stable?``)."""
        return parse_yes_no(self._checked(encode_query("Stable")))

    def settings(self) -> dict[str, Any]:
        """JSON-able description for the session file."""
        return {"model": "Mensor", "identity": self.identity, "unit": self.unit, "ptype": self.ptype,
                "is_controller": self.is_controller, "device": self.link.device,
                "timeout_s": self.link.timeout, "retries": self.retries}


def open_mensor(spec: Any, *, baudrate: int = 9600, timeout: float = 0.25, retries: int = 2,
                list_ports: Callable[[], list] | None = None, reconnect_interval: float = 0.5) -> MensorPressure:
    """Open a Mensor indicator/controller from a port spec (see :mod:`acquisition.serial_link`)."""
    link = SerialLink(spec, name="pressure (Mensor)", baudrate=baudrate, timeout=timeout,
                      list_ports=list_ports, reconnect_interval=reconnect_interval)
    try:
        return MensorPressure(link, retries=retries)
    except BaseException:
        link.close()
        raise
