"""Mark-10 Gauge Control Language (Series 5 gauges, 7i indicators): pure encode/parse + a thin driver.

Protocol (Mark-10 Series 5 user's guide, "Command Set / GCL2"): commands end with CR or CR LF (we send
CR LF); replies always end with CR LF. ``?`` returns the displayed reading, e.g. ``4.285 N`` (compression
positive, tension negative, unless the gauge's polarity setting inverts it). Units ``LB OZ KG G N MN KN``;
modes ``CUR PT PC``; ``Z`` zero/tare; filters ``FLTCn`` (displayed) and ``FLTPn`` (current), n = 0..10;
``RN RM RV RS`` product name, model, firmware version, serial number; ``LIST`` the configuration as
``;``-separated fields (e.g. ``V1.00;LBF;CUR;FLTC8;FLTP1;AOUT00;AOFF5;FULL;MIT;POL;B0``). Errors come back
as ``*10`` illegal command, ``*11`` not applicable, ``*12`` invalid specifier, ``*22`` value too large.

The guide does not say whether set commands are acknowledged, so after a set the driver only collects
whatever lines arrive in a short window (an error code there is raised; anything else is logged) and then
confirms the setting by reading ``LIST`` back.
"""

from __future__ import annotations

import logging
import math
import re
from typing import Any, Callable

from acquisition.driver_base import Reading, RetryingDriver, decode_reply_line
from acquisition.instrument_errors import DeviceError, GarbledReply
from acquisition.serial_link import SerialLink

log = logging.getLogger(__name__)

LINE_ENDING = b"\r\n"

#: reply unit token -> (set command, LIST token, N per unit)
UNITS: dict[str, tuple[str, str, float]] = {
    "N": ("N", "N", 1.0),
    "mN": ("MN", "MN", 1.0e-3),
    "kN": ("KN", "KN", 1.0e3),
    "lbF": ("LB", "LBF", 4.4482216152605),
    "ozF": ("OZ", "OZF", 0.27801385095378125),
    "kgF": ("KG", "KGF", 9.80665),
    "gF": ("G", "GF", 9.80665e-3),
}
_UNIT_BY_LOWER = {u.lower(): u for u in UNITS}
_UNIT_BY_LIST = {v[1]: u for u, v in UNITS.items()}
MODES = {"CUR": "current", "PT": "peak tension", "PC": "peak compression"}
ERROR_CODES = {"*10": "illegal command", "*11": "not applicable", "*12": "invalid specifier",
               "*22": "value too large"}
_NUMBER = r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"
_READING = re.compile(rf"^\s*({_NUMBER})\s*([A-Za-z]+)?\s*$")


# ------------------------------------------------------------------------------------------------
# encoding
# ------------------------------------------------------------------------------------------------
def encode(command: str) -> bytes:
    """``encode("?") -> b"?\\r\\n"``; ``encode("FLTC4") -> b"FLTC4\\r\\n"`` (uppercase letters, digits, ``?``)."""
    if not isinstance(command, str) or not re.fullmatch(r"\?|[A-Z?][A-Z0-9?\-.]*", command):
        raise ValueError(f"Mark-10 command must be uppercase letters/digits or '?'; got {command!r}")
    return command.encode("ascii") + LINE_ENDING


def unit_command(unit: str) -> str:
    """Set command for a unit: ``unit_command("lbF") -> "LB"``."""
    if unit not in UNITS:
        raise ValueError(f"unit must be one of {sorted(UNITS)}; got {unit!r}")
    return UNITS[unit][0]


def filter_command(which: str, n: int) -> str:
    """``filter_command("current", 4) -> "FLTP4"``; ``"displayed" -> "FLTCn"``; n in 0..10 (2**n samples)."""
    if which not in ("current", "displayed"):
        raise ValueError(f"filter must be 'current' or 'displayed'; got {which!r}")
    if not isinstance(n, int) or not 0 <= n <= 10:
        raise ValueError(f"filter n must be an int in 0..10; got {n!r}")
    return f"FLT{'P' if which == 'current' else 'C'}{n}"


