"""Device side of the Mensor command set (a CPC controller, or a CPG2500 indicator in manual mode).

:meth:`MensorDevice.handle` maps one received command line to the reply bytes (or None: commands without
``?`` get no reply, as in the manual). Replies begin with a space, or ``E`` while the error queue is not
empty, and end with CR LF.
"""

from __future__ import annotations

import collections
import threading
import numpy as np

from acquisition.mensor import CODE_OF_UNIT, PA_PER_UNIT, UNIT_CODES
from rig_sim.instrument_physics import PressurePlant

ATMOSPHERE_PA = 101325.0


class MensorDevice:
    """Simulated Mensor pressure instrument.

    Parameters
    ----------
    plant : PressurePlant
        The pressure it measures (and, as a controller, drives).
    controller : bool
        True: a CPC controller (``Mode``, ``Setpt``, ``Stable?``); False: a CPG2500 indicator whose
        pressure is set by the operator (:meth:`set_operator_pressure`).
    rng : numpy.random.Generator
        Measurement noise.
    noise_pa : float
        Gaussian noise of a reading (Pa).
    stable_window_pa : float
        ``Stable?`` answers YES when |p - set-point| <= this in control mode.
    serial_number : str
        Reported by ``ID?``.
    """

    def __init__(self, plant: PressurePlant, *, controller: bool = True, rng: np.random.Generator | None = None,
                 noise_pa: float = 2.0, stable_window_pa: float = 20.0, serial_number: str = "SIM0001",
                 unit: str = "mmHg") -> None:
        self.plant = plant
        self.controller = controller
        self.rng = rng if rng is not None else np.random.default_rng(1)
        self.noise_pa = float(noise_pa)
        self.stable_window_pa = float(stable_window_pa)
        self.serial_number = serial_number
        self.unit = unit
        self.ptype = "GAUGE"
        self.mode = "MEASURE"
        self.setpoint_pa = 0.0
        self.errors: collections.deque[str] = collections.deque(maxlen=10)
        self.lock = threading.Lock()
        self.model = "CPC6050" if controller else "CPG2500"

    # -- operator side -----------------------------------------------------------------------------
    def set_operator_pressure(self, pa: float) -> None:
        """Manual pressure source (indicator): the pressure moves to ``pa`` with the plant's time constant."""
        self.plant.set_target(pa)

    def push_error(self, message: str) -> None:
        """Put an entry in the error queue (fault injection, or a bad command)."""
        with self.lock:
            self.errors.append(message)

    # -- protocol ----------------------------------------------------------------------------------
    def _reply(self, text: str) -> bytes:
        flag = "E" if self.errors else " "
        return f"{flag}{text}\r\n".encode("ascii")

    def _value(self, pa: float) -> str:
        return f"{pa / PA_PER_UNIT[self.unit]:+.6E}"

    def handle(self, line: str) -> bytes | None:
        """Reply to one command line (without terminator); None when the command gets no reply."""
        with self.lock:
            return self._handle(line.strip())

    def _handle(self, line: str) -> bytes | None:
        if not line:
            return None
        is_query = line.endswith("?") or "? " in line
        head, _, data = line.partition(" ")
        key = head.rstrip("?").upper()
        data = data.strip()
        if is_query:
            return self._query(key, line)
        self._command(key, data, line)
        return None

    def _query(self, key: str, line: str) -> bytes:
        if key == "":
            p = self.plant.pressure() + (self.rng.normal(0.0, self.noise_pa) if self.noise_pa > 0 else 0.0)
            return self._reply(self._value(p))
        if key == "ID":
            return self._reply(f"MENSOR, {self.model}, {self.serial_number}, 1.00")
        if key == "UNITS":
            return self._reply(self.unit)
        if key == "PTYPE":
            return self._reply(self.ptype)
        if key == "ERROR":
            msg = self.errors.popleft() if self.errors else "NO ERROR"
            return self._reply(msg)
        if self.controller:
            if key == "MODE":
                return self._reply(self.mode)
            if key == "SETPT":
                return self._reply(self._value(self.setpoint_pa))
            if key == "STABLE":
                ok = self.mode == "CONTROL" and abs(self.plant.pressure() - self.setpoint_pa) <= self.stable_window_pa
                return self._reply("YES" if ok else "NO")
        self.errors.append(f"Unknown query {line!r}")
        return self._reply("")

    def _command(self, key: str, data: str, line: str) -> None:
        if key == "UNITS":
            code = int(data) if data.isdigit() else CODE_OF_UNIT.get(data, -1)
            if code in UNIT_CODES:
                self.unit = UNIT_CODES[code][0]
                return
        elif key == "PTYPE" and data.upper() in ("GAUGE", "ABSOLUTE"):
            self.ptype = data.upper()
            return
        elif self.controller and key == "MODE" and data.upper() in ("STANDBY", "MEASURE", "CONTROL", "VENT"):
            self.mode = data.upper()
            self._drive()
            return
        elif self.controller and key == "SETPT":
            try:
                self.setpoint_pa = float(data) * PA_PER_UNIT[self.unit]
            except ValueError:
                pass
            else:
                self._drive()
                return
        self.errors.append(f"Bad command {line!r}")

    def _drive(self) -> None:
        if self.mode == "CONTROL":
            self.plant.set_target(self.setpoint_pa)
        elif self.mode == "VENT":
            self.plant.set_target(0.0 if self.ptype == "GAUGE" else ATMOSPHERE_PA)
        else:
            self.plant.hold()

