"""Device side of the Zaber ASCII protocol: a one-axis linear stage moving at finite speed, on a pty.

:meth:`ZaberDevice.handle` maps one received command line to the reply bytes (or None: not addressed to
this device, or a command whose checksum fails, which the simulator drops like line noise). Motion is
trapezoid-free: constant ``speed`` microsteps/s on an injectable clock, so a test that advances its own
clock moves the carriage deterministically. The axis powers up without a reference position (flag ``WR``)
until ``home`` has run. Simplifications: ``stop`` halts at once (no deceleration), a new move retargets a
moving axis without the ``NI`` notice.

Fault injection: the :class:`~rig_sim.serial_server.FaultInjector` of the server (garble, truncate,
silence, slow, unplug) plus :meth:`ZaberDevice.stall` (the axis stops where it is and reports ``FS``),
:meth:`ZaberDevice.set_flag` (any latched flag, e.g. ``FD``) and :meth:`ZaberDevice.stall_at` (a stall
when the carriage passes a position).
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
import threading
import time
from typing import Callable

import numpy as np

from acquisition.zaber import checksum
from rig_sim.serial_server import DeviceServer, FaultInjector

#: flags a ``warnings clear`` removes (faults and latched warnings); WR clears only by homing
_LATCHED = ("FS", "FD", "FQ", "FE", "WL", "NI")
#: reply priority of the flags, highest first (the manual's order)
_PRIORITY = ("FF", "FD", "FQ", "FS", "FT", "FB", "FP", "FE", "WH", "WL", "WP", "WV", "WT", "WM", "WR", "NC", "NI",
             "ND", "NU", "NJ")


class ZaberDevice:
    """Simulated one-axis Zaber stage (device address ``address``, axis 1).

    Parameters
    ----------
    clock : callable
        Time source (s) of the motion.
    speed : float
        Carriage speed, microsteps/s.
    limit_min, limit_max : int
        Travel (``limit.min``/``limit.max``), microsteps; home is ``limit_min``.
    start : int
        Power-up position register, microsteps (meaningless until homed).
    address : int
        Device address.
    reply_checksum : bool
        Append ``:CC`` to every reply (``comm.checksum 1``).
    """

    def __init__(self, *, clock: Callable[[], float] = time.monotonic, speed: float = 200_000.0,
                 limit_min: int = 0, limit_max: int = 1_066_667, start: int = 300_000, address: int = 1,
                 reply_checksum: bool = False) -> None:
        if not speed > 0:
            raise ValueError(f"speed must be > 0 microsteps/s; got {speed}")
        if not limit_min < limit_max:
            raise ValueError(f"limit_min must be < limit_max; got {limit_min}, {limit_max}")
        self.clock = clock
        self.speed = float(speed)
        self.limit_min, self.limit_max = int(limit_min), int(limit_max)
        self.address = int(address)
        self.reply_checksum = reply_checksum
        self.homed = False
        self.flags: set[str] = set()
        self._x0, self._target, self._t0 = float(start), float(start), clock()
        self._pos_now = float(start)
        self._homing = False
        self._stall_at: float | None = None
        self.commands: list[str] = []
        self.lock = threading.RLock()

    # -- physics -----------------------------------------------------------------------------------
    def _advance(self) -> None:
        """Bring the motion state up to now (finish a move, a homing run, or a pending stall)."""
        t = self.clock()
        d = self._target - self._x0
        travelled = min(abs(d), self.speed * max(0.0, t - self._t0))
        x = self._x0 + math.copysign(travelled, d)
        stall = self._stall_at
        if stall is not None and d != 0 and (stall - self._x0) * (stall - x) <= 0:
            self._stall_at, self._homing = None, False
            self._halt(stall)
            self.flags.add("FS")
            return
        if travelled >= abs(d):
            self._halt(self._target)
            if self._homing:
                self._homing, self.homed = False, True
                self._halt(float(self.limit_min))
                self.flags.discard("WR")
        else:
            self._pos_now = x

    def _halt(self, x: float) -> None:
        self._x0 = self._target = float(x)
        self._t0 = self.clock()

    def position(self) -> int:
        """Position register now, microsteps."""
        with self.lock:
            self._advance()
            return int(round(self._x0 if self._x0 == self._target else self._pos_now))

    def busy(self) -> bool:
        with self.lock:
            self._advance()
            return self._x0 != self._target

    def _move(self, target: float) -> None:
        x = float(self.position())
        self._x0, self._target, self._t0 = x, float(target), self.clock()
        self._pos_now = x

    # -- fault injection ---------------------------------------------------------------------------
    def stall(self, n: int = 1) -> None:
        """The axis stalls now: it stops where it is and reports ``FS`` until ``warnings clear``."""
        with self.lock:
            self._halt(float(self.position()))
            self._homing = False
            self.flags.add("FS")

    def stall_at(self, microsteps: float) -> None:
        """Stall when the carriage reaches ``microsteps`` during a later or the current move."""
        with self.lock:
            self._stall_at = float(microsteps)

    def set_flag(self, flag: str) -> None:
        """Latch any two-character flag (e.g. ``"FD"`` driver disabled)."""
        with self.lock:
            self.flags.add(flag)

    # -- protocol ----------------------------------------------------------------------------------
    def _flag(self) -> str:
        active = set(self.flags) | (set() if self.homed else {"WR"})
        for f in _PRIORITY:
            if f in active:
                return f
        return sorted(active)[0] if active else "--"

    def _reply(self, axis: int, mid: str | None, ok: bool, data: str) -> bytes:
        status = "BUSY" if self.busy() else "IDLE"
        body = " ".join([f"{self.address:02d}", str(axis)] + ([mid] if mid is not None else [])
                        + ["OK" if ok else "RJ", status, self._flag(), data])
        if self.reply_checksum:
            body += ":" + checksum(body)
        return f"@{body}\r\n".encode("ascii")

    def handle(self, line: str) -> bytes | None:
        """Reply to one command line (without terminator); None if it is not for this device or corrupt."""
        with self.lock:
            return self._handle(line.strip())

    def _handle(self, line: str) -> bytes | None:
        if not line.startswith("/"):
            return None
        body = line[1:]
        if len(body) >= 3 and body[-3] == ":":
            body, cc = body[:-3], body[-2:]
            if checksum(body) != cc.upper():
                return None  # a corrupt command is dropped
        words = body.split()
        device, axis, mid = 0, 0, None
        if words and words[0].isdigit():
            device = int(words.pop(0))
            if words and words[0].isdigit():
                axis = int(words.pop(0))
                if words and (words[0].isdigit() or words[0] == "--"):
                    mid = words.pop(0)
        if device not in (0, self.address):
            return None
        self.commands.append(" ".join(words))
        if axis > 1:
            return self._reply(axis, mid, False, "BADAXIS")
        ok, data = self._execute(words)
        return self._reply(axis, mid, ok, data)

    def _execute(self, words: list[str]) -> tuple[bool, str]:
        if not words:
            return True, "0"
        cmd, args = words[0], words[1:]
        if cmd == "home" and not args:
            self._move(self.limit_min)  # towards the home sensor at limit.min
            self._homing = True
            self._advance()
            return True, "0"
        if cmd == "move" and len(args) == 2 and args[0] == "abs":
            try:
                n = int(args[1])
            except ValueError:
                return False, "BADDATA"
            if not self.limit_min <= n <= self.limit_max:
                return False, "BADDATA"
            self._move(n)
            return True, "0"
        if cmd == "stop" and not args:
            self._halt(float(self.position()))
            self._homing = False
            return True, "0"
        if cmd == "get" and len(args) == 1:
            values = {"pos": self.position(), "limit.min": self.limit_min, "limit.max": self.limit_max,
                      "maxspeed": int(round(self.speed * 1.6384)), "comm.checksum": int(self.reply_checksum)}
            if args[0] in values:
                return True, str(values[args[0]])
            return False, "BADCOMMAND"
        if cmd == "warnings" and args in ([], ["clear"]):
            active = sorted(set(self.flags) | (set() if self.homed else {"WR"}))
            data = " ".join([f"{len(active):02d}"] + active)
            if args:
                self.flags -= set(_LATCHED)
            return True, data
        return False, "BADCOMMAND"


class SimulatedStage:
    """A :class:`ZaberDevice` served on a pseudo-terminal behind a stable symlink (context manager).

    Parameters
    ----------
    device : ZaberDevice, optional
        The stage model (default: one on ``clock``).
    clock : callable
        Time source of the default device.
    transport : {"pty", "socket"}
    rng : numpy.random.Generator
        Garbage bytes of the fault injector.
    """

    def __init__(self, device: ZaberDevice | None = None, *, clock: Callable[[], float] = time.monotonic,
                 transport: str = "pty", rng: np.random.Generator | None = None, serial_number: str = "SIMZ001"):
        self.device = device if device is not None else ZaberDevice(clock=clock)
        self.serial_number = serial_number
        self._dir = tempfile.mkdtemp(prefix="vfmlab-stage-sim-")
        os.makedirs(os.path.join(self._dir, "by-id"))
        self.server = DeviceServer(self.device.handle, transport=transport, name="zaber-sim",
                                   link_path=os.path.join(self._dir, "by-id", f"usb-Zaber_{serial_number}"),
                                   rng=rng if rng is not None else np.random.default_rng(5),
                                   inject_device_error=self.device.stall)

    @property
    def port(self) -> str:
        """Stable path (pty symlink) or socket URL the driver opens."""
        return self.server.port

    @property
    def faults(self) -> FaultInjector:
        """Line faults (garble, truncate, silence, slow, unplug); ``device_error()`` stalls the axis (``FS``)."""
        return self.server.faults

    def start(self) -> "SimulatedStage":
        self.server.start()
        return self

    def close(self) -> None:
        self.server.stop()
        shutil.rmtree(self._dir, ignore_errors=True)

    def __enter__(self) -> "SimulatedStage":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
