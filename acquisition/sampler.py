"""Background sampling of the pressure and force instruments, with a lossless record for the session log.

One thread per instrument reads it at ``rate_hz`` so a slow or faulty instrument never stalls the other.
Every successful reading gets the next sequence number of its channel and goes to two places:

* a ring buffer (latest value, recent history, stability test, live display), which may overwrite, and
* a pending queue that :meth:`Sampler.drain` empties, so a session runner writes every sample to the
  session log exactly once (sequence numbers are contiguous across drains; if the pending queue ever
  overflowed, the count of dropped samples is reported in ``ChannelRecord.lost``, never hidden).

Failed reads do not consume sequence numbers; they become :class:`SamplerEvent` entries and change the
channel status (``ok`` / ``fault`` / ``disconnected``), reported to ``on_status`` so a runner can pause
and resume. Timestamps: the midpoint of the query on the injected monotonic clock and on the wall clock.
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from acquisition.instrument_errors import Disconnected, InstrumentError

log = logging.getLogger(__name__)

CHANNELS = ("pressure", "force")


@dataclass(frozen=True)
class Sample:
    """One timestamped reading: ``seq`` (per channel), ``t_monotonic``/``t_wall`` (s), ``value`` (Pa or N), ``raw``."""

    seq: int
    t_monotonic: float
    t_wall: float
    value: float
    raw: str


@dataclass(frozen=True)
class ChannelRecord:
    """Samples of one channel as arrays, shapes ``(n,)``; ``value`` in Pa (pressure) or N (force).

    ``lost`` counts samples dropped because the pending queue overflowed before this drain (0 normally).
    """

    seq: np.ndarray
    t_monotonic: np.ndarray
    t_wall: np.ndarray
    value: np.ndarray
    raw: list[str]
    lost: int = 0

    def __len__(self) -> int:
        return int(self.seq.shape[0])

    @staticmethod
    def from_samples(samples: list[Sample], lost: int = 0) -> "ChannelRecord":
        return ChannelRecord(seq=np.array([s.seq for s in samples], dtype=np.int64),
                             t_monotonic=np.array([s.t_monotonic for s in samples], dtype=float),
                             t_wall=np.array([s.t_wall for s in samples], dtype=float),
                             value=np.array([s.value for s in samples], dtype=float),
                             raw=[s.raw for s in samples], lost=lost)


@dataclass(frozen=True)
class ChannelStatus:
    """State of a channel: ``"ok"``, ``"fault"``, ``"disconnected"`` or ``"stopped"``, since ``since`` (monotonic s)."""

    state: str
    message: str
    since: float
    n_ok: int
    n_faults: int


@dataclass(frozen=True)
class SamplerEvent:
    """Something the session log should record: kind ``"fault"``, ``"disconnected"`` or ``"recovered"``."""

    t_monotonic: float
    t_wall: float
    channel: str
    kind: str
    message: str


@dataclass
class _Channel:
    name: str
    instrument: Any
    ring: collections.deque
    pending: collections.deque = field(default_factory=collections.deque)
    next_seq: int = 0
    lost: int = 0
    state: str = "stopped"
    message: str = ""
    since: float = 0.0
    n_ok: int = 0
    n_faults: int = 0
    last_fault: float = -float("inf")
    lock: threading.Lock = field(default_factory=threading.Lock)


class Sampler:
    """Read the pressure and force instruments continuously in background threads.

    Parameters
    ----------
    pressure, load_cell : object with ``read() -> Reading`` or None
        The drivers (``Reading.value`` in Pa / N). A None channel is not sampled.
    rate_hz : float
        Reads per second of *each* instrument (the combined rate is twice this with both present).
    clock, wall_clock : callable
        Monotonic and wall clocks (s); injectable for tests.
    ring_size : int
        Samples kept per channel for :meth:`latest`, :meth:`history` and :meth:`is_stable`.
    max_pending : int
        Bound of the not-yet-drained queue per channel (overflow is counted in ``ChannelRecord.lost``).
    on_status : callable, optional
        ``on_status(channel, ChannelStatus)`` on every state change, from the sampler thread.
    """

    def __init__(self, pressure: Any, load_cell: Any, rate_hz: float = 50.0, *,
                 clock: Callable[[], float] = time.monotonic, wall_clock: Callable[[], float] = time.time,
                 ring_size: int = 4096, max_pending: int = 1_000_000,
                 on_status: Callable[[str, ChannelStatus], None] | None = None) -> None:
        if not (0 < rate_hz <= 1000):
            raise ValueError(f"rate_hz must be in (0, 1000]; got {rate_hz}")
        if ring_size < 2 or max_pending < 1:
            raise ValueError(f"ring_size must be >= 2 and max_pending >= 1; got {ring_size}, {max_pending}")
        self.rate_hz = float(rate_hz)
        self.clock = clock
        self.wall_clock = wall_clock
        self.max_pending = int(max_pending)
        self.on_status = on_status
        self._channels: dict[str, _Channel] = {}
        for name, inst in zip(CHANNELS, (pressure, load_cell)):
            if inst is not None:
                self._channels[name] = _Channel(name, inst, collections.deque(maxlen=int(ring_size)),
                                                since=clock())
        if not self._channels:
            raise ValueError("Sampler needs at least one instrument; got pressure=None and load_cell=None")
        self._events: collections.deque[SamplerEvent] = collections.deque(maxlen=100_000)
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    # -- life cycle --------------------------------------------------------------------------------
    @property
    def channels(self) -> tuple[str, ...]:
        return tuple(self._channels)

    @property
    def running(self) -> bool:
        return any(t.is_alive() for t in self._threads)

    def start(self) -> "Sampler":
        """Start one sampling thread per instrument."""
        if self.running:
            raise RuntimeError("Sampler already running")
        self._stop.clear()
        self._threads = [threading.Thread(target=self._run, args=(ch,), name=f"sampler-{ch.name}", daemon=True)
                         for ch in self._channels.values()]
        for t in self._threads:
            t.start()
        return self

    def stop(self, timeout: float = 5.0) -> None:
        """Stop the threads (waits for the read in flight) and mark channels ``stopped``."""
        self._stop.set()
        for t in self._threads:
            t.join(timeout)
        self._threads = []
        for ch in self._channels.values():
            self._set_state(ch, "stopped", "sampler stopped", event=False)

    def __enter__(self) -> "Sampler":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def poll_once(self) -> None:
        """Read every instrument once, synchronously (only while the threads are stopped)."""
        if self.running:
            raise RuntimeError("poll_once() is for a stopped Sampler; the threads are running")
        for ch in self._channels.values():
            self._poll(ch)

    # -- sampling ----------------------------------------------------------------------------------
    def _run(self, ch: _Channel) -> None:
        period = 1.0 / self.rate_hz
        next_t = self.clock()
        while not self._stop.is_set():
            self._poll(ch)
            next_t += period
            delay = next_t - self.clock()
            if delay < -period:  # fell behind (slow device, fault): restart the schedule, no burst
                next_t = self.clock()
                delay = 0.0
            if delay > 0:
                self._stop.wait(delay)

    def _poll(self, ch: _Channel) -> None:
        t0, w0 = self.clock(), self.wall_clock()
        try:
            reading = ch.instrument.read()
        except Disconnected as exc:
            ch.last_fault = self.clock()
            self._set_state(ch, "disconnected", str(exc))
            return
        except InstrumentError as exc:
            ch.last_fault = self.clock()
            ch.n_faults += 1
            self._set_state(ch, "fault", f"{type(exc).__name__}: {exc}", force_event=True)
            return
        except Exception as exc:  # a bug in a driver must not kill the thread silently
            log.exception("%s: unexpected error while reading", ch.name)
            ch.last_fault = self.clock()
            ch.n_faults += 1
            self._set_state(ch, "fault", f"{type(exc).__name__}: {exc}", force_event=True)
            return
        t1, w1 = self.clock(), self.wall_clock()
        with ch.lock:
            s = Sample(ch.next_seq, 0.5 * (t0 + t1), 0.5 * (w0 + w1), float(reading.value), str(reading.raw))
            ch.next_seq += 1
            ch.ring.append(s)
            ch.pending.append(s)
            if len(ch.pending) > self.max_pending:
                ch.pending.popleft()
                ch.lost += 1
            ch.n_ok += 1
        if ch.state != "ok":
            self._set_state(ch, "ok", "")

    def _set_state(self, ch: _Channel, state: str, message: str, *, event: bool = True,
                   force_event: bool = False) -> None:
        changed = state != ch.state
        previous = ch.state
        if changed:
            ch.state, ch.message, ch.since = state, message, self.clock()
        else:
            ch.message = message
        if event and (changed or force_event) and not (state == "ok" and previous == "stopped"):
            kind = "recovered" if state == "ok" else state
            self._events.append(SamplerEvent(self.clock(), self.wall_clock(), ch.name, kind,
                                             message or f"{ch.name} reading again"))
            if state != "ok":
                log.warning("%s: %s: %s", ch.name, kind, message)
        if changed and self.on_status is not None:
            try:
                self.on_status(ch.name, self.status(ch.name))
            except Exception:  # pragma: no cover - a broken callback must not stop sampling
                log.exception("on_status callback failed")

    # -- access ------------------------------------------------------------------------------------
    def _ch(self, channel: str) -> _Channel:
        try:
            return self._channels[channel]
        except KeyError:
            raise ValueError(f"channel must be one of {self.channels}; got {channel!r}") from None

    def latest(self, channel: str) -> Sample | None:
        """The most recent sample of ``channel`` (None before the first one)."""
        ch = self._ch(channel)
        with ch.lock:
            return ch.ring[-1] if ch.ring else None

    def history(self, channel: str, seconds: float | None = None) -> ChannelRecord:
        """Samples still in the ring buffer, optionally only the last ``seconds``."""
        ch = self._ch(channel)
        with ch.lock:
            samples = list(ch.ring)
        if seconds is not None:
            t_min = self.clock() - seconds
            samples = [s for s in samples if s.t_monotonic >= t_min]
        return ChannelRecord.from_samples(samples)

    def drain(self, channel: str) -> ChannelRecord:
        """Every sample of ``channel`` since the previous drain, exactly once, in sequence order."""
        ch = self._ch(channel)
        with ch.lock:
            samples = list(ch.pending)
            ch.pending.clear()
            lost, ch.lost = ch.lost, 0
        return ChannelRecord.from_samples(samples, lost=lost)

    def drain_events(self) -> list[SamplerEvent]:
        """Fault/disconnect/recovery events since the previous call, oldest first."""
        out = []
        while self._events:
            out.append(self._events.popleft())
        return out

    def status(self, channel: str) -> ChannelStatus:
        """Current state of ``channel``."""
        ch = self._ch(channel)
        return ChannelStatus(ch.state, ch.message, ch.since, ch.n_ok, ch.n_faults)

    @property
    def healthy(self) -> bool:
        """True when every channel is ``ok``."""
        return all(ch.state == "ok" for ch in self._channels.values())

    # -- stability ---------------------------------------------------------------------------------
    def is_stable(self, band_pa: float, dwell_s: float, target_pa: float | None = None) -> bool:
        """True if the pressure stayed within ``±band_pa`` for the last ``dwell_s`` seconds.

        The reference is ``target_pa`` or, if None, the mean over the window. Also required: the ring
        buffer reaches back at least ``dwell_s``, no fault happened in the window, the channel is ``ok``
        and the newest sample is fresh (younger than max(0.5 s, 5 periods)).
        """
        if band_pa <= 0 or dwell_s <= 0:
            raise ValueError(f"band_pa and dwell_s must be > 0; got {band_pa}, {dwell_s}")
        ch = self._ch("pressure")
        if dwell_s * self.rate_hz >= ch.ring.maxlen:
            raise ValueError(f"dwell_s={dwell_s} needs {dwell_s * self.rate_hz:.0f} samples at {self.rate_hz} Hz; "
                             f"the ring buffer holds {ch.ring.maxlen} (raise ring_size)")
        now = self.clock()
        start = now - dwell_s
        with ch.lock:
            samples = list(ch.ring)
        if ch.state != "ok" or len(samples) < 2 or ch.last_fault >= start:
            return False
        if samples[0].t_monotonic > start or now - samples[-1].t_monotonic > max(0.5, 5.0 / self.rate_hz):
            return False
        values = np.array([s.value for s in samples if s.t_monotonic >= start])
        if values.size < 2:
            return False
        ref = float(values.mean()) if target_pa is None else float(target_pa)
        return bool(np.all(np.abs(values - ref) <= band_pa))

    def wait_stable(self, band_pa: float, dwell_s: float, target_pa: float | None = None,
                    timeout_s: float = 60.0, poll_s: float = 0.02) -> bool:
        """Block until :meth:`is_stable` (True) or ``timeout_s`` elapses (False)."""
        deadline = self.clock() + timeout_s
        while self.clock() < deadline:
            if self.is_stable(band_pa, dwell_s, target_pa):
                return True
            time.sleep(poll_s)
        return self.is_stable(band_pa, dwell_s, target_pa)