# ------------------------------------------------------------------------------------------------
# parsing
# ------------------------------------------------------------------------------------------------
def decode_line(raw: bytes) -> str:
    """ASCII text of a reply line without CR LF; raises :class:`DeviceError` for ``*NN`` error replies.

    Raises
    ------
    GarbledReply
        Not ASCII, control characters, or empty.
    DeviceError
        The reply is an error code (``.code`` = ``"*10"`` etc.).
    """
    text = decode_reply_line(raw, "Mark-10")
    if not text.strip():
        raise GarbledReply(f"Mark-10 reply is blank: {bytes(raw)!r}", raw=bytes(raw))
    t = text.strip()
    if re.fullmatch(r"\*\d\d", t):
        raise DeviceError(f"Mark-10 error {t}: {ERROR_CODES.get(t, 'unknown error code')}", raw=text, code=t)
    return text


def parse_force(raw: bytes, default_unit: str | None = None) -> tuple[float, str, str]:
    """Parse a reading reply such as ``b"-4.285 N\\r\\n"``.

    Returns
    -------
    value_device : float
        The number as printed (device sign convention: compression positive).
    unit : str
        Unit token (``"N"``, ``"lbF"`` ...); ``default_unit`` if the gauge omits units.
    text : str
        The decoded reply.
    """
    text = decode_line(raw)
    m = _READING.match(text)
    if not m:
        raise GarbledReply(f"expected '<number> <unit>' in Mark-10 reply {text!r}", raw=text)
    value = float(m.group(1))
    if not math.isfinite(value):
        raise GarbledReply(f"non-finite Mark-10 reading {text!r}", raw=text)
    token = m.group(2)
    if token is None:
        if default_unit is None:
            raise GarbledReply(f"Mark-10 reading {text!r} has no unit and none is configured", raw=text)
        unit = default_unit
    else:
        unit = _UNIT_BY_LOWER.get(token.lower())
        if unit is None:
            raise GarbledReply(f"unknown Mark-10 unit {token!r} in {text!r}; known {sorted(UNITS)}", raw=text)
    return value, unit, text


def parse_list(raw: bytes) -> dict[str, Any]:
    """Parse the ``LIST`` reply into a dict: ``version, unit, mode, filter_displayed, filter_current,
    battery`` (None when absent) and ``fields`` (all fields, in order)."""
    text = decode_line(raw).strip()
    fields = [f.strip() for f in text.split(";")]
    if len(fields) < 2 or not all(re.fullmatch(r"[A-Za-z0-9.+\-]*", f) for f in fields):
        raise GarbledReply(f"expected ';'-separated LIST fields from the Mark-10; got {text!r}", raw=text)
    out: dict[str, Any] = {"version": None, "unit": None, "mode": None, "filter_displayed": None,
                           "filter_current": None, "battery": None, "fields": fields}
    for f in fields:
        u = f.upper()
        if out["version"] is None and re.fullmatch(r"V\d+(\.\d+)*", u):
            out["version"] = f[1:]
        elif out["unit"] is None and u in _UNIT_BY_LIST:
            out["unit"] = _UNIT_BY_LIST[u]
        elif out["mode"] is None and u in MODES:
            out["mode"] = u
        elif m := re.fullmatch(r"FLT([CP])(\d{1,2})", u):
            out["filter_displayed" if m.group(1) == "C" else "filter_current"] = int(m.group(2))
        elif re.fullmatch(r"B\d", u):
            out["battery"] = int(u[1])
    if out["unit"] is None:
        raise GarbledReply(f"no unit field in Mark-10 LIST reply {text!r}", raw=text)
    return out


