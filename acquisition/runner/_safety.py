"""The runner's readings at a capture and its safety checks (limits, implausible lone readings).

A mixin of :class:`~acquisition.runner.SessionRunner`: it uses the runner's ``protocol``, ``sampler``,
``safety``, ``clock``, ``sleep``, ``tick_s``, ``_actuated_at`` and its ``_warn``/``_event``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from acquisition.plausibility import LoadLimits
from acquisition.protocol import MMHG
from acquisition.runner._errors import SessionAborted

CHANNELS = ("pressure", "force")


class _SafetyChecks:
    """Readings at the exposure, and aborts (resumable) when they exceed the rig's safety limits."""

    def _readings(self, t_exposure: float) -> tuple[float, float]:
        """Mean pressure (Pa) and force (N) at the exposure: over a window centred on the trigger time
        ``t_exposure`` (clock s), as wide as the stable dwell (at most 1 s), never reaching back before
        the last actuation; the latest sample if that window is empty.

        Centred, because a pressure still creeping inside the stability band is what the images show at
        the trigger: a window from the end of the dwell to the end of the capture (a slow camera or a
        renderer takes seconds) recorded it ahead of the images (simulated rig, +-1 mmHg band: 0.3-0.5 mmHg
        above the imaged state, Fung beta +1 to +2 %).
        """
        half = max(min(self.protocol.stability.dwell_s, 1.0), 2 * self.tick_s) / 2
        t_min = max(t_exposure - half, self._actuated_at)  # nothing from before a move
        seconds = max(self.clock() - t_min, self.tick_s)
        out = []
        for ch in CHANNELS:
            rec = self.sampler.history(ch, seconds=seconds)
            t = np.asarray(rec.t_monotonic, dtype=float)
            values = np.asarray(rec.value, dtype=float)[(t >= t_min) & (t <= t_exposure + half)]
            if values.size:
                out.append(_robust_mean(values))
            else:
                latest = self.sampler.latest(ch)
                out.append(float(latest.value) if latest is not None else math.nan)
        self._check_limits(out[0], out[1])
        return out[0], out[1]

    def _over_limit(self, ch: str, value: float) -> str | None:
        """What is wrong when ``value`` of channel ``ch`` exceeds the rig's safety limit, else None."""
        if ch == "pressure" and value > self.safety.max_pressure * 1.05:  # 5 % grace on pressure
            return (f"pressure {value / MMHG:.1f} mmHg exceeds the safety limit "
                    f"{self.safety.max_pressure / MMHG:.1f} mmHg")
        if ch == "force" and abs(value) > self.safety.max_force:
            return f"force {value:.3f} N exceeds the safety limit {self.safety.max_force:.3f} N"
        return None

    def _check_limits(self, pressure: float, force: float) -> None:
        """Abort (and so vent) when a reading exceeds the rig's safety limits (resumable once safe)."""
        for ch, value in (("pressure", pressure), ("force", force)):
            what = self._over_limit(ch, value)
            if what is not None:
                raise SessionAborted(what + "; pressure vented", resumable=True)

    #: Fresh samples that must confirm an over-limit reading, and how long to wait for them, s.
    CONFIRM_SAMPLES, CONFIRM_WAIT_S = 3, 0.5

    def _check_readings(self, drained: dict[str, Any]) -> None:
        """Judge every new sample against the limits, and an over-limit one against its neighbours.

        One corrupted reading (a well-formed reply with a wrong number) must not abort a test: an
        over-limit sample is retried, i.e. confirmed by the fresh samples that follow it; the
        session aborts if most of them are over the limit too (or none arrive), and the lone
        reading is recorded as an event and ignored otherwise.
        """
        for ch in CHANNELS:
            rec = drained.get(ch)
            if rec is None or not len(rec.t_monotonic):
                continue
            values, times = np.asarray(rec.value, dtype=float), np.asarray(rec.t_monotonic, dtype=float)
            if ch == "pressure":
                self._check_negative(values)
            over = [i for i in range(values.size) if self._over_limit(ch, values[i]) is not None]
            for i in over:
                self._judge(ch, float(values[i]), float(times[i]))

    #: A pressure reading below this (Pa) is no transducer offset: a sign, a vacuum or a wrong zero.
    NEGATIVE_PRESSURE = LoadLimits().min_pressure

    def _check_negative(self, values: np.ndarray) -> None:
        """Warn (once per run, stored as a "warning" event) when pressure readings are below -1 kPa."""
        negative = values < self.NEGATIVE_PRESSURE
        if not negative.any() or getattr(self, "_negative_warned", False):
            return
        self._negative_warned = True
        low = float(values[negative].min())
        msg = (f"negative pressure readings: {int(negative.sum())} below {self.NEGATIVE_PRESSURE / MMHG:.1f} mmHg "
               f"(lowest {low / MMHG:.1f} mmHg = {low / 1e3:.3g} kPa); check the transducer's zero, its sign and "
               "that the lumen is not under suction")
        self._warn(msg)
        self._event("warning", msg)

    def _judge(self, ch: str, value: float, t_sample: float) -> None:
        what = self._over_limit(ch, value)
        fresh = self._fresh_samples(ch, t_sample)
        bad = sum(self._over_limit(ch, v) is not None for v in fresh)
        if len(fresh) < self.CONFIRM_SAMPLES or bad * 2 > len(fresh):
            raise SessionAborted(what + f" (confirmed by {bad} of {len(fresh)} following readings); "
                                        "pressure vented", resumable=True)
        msg = (f"implausible {_NAMES[ch]} reading ignored: {what}, but {len(fresh) - bad} of the "
               f"{len(fresh)} readings that followed are normal (median {np.median(fresh):.4g})")
        self._warn(msg)
        self._event("implausible_reading", msg)

    def _fresh_samples(self, ch: str, t_after: float) -> list[float]:
        """Values of ``ch`` sampled after ``t_after``, waiting (bounded) for CONFIRM_SAMPLES of them."""
        deadline = self.clock() + self.CONFIRM_WAIT_S
        while True:
            rec = self.sampler.history(ch, seconds=self.CONFIRM_WAIT_S + 5.0)
            t = np.asarray(rec.t_monotonic, dtype=float)
            values = np.asarray(rec.value, dtype=float)[t > t_after]
            if values.size >= self.CONFIRM_SAMPLES or self.clock() >= deadline:
                return values[: max(self.CONFIRM_SAMPLES, 5)].tolist()
            self.sleep(self.tick_s)


_NAMES = {"pressure": "pressure transducer", "force": "load cell"}


def _robust_mean(values: np.ndarray) -> float:
    """Mean of ``values`` (n,) without readings far from their neighbours (> 5 robust sigma off the median)."""
    med = float(np.median(values))
    mad = 1.4826 * float(np.median(np.abs(values - med)))
    scale = max(mad, 1e-3 * abs(med), 1e-12)
    keep = np.abs(values - med) <= 5 * scale
    return float(values[keep].mean()) if keep.any() else med
