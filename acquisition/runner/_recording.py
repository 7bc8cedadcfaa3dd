"""The runner's record keeping: the instrument log drained into the session, events, warnings, the
live state, and the disk-space checks before every write.

A mixin of :class:`~acquisition.runner.SessionRunner`: it uses the runner's ``writer``, ``sampler``,
``state``, ``protocol``, ``clock``, ``on_update`` and its ``_check_readings``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace
from typing import Any

from acquisition.runner._errors import DiskFull
from acquisition.runner._safety import CHANNELS

log = logging.getLogger("acquisition.runner")


class _Recording:
    """Writes to the session file (log, events) and the live view's state."""

    # ------------------------------------------------------------------ log, events, view
    def _pump(self) -> None:
        """Drain the sampler into the session log and refresh the live state."""
        if not self._finalizing:
            self._ensure_space(0, "the instrument log")
        drained = {}
        for ch in CHANNELS:
            rec = drained[ch] = self.sampler.drain(ch)
            if len(rec.t_monotonic):
                self._write(self.writer.append_log, ch, rec.t_monotonic, rec.t_wall, rec.value, list(rec.raw),
                            seq=rec.seq)
            if getattr(rec, "lost", 0):
                self._warn(f"{rec.lost} {ch} samples lost (sampler queue overflow)")
        for ev in self.sampler.drain_events():
            self._event(f"instrument_{ev.kind}", f"{ev.channel}: {ev.message}")
        for ch in CHANNELS:
            s = self.sampler.latest(ch)
            if s is not None:
                setattr(self.state, ch, float(s.value))
        self._update()
        if not self._finalizing:
            self._check_readings(drained)

    # ------------------------------------------------------------------ disk space
    #: Free space kept in hand besides the next write (the log, events and HDF5 metadata), bytes.
    RESERVE_BYTES = 16e6

    def _disk_free(self) -> float:
        import shutil
        from pathlib import Path

        return float(shutil.disk_usage(Path(self.writer.path).resolve().parent).free)

    def _ensure_space(self, nbytes: float, what: str) -> None:
        """Stop at this boundary (nothing half-written) when ``nbytes`` plus the reserve do not fit."""
        free = self._free_space()
        need = nbytes + self.RESERVE_BYTES
        if free >= need:
            return
        left = self.protocol.n_steps - self.state.steps_done
        per_step = max(nbytes, self._last_step_bytes)
        raise DiskFull(f"disk full: {free / 1e6:.1f} MB free where {self.writer.path} is written; {what} needs "
                       f"about {need / 1e6:.1f} MB"
                       + (f" and the {left} remaining steps about {(left * per_step + self.RESERVE_BYTES) / 1e6:.0f} MB"
                          if left and per_step else "")
                       + f". Stopped cleanly at a step boundary: free some space, then `vfmlab resume "
                         f"{self.writer.path}`")

    def _write(self, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        """A session write; running out of space (ENOSPC) becomes :class:`DiskFull`."""
        try:
            return fn(*args, **kwargs)
        except OSError as exc:
            if getattr(exc, "errno", None) == 28 or "No space left" in str(exc):
                raise DiskFull(f"disk full while writing {self.writer.path} ({exc}); free some space, then "
                               f"`vfmlab resume {self.writer.path}`") from exc
            raise

    def _safe_event(self, kind: str, message: str) -> None:
        try:
            self._event(kind, message)
        except Exception as exc:  # noqa: BLE001 - the file may be the problem
            log.error("could not record event %s: %s", kind, exc)

    def _event(self, kind: str, message: str) -> None:
        log.info("%s: %s", kind, message)
        self.writer.add_event(kind, message)

    def _warn(self, message: str) -> None:
        log.warning("%s", message)
        self.state.warnings = (self.state.warnings + [message])[-5:]
        self._update()

    def _phase(self, phase: str, message: str = "") -> None:
        self.state.phase, self.state.message = phase, message
        self._update()

    def _update(self) -> None:
        now = self.clock()
        self.state.elapsed_s = now - self._t_start
        left = self.protocol.n_steps - self.state.steps_done
        if len(self._step_times) >= 2:
            per_step = (self._step_times[-1] - self._step_times[0]) / (len(self._step_times) - 1)
        else:
            stab = self.protocol.stability
            per_step = stab.dwell_s + 1.0
        self.state.remaining_s = max(0.0, left * per_step)
        if self.on_update is not None:
            self.on_update(replace(self.state, markers=dict(self.state.markers), warnings=list(self.state.warnings)))