# ------------------------------------------------------------------------------------------------
# driver
# ------------------------------------------------------------------------------------------------
class Mark10ForceGauge(RetryingDriver):
    """Mark-10 Series 5 gauge or 7i indicator on a serial port.

    Parameters
    ----------
    link : SerialLink
        The opened transport.
    retries : int
        Retries of a timed-out or garbled query.
    tension_positive : bool
        The gauge prints compression positive; with True (default) the driver returns tension as
        positive N, which is what the rig's load cell measures.
    ack_window : float
        Seconds to collect unsolicited lines after a set command (acknowledgement is not documented).

    Notes
    -----
    Opening reads ``LIST`` and the identity (``RM``, ``RS``, ``RV``) and never changes a setting.
    """

    def __init__(self, link: SerialLink, *, retries: int = 2, tension_positive: bool = True,
                 ack_window: float = 0.05) -> None:
        super().__init__(link, retries=retries)
        self.sign = -1.0 if tension_positive else 1.0
        self.ack_window = float(ack_window)
        self.identity = ""
        self.unit: str | None = None
        self.config: dict[str, Any] = {}
        self._refresh()

    def _refresh(self) -> None:
        self.config = self.list_settings()
        ident = []
        for cmd in ("RM", "RS", "RV"):
            try:
                ident.append(self._text(cmd).strip())
            except DeviceError:  # older indicators may not know every personality command
                ident.append("?")
        self.identity = "Mark-10 model {} s/n {} fw {}".format(*ident)
        log.info("%s: %s, %s", self.name, self.identity, self.config)

    def _text(self, command: str) -> str:
        with self.link.lock:
            self._ensure()
            return self._query(encode(command), decode_line)

    def _set(self, command: str) -> None:
        """Send a set command; raise a device error if one comes back in ``ack_window``."""
        with self.link.lock:
            self._ensure()
            self.link.send(encode(command))
            for line in self.link.collect_lines(self.ack_window):
                try:
                    text = decode_line(line)
                except GarbledReply:
                    log.debug("%s: ignoring unparseable line after %s: %r", self.name, command, line)
                    continue
                log.debug("%s: %s acknowledged with %r", self.name, command, text)

    # -- readings ------------------------------------------------------------------------------
    def read(self) -> Reading:
        """One force reading (``?``), in N (tension positive by default)."""
        with self.link.lock:
            self._ensure()
            value, unit, text = self._query(encode("?"), lambda raw: parse_force(raw, self.unit))
        self.unit = unit
        return Reading(value=self.sign * value * UNITS[unit][2], raw=text, unit=unit)

    def list_settings(self) -> dict[str, Any]:
        """Configuration snapshot from ``LIST`` (unit, mode, filters, version, battery, all fields)."""
        with self.link.lock:
            self.link.ensure_open()
            cfg = self._query(encode("LIST"), parse_list)
        self.unit = cfg["unit"]
        self.config = cfg
        return cfg

    # -- settings (confirmed by LIST) ----------------------------------------------------------
    def zero(self) -> None:
        """Zero (tare) the gauge with ``Z`` (also clears peaks)."""
        self._set("Z")

    def set_unit(self, unit: str) -> None:
        """Select the unit (``N``, ``kN``, ``lbF`` ...) and confirm it with ``LIST``."""
        cmd = unit_command(unit)
        with self.link.lock:
            self._set(cmd)
            got = self.list_settings()["unit"]
            if got != unit:
                raise DeviceError(f"{self.name}: asked for unit {unit!r} ({cmd}), LIST reports {got!r}")

    def set_mode(self, mode: str) -> None:
        """``CUR``, ``PT`` or ``PC``, confirmed with ``LIST``."""
        if mode not in MODES:
            raise ValueError(f"mode must be one of {sorted(MODES)}; got {mode!r}")
        with self.link.lock:
            self._set(mode)
            got = self.list_settings()["mode"]
            if got != mode:
                raise DeviceError(f"{self.name}: asked for mode {mode}, LIST reports {got}")

    def set_filter(self, which: str, n: int) -> None:
        """Digital filter ``FLTPn`` (current readings) or ``FLTCn`` (displayed), confirmed with ``LIST``."""
        cmd = filter_command(which, n)
        with self.link.lock:
            self._set(cmd)
            got = self.list_settings()["filter_current" if which == "current" else "filter_displayed"]
            if got != n:
                raise DeviceError(f"{self.name}: asked for {cmd}, LIST reports {got}")

    def settings(self) -> dict[str, Any]:
        """JSON-able description for the session file."""
        return {"model": "Mark-10", "identity": self.identity, "unit": self.unit,
                "mode": self.config.get("mode"), "list": ";".join(self.config.get("fields", [])),
                "tension_positive": self.sign < 0, "device": self.link.device,
                "timeout_s": self.link.timeout, "retries": self.retries}


def open_mark10(spec: Any, *, baudrate: int = 115200, timeout: float = 0.25, retries: int = 2,
                list_ports: Callable[[], list] | None = None, tension_positive: bool = True,
                reconnect_interval: float = 0.5) -> Mark10ForceGauge:
    """Open a Mark-10 gauge/indicator from a port spec (see :mod:`acquisition.serial_link`)."""
    link = SerialLink(spec, name="load cell (Mark-10)", baudrate=baudrate, timeout=timeout,
                      list_ports=list_ports, reconnect_interval=reconnect_interval)
    try:
        return Mark10ForceGauge(link, retries=retries, tension_positive=tension_positive)
    except BaseException:
        link.close()
        raise
