"""Test doubles for the runner's collaborators (not production code): an instrument pair whose
pressure follows a first-order response to the setpoint, exposing the Sampler API."""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field

import numpy as np


@dataclass
class Rec:
    seq: np.ndarray
    t_monotonic: np.ndarray
    t_wall: np.ndarray
    value: np.ndarray
    raw: list
    lost: int = 0


@dataclass
class Status:
    state: str = "ok"
    message: str = ""


@dataclass
class Ev:
    t_monotonic: float
    t_wall: float
    channel: str
    kind: str
    message: str


@dataclass
class FakeRig:
    """Pressure driver + Sampler look-alike. Samples are generated lazily at ``rate_hz``."""

    tau_s: float = 0.03
    rate_hz: float = 200.0
    force_per_pa: float = 1e-4
    identity: str = "FAKE-CPC 0001"
    is_controller: bool = True
    modes: list = field(default_factory=list)
    fault: dict = field(default_factory=dict)  # channel -> message while faulty

    def __post_init__(self):
        self.t0 = time.monotonic()
        self._sp, self._p0, self._tset = 0.0, 0.0, self.t0
        self._last = {"pressure": self.t0, "force": self.t0}
        self._seq = {"pressure": 0, "force": 0}
        self._pending = {ch: [] for ch in self._last}
        self._ring = {ch: [] for ch in self._last}
        self._events = []
        self._lock = threading.Lock()
        self.stretch = 1.0

    # pressure driver
    def true_pressure(self, t=None):
        t = time.monotonic() if t is None else t
        return self._sp + (self._p0 - self._sp) * math.exp(-(t - self._tset) / self.tau_s)

    def set_setpoint(self, pa):
        if "pressure" in self.fault:
            from acquisition.instrument_errors import Disconnected
            raise Disconnected(f"pressure port gone: {self.fault['pressure']}")
        self._gen()
        now = time.monotonic()
        self._p0, self._tset, self._sp = self.true_pressure(now), now, float(pa)

    def set_mode(self, mode):
        self.modes.append(mode)
        if mode == "vent":
            self.set_setpoint(0.0)

    def settings(self):
        return {"fake": True}

    # faults
    def set_fault(self, channel, message):
        self._gen()
        self.fault[channel] = message
        self._events.append(Ev(time.monotonic(), time.time(), channel, "disconnected", message))

    def clear_fault(self, channel):
        self._gen()
        self.fault.pop(channel, None)
        self._events.append(Ev(time.monotonic(), time.time(), channel, "recovered", "back"))

    # sampler
    def _gen(self):
        with self._lock:
            now = time.monotonic()
            for ch in self._last:
                ts = np.arange(self._last[ch] + 1 / self.rate_hz, now, 1 / self.rate_hz)
                if ts.size:
                    self._last[ch] = ts[-1]
                if ch in self.fault:
                    continue
                for t in ts:
                    p = self.true_pressure(t)
                    v = p if ch == "pressure" else self.force_per_pa * p + (self.stretch - 1.0)
                    s = (self._seq[ch], t, time.time() - (now - t), v, f"{v:.5f}")
                    self._seq[ch] += 1
                    self._pending[ch].append(s)
                    self._ring[ch].append(s)
                self._ring[ch] = self._ring[ch][-4000:]

    @staticmethod
    def _rec(samples):
        if not samples:
            return Rec(np.zeros(0, np.int64), np.zeros(0), np.zeros(0), np.zeros(0), [])
        a = list(zip(*samples))
        return Rec(np.array(a[0], np.int64), np.array(a[1]), np.array(a[2]), np.array(a[3]), list(a[4]))

    def drain(self, ch):
        self._gen()
        with self._lock:
            out, self._pending[ch] = self._pending[ch], []
        return self._rec(out)

    def history(self, ch, seconds=None):
        self._gen()
        now = time.monotonic()
        return self._rec([s for s in self._ring[ch] if seconds is None or s[1] >= now - seconds])

    def latest(self, ch):
        self._gen()
        if not self._ring[ch]:
            return None
        s = self._ring[ch][-1]
        return Rec(s[0], s[1], s[2], s[3], s[4])

    def drain_events(self):
        out, self._events = self._events, []
        return out

    def status(self, ch):
        return Status("disconnected", self.fault[ch]) if ch in self.fault else Status()

    @property
    def healthy(self):
        return not self.fault

    def is_stable(self, band, dwell, target=None):
        self._gen()
        if self.fault:
            return False
        now = time.monotonic()
        win = [s for s in self._ring["pressure"] if s[1] >= now - dwell]
        if not win or now - self._tset < dwell:
            return False
        v = np.array([s[3] for s in win])
        ref = target if target is not None else v.mean()
        return bool(np.all(np.abs(v - ref) <= band))
