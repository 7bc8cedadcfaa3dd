"""Device side of the Mark-10 Gauge Control Language (a Series 5 gauge / 7i indicator with a load cell).

:meth:`Mark10Device.handle` maps one received command line to the reply bytes, or None for set commands
(the guide does not promise an acknowledgement; ``ack`` makes the simulator send one, to exercise the
driver's tolerant read). Readings are printed compression-positive, like the gauge.
"""

from __future__ import annotations

import re
import threading

from acquisition.mark10 import UNITS
from rig_sim.instrument_physics import ForceModel

_DECIMALS = {"N": 3, "mN": 0, "kN": 6, "lbF": 4, "ozF": 2, "kgF": 4, "gF": 1}
_UNIT_OF_COMMAND = {v[0]: u for u, v in UNITS.items()}


class Mark10Device:
    """Simulated Mark-10 indicator.

    Parameters
    ----------
    force : ForceModel
        The load-cell signal (N, tension positive).
    serial_number : str
        Reported by ``RS``.
    ack : str or None
        Line sent after each accepted set command (None: silent, the default).
    """

    def __init__(self, force: ForceModel, *, serial_number: str = "SIM1001", ack: str | None = None) -> None:
        self.force = force
        self.serial_number = serial_number
        self.ack = ack
        self.unit = "N"
        self.mode = "CUR"
        self.filter_displayed = 8
        self.filter_current = 0
        self.tare_n = 0.0
        self.peak_tension = 0.0
        self.peak_compression = 0.0
        self.pending_errors = 0
        self.lock = threading.Lock()

    def inject_error(self, n: int = 1) -> None:
        """Answer the next ``n`` commands with ``*10`` (as if they arrived corrupted)."""
        with self.lock:
            self.pending_errors += n

    def _net(self) -> float:
        f = self.force.signal() - self.tare_n
        self.peak_tension = max(self.peak_tension, f)
        self.peak_compression = max(self.peak_compression, -f)
        return f

    def _fmt(self, tension_n: float) -> bytes:
        value = -tension_n / UNITS[self.unit][2]  # compression positive
        d = _DECIMALS[self.unit]
        return f"{value:.{d}f} {self.unit}\r\n".encode("ascii")

    def _list(self) -> str:
        return (f"V1.00;{UNITS[self.unit][1]};{self.mode};FLTC{self.filter_displayed};FLTP{self.filter_current};"
                f"AOUT00;AOFF5;FULL;MIT;POL;B0")

    def handle(self, line: str) -> bytes | None:
        """Reply to one command line (without terminator)."""
        with self.lock:
            cmd = line.strip()
            if not cmd:
                return None
            if self.pending_errors:
                self.pending_errors -= 1
                return b"*10\r\n"
            return self._handle(cmd)

    def _ok(self) -> bytes | None:
        return None if self.ack is None else f"{self.ack}\r\n".encode("ascii")

    def _handle(self, cmd: str) -> bytes | None:
        if cmd in ("?", "?C"):
            f = self._net()
            if cmd == "?" and self.mode == "PT":
                f = self.peak_tension
            elif cmd == "?" and self.mode == "PC":
                f = -self.peak_compression
            return self._fmt(f)
        if cmd == "?PT":
            self._net()
            return self._fmt(self.peak_tension)
        if cmd == "?PC":
            self._net()
            return self._fmt(-self.peak_compression)
        if cmd == "LIST":
            return (self._list() + "\r\n").encode("ascii")
        if cmd == "RN":
            return b"Series 5 Force Gauge (simulated)\r\n"
        if cmd == "RM":
            return b"M5-20\r\n"
        if cmd == "RS":
            return f"{self.serial_number}\r\n".encode("ascii")
        if cmd == "RV":
            return b"1.00\r\n"
        if cmd in _UNIT_OF_COMMAND:
            self.unit = _UNIT_OF_COMMAND[cmd]
            return self._ok()
        if cmd in ("CUR", "PT", "PC"):
            self.mode = cmd
            return self._ok()
        if cmd == "CLR":
            self.peak_tension = self.peak_compression = 0.0
            return self._ok()
        if cmd == "Z":
            self.tare_n = self.force.signal()
            self.peak_tension = self.peak_compression = 0.0
            return self._ok()
        m = re.fullmatch(r"FLT([CP])(\d+)", cmd)
        if m:
            n = int(m.group(2))
            if n > 10:
                return b"*22\r\n"
            if m.group(1) == "C":
                self.filter_displayed = n
            else:
                self.filter_current = n
            return self._ok()
        if cmd.startswith("FLT"):
            return b"*12\r\n"
        return b"*10\r\n"
