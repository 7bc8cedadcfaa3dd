"""The session runner: :class:`SessionRunner` executes a protocol on the rig, step by step."""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from acquisition.cameras import Camera, CaptureError, capture_all
from acquisition.instrument_errors import InstrumentError
from acquisition.protocol import MMHG, Protocol, SafetyLimits
from acquisition.runner._errors import DiskFull, RunnerError, SessionAborted, SessionQuit
from acquisition.runner._operator import Operator
from acquisition.runner._preparation import _Preparation
from acquisition.runner._recording import _Recording
from acquisition.runner._safety import _NAMES, CHANNELS, _SafetyChecks
from acquisition.runner._state import RunnerState

log = logging.getLogger("acquisition.runner")


class SessionRunner(_Preparation, _SafetyChecks, _Recording):
    """Run a protocol on a rig into an open :class:`~acquisition.session.SessionWriter`.

    Parameters
    ----------
    protocol : Protocol
    writer : SessionWriter
    pressure : pressure driver (see module docstring)
    sampler : background sampler, started
    cameras : sequence of open Camera
    operator : Operator
    pressure_mode : 'controller' or 'manual'
    stage : callable(stretch) or None
        Motorised axial stage; None = ask the operator.
    safety : SafetyLimits
    detector : callable(image (H, W)) -> int, optional
        Counts markers in a frame for the live view.
    on_update : callable(RunnerState), optional
        Called at every tick (the live view).
    on_step_captured : callable(row, images {camera: (H, W)}, StepRecord), optional
        Called after each step is written (e.g. to reconstruct it in the background); it must
        return at once. An exception from it is logged and never stops the test.
    tick_s : float
        Polling period of the waits and the log drain, s.
    capture_retries : int
        Failed captures retried automatically (after ``retry_delay_s``) before the operator
        is asked to retry or abort.
    clock, sleep : injectable time sources.
    free_space : callable() -> bytes free where the session file lives (injectable for tests).

    A ``stage`` with ``clear_fault()`` (:class:`acquisition.stage.StretchStage`) that raises an instrument
    fault pauses the session (pressure held) until the operator clears it; see :meth:`_stage_fault`.
    """

    #: Stage faults that may be cleared in one session before only quit or abort are offered.
    STAGE_CLEARS = 3

    def __init__(self, protocol: Protocol, writer: Any, *, pressure: Any, sampler: Any,
                 cameras: Sequence[Camera], operator: Operator, pressure_mode: str = "controller",
                 stage: Callable[[float], None] | None = None, safety: SafetyLimits | None = None,
                 detector: Callable[[np.ndarray], int] | None = None,
                 on_update: Callable[[RunnerState], None] | None = None,
                 on_step_captured: Callable[[int, dict, Any], None] | None = None, tick_s: float = 0.05,
                 capture_retries: int = 2, retry_delay_s: float = 0.5,
                 clock: Callable[[], float] = time.monotonic, sleep: Callable[[float], None] = time.sleep,
                 free_space: Callable[[], float] | None = None):
        if pressure_mode not in ("controller", "manual"):
            raise ValueError(f"pressure_mode: expected 'controller' or 'manual'; got {pressure_mode!r}")
        if pressure_mode == "controller" and not getattr(pressure, "is_controller", False):
            raise RunnerError("pressure_mode is 'controller' but the pressure instrument "
                              f"{getattr(pressure, 'identity', '?')!r} cannot control pressure (no Setpt): "
                              "set mode = \"manual\" in the rig file")
        self.protocol, self.writer, self.pressure, self.sampler = protocol, writer, pressure, sampler
        self.cameras = list(cameras)
        self.operator, self.pressure_mode, self.stage = operator, pressure_mode, stage
        self.safety = safety or SafetyLimits()
        self.detector, self.on_update, self.on_step_captured = detector, on_update, on_step_captured
        self.tick_s, self.clock, self.sleep = tick_s, clock, sleep
        self.state = RunnerState(n_steps=protocol.n_steps)
        self._pause_requested = False
        self._stretch: float | None = None
        self._actuated_at = -math.inf  # clock time of the last stage or pressure command
        self._t_start = clock()
        self._step_times: list[float] = []
        self._last_step: tuple[int, int, float, float] | None = None  # (row, block, stretch, target)
        self._finalizing = False
        self.capture_retries, self.retry_delay_s = int(capture_retries), float(retry_delay_s)
        self._capture_failures = 0
        self._stage_faults = 0
        self.status = "running"
        self.resumable = False  # after run(): whether an 'aborted' run left the file resumable
        self.stop_reason = ""
        self._free_space = free_space or self._disk_free
        self._last_step_bytes = 0

    # ------------------------------------------------------------------ public
    def request_pause(self) -> None:
        """Ask for a pause at the next safe point (signal-handler safe: sets a flag)."""
        self._pause_requested = True

    def run(self, start_step: int = 0, precondition: bool = True, calibrate: bool = True) -> str:
        """Execute the protocol from planned step ``start_step``; returns the final status.

        ``calibrate``/``precondition``: capture the calibration-board views / run the
        preconditioning first (only when starting at step 0).

        The final status is 'complete', 'aborted' (operator, safety limit or error; the error
        is re-raised after clean-up) or 'interrupted' (operator chose quit; resumable).
        """
        self._t_start = self.clock()
        self.state.steps_done = start_step
        status = "aborted"
        error: BaseException | None = None
        try:
            self._event("start", f"protocol {self.protocol.name!r}: {self.protocol.n_steps} steps, "
                                 f"starting at step {start_step}")
            if calibrate and start_step == 0:
                self._calibration_views()
            if precondition and start_step == 0:
                self._precondition()
            plan = self.protocol.steps
            k = start_step
            while k < len(plan):
                block, stretch, target = plan[k]
                self.state.step = k
                self._do_step(block, stretch, target)
                k += 1
            self._pump()
            status = "complete"
        except SessionQuit as exc:
            status = "interrupted"
            self._warn(str(exc))
            self._safe_event("quit", str(exc))
        except DiskFull as exc:
            status = "interrupted"
            self.stop_reason = str(exc)
            self._warn(str(exc))
            self._safe_event("disk_full", str(exc))
        except SessionAborted as exc:
            status = "aborted"
            self.resumable = exc.resumable
            self.stop_reason = str(exc)
            self._warn(str(exc))
            self._safe_event("abort", str(exc) + ("; the session stays resumable" if exc.resumable else ""))
        except BaseException as exc:  # noqa: BLE001 - clean-up below, then re-raise
            error = exc
            status = "aborted"
            log.error("session aborted by an error: %s", exc)
        finally:
            self._finalize(status, error)
        self.status = status
        if error is not None:
            raise error
        return status

    # ------------------------------------------------------------------ steps
    def _do_step(self, block: int, stretch: float, target: float, supersedes: int = -1) -> None:
        """Set, stabilise, capture and write one step (again and again until it is written)."""
        self.state.block, self.state.stretch, self.state.target = block, stretch, target
        while True:
            self._set_stretch(stretch)
            self._set_pressure(target)
            self._wait_stable(target)
            if self._capture_and_write(block, stretch, target, supersedes) == "written":
                return

    def _capture_and_write(self, block: int, stretch: float, target: float, supersedes: int) -> str:
        if self._check_pause():
            return "again"  # a retake moved the rig: stabilise again
        if self._check_fault():
            return "again"  # a fault while stabilising: stabilise again
        self._phase("capturing", f"capturing {len(self.cameras)} cameras")
        t0 = self.clock()
        try:
            result = capture_all(self.cameras, self.protocol.capture.timeout_s)
        except CaptureError as exc:
            self._capture_failures += 1
            self._warn(str(exc))
            self._event("capture_failed", str(exc))
            if self._capture_failures <= self.capture_retries:
                self._hold(self.retry_delay_s)  # automatic retry after a short wait
                return "again"
            choice = self.operator.choose(f"Capture failed {self._capture_failures} times in a row: {exc}",
                                          ["retry", "abort"])
            if choice == "abort":
                # the completed steps are sound and a camera can be fixed: resumable (SessionAborted)
                raise SessionAborted(f"aborted after a failed capture: {exc}", resumable=True) from exc
            self._capture_failures = 0
            return "again"
        self._capture_failures = 0
        pressure, force = self._readings(t0)
        if self._check_fault():
            return "again"  # a reading inside the capture window is missing: redo
        frames = result.frames
        t_mono = float(np.mean([f.t_monotonic for f in frames.values()]))
        t_wall = float(np.mean([f.t_wall for f in frames.values()]))
        from acquisition.session import StepRecord

        record = StepRecord(block=block, stretch=stretch, target_pressure=target, pressure=pressure,
                            force=force, t_monotonic=t_mono, t_wall=t_wall, supersedes=supersedes)
        images = {name: frames[name].pixels for name in self.writer.camera_names}
        self._pump()
        self._last_step_bytes = sum(np.asarray(im).nbytes for im in images.values())
        self._ensure_space(self._last_step_bytes, "the next step")
        row = self._write(self.writer.add_step, record, images)
        self._last_step = (row, block, stretch, target)
        self._step_times.append(self.clock())
        if block >= 0 and supersedes < 0:
            self.state.steps_done += 1
        if self.on_step_captured is not None:
            try:
                self.on_step_captured(row, images, record)
            except Exception as exc:  # noqa: BLE001 - an observer of the steps must never stop the test
                log.warning("step %d: on_step_captured failed: %s", row, exc)
        if self.detector is not None:
            self.state.markers = {name: int(self.detector(f.pixels)) for name, f in frames.items()}
        what = f"retake of step row {supersedes}" if supersedes >= 0 else "step"
        log.info("%s %d written: block %d, L/L0 %.3f, p %.2f kPa (target %.2f), F %.4f N, capture spread %.1f ms",
                 what, row, block, stretch, pressure / 1e3, target / 1e3, force, result.spread_s * 1e3)
        self._update()
        return "written"


    # ------------------------------------------------------------------ actuation
    def _set_stretch(self, stretch: float) -> None:
        if self._stretch is not None and math.isclose(self._stretch, stretch, abs_tol=1e-9):
            return
        self._phase("setting", f"axial stretch L/L0 -> {stretch:.3f}")
        if self.stage is not None:
            self._command("stage", self.stage, stretch)
        else:
            self.operator.set_stretch(stretch)
        self._stretch = stretch
        self._actuated_at = self.clock()
        self._event("stretch", f"axial stretch set to L/L0 = {stretch:.4f}")

    def _set_pressure(self, target: float) -> None:
        self._phase("setting", f"pressure -> {target / MMHG:.1f} mmHg")
        if self.pressure_mode == "controller":
            self._command("pressure controller", self.pressure.set_setpoint, target)
            self._command("pressure controller", self.pressure.set_mode, "control")
        else:
            self.operator.set_pressure(target)
        self._actuated_at = self.clock()

    def _command(self, what: str, fn: Callable[..., Any], *args: Any, attempts: int = 3) -> Any:
        """Send a command to an instrument; on an instrument fault pause until it is back, then retry.

        A command that fails ``attempts`` times while the instruments read fine (the device
        refuses it) aborts the session.
        """
        failures = 0
        while True:
            try:
                return fn(*args)
            except InstrumentError as exc:
                if what == "stage" and hasattr(self.stage, "clear_fault"):
                    self._stage_fault(exc)  # paused until cleared (or quit/abort); then the move is retried
                    continue
                failures += 1
                msg = f"{what}: command failed ({type(exc).__name__}: {exc})"
                self._warn(msg)
                self._event("fault", msg)
                if failures >= attempts and self.sampler.healthy:
                    raise SessionAborted(f"{what} refuses the command after {failures} attempts: {exc}") from exc
                self._hold(self.retry_delay_s)  # pauses here while the sampler sees the fault

    def _stage_fault(self, exc: InstrumentError) -> None:
        """A motorised stage fault (stall, driver off, timeout): stop the axis, hold the pressure, pause.

        The operator (the unattended one: once per move) clears the stage's latched fault and the move is
        retried; quit leaves the session resumable, abort vents it.
        """
        msg = f"stage fault, session paused (pressure held): {type(exc).__name__}: {exc}"
        self._warn(msg)
        self._event("fault", msg)
        self.operator.notify(msg)
        stop = getattr(self.stage, "stop", None)
        try:
            if stop is not None:
                stop()
        except InstrumentError as err:
            log.error("stage stop after the fault failed: %s", err)
        prev = self.state.phase
        self._phase("paused", msg)
        self._stage_faults += 1
        options = ["clear", "quit", "abort"] if self._stage_faults <= self.STAGE_CLEARS else ["quit", "abort"]
        choice = self.operator.choose("Stage fault: check the carriage and the specimen, then clear the fault "
                                      "and retry the move (clear), stop resumably (quit) or abort?", options)
        self._event("operator", f"operator chose {choice!r}")
        if choice == "abort":
            raise SessionAborted(f"aborted after a stage fault: {exc}")
        if choice == "quit":
            raise SessionQuit("stopped after a stage fault; continue with `vfmlab resume`")
        clear: Any = getattr(self.stage, "clear_fault", list)
        try:
            flags = clear()
        except InstrumentError as err:
            self._warn(f"stage: clearing the fault failed ({err}); retrying the move")
            flags = []
        self._event("recovered", "stage fault cleared" + (f" (flags {', '.join(flags)})" if flags else "")
                    + "; retrying the move")
        self.operator.notify("stage fault cleared, resuming")
        self._phase(prev, "resumed after the stage fault")

    def _wait_stable(self, target: float) -> None:
        stab = self.protocol.stability
        t0 = self.clock()
        self._phase("stabilising", f"waiting for {target / MMHG:.1f} +- {stab.band / MMHG:.1f} mmHg "
                                   f"for {stab.dwell_s:g} s")
        while True:
            if self._tick():
                t0 = self.clock()
            if self._check_fault():
                t0 = self.clock()
                continue
            # the dwell starts at the last actuation: samples from before a stage move (the pressure
            # may already have been stable) say nothing about the state being captured
            settled = self.clock() - self._actuated_at >= stab.dwell_s
            if settled and self.sampler.is_stable(stab.band, stab.dwell_s, target):
                self.state.stable = True
                self._update()
                return
            self.state.stable = False
            if self.clock() - t0 > stab.timeout_s:
                msg = (f"pressure not stable within +-{stab.band / MMHG:.1f} mmHg of {target / MMHG:.1f} mmHg "
                       f"after {stab.timeout_s:g} s (now {self.state.pressure / MMHG:.1f} mmHg)")
                self._warn(msg)
                choice = self.operator.choose(msg, ["wait", "capture", "abort"])
                if choice == "abort":
                    raise SessionAborted(msg)
                if choice == "capture":
                    self._event("warning", "captured without stability: " + msg)
                    return
                t0 = self.clock()

    def _hold(self, seconds: float) -> None:
        t_end = self.clock() + seconds
        while self.clock() < t_end:
            self._tick()
            self._check_fault()

    # ------------------------------------------------------------------ pause / faults
    def _tick(self) -> bool:
        """Sleep one tick, drain the log, honour a pause; True if the pause moved the rig."""
        self.sleep(self.tick_s)
        self._pump()
        return self._check_pause()

    def _check_pause(self) -> bool:
        """Handle a requested pause (operator menu); True if a retake moved the rig."""
        if not self._pause_requested:
            return False
        self._pause_requested = False
        prev = self.state.phase
        self._phase("paused", "paused by the operator")
        self._event("pause", "paused by the operator")
        options = ["resume", "retake", "note", "quit", "abort"] if self._last_step else \
            ["resume", "note", "quit", "abort"]
        while True:
            choice = self.operator.choose("Paused. Resume, retake the last step, add a note, quit (resume later) "
                                          "or abort?", options)
            self._event("operator", f"operator chose {choice!r}")
            if choice != "note":
                break
            text = self.operator.ask_text("Note for the session record")
            if text:
                self._event("note", text)
        if choice == "abort":
            raise SessionAborted("aborted by the operator")
        if choice == "quit":
            raise SessionQuit("stopped by the operator; continue with `vfmlab resume`")
        if choice == "retake" and self._last_step is not None:
            row, block, stretch, target = self._last_step
            self._event("retake", f"retaking step row {row} (block {block}, L/L0 {stretch:g}, "
                                  f"{target / MMHG:.1f} mmHg)")
            saved = (self.state.block, self.state.stretch, self.state.target)
            self._do_step(block, stretch, target, supersedes=row)
            self.state.block, self.state.stretch, self.state.target = saved
            # back to the interrupted step: actuation is redone by the caller's loop
            if not math.isnan(saved[1]):
                self._set_stretch(saved[1])
            if not math.isnan(saved[2]):
                self._set_pressure(saved[2])
            self._phase(prev if prev != "paused" else "setting", "resumed after the retake")
            return True
        self._phase(prev if prev != "paused" else "setting", "resumed")
        return False

    def _check_fault(self) -> bool:
        """If an instrument is faulty, pause until it is back; True if a pause happened."""
        if self.sampler.healthy:
            return False
        faulty = {ch: self.sampler.status(ch) for ch in CHANNELS}
        bad = {ch: s for ch, s in faulty.items() if s.state != "ok"}
        if not bad:
            return False
        desc = "; ".join(f"{_NAMES[ch]} {s.state}: {s.message}" for ch, s in bad.items())
        msg = f"instrument fault, session paused until it is back: {desc}"
        self._warn(msg)
        self._event("fault", msg)
        self.operator.notify(msg)
        prev = self.state.phase
        self._phase("paused", msg)
        if self.pressure_mode == "controller" and "pressure" in bad:
            log.warning("pressure controller unreachable: the controller holds its last setpoint")
        while not self.sampler.healthy:
            self.sleep(self.tick_s)
            self._pump()
            self._check_pause()
        self._event("recovered", "instruments back: " + ", ".join(_NAMES[ch] for ch in bad))
        self.operator.notify("instruments back, resuming")
        self._phase(prev, "resumed after the fault")
        return True


    # ------------------------------------------------------------------ clean-up
    def _finalize(self, status: str, error: BaseException | None) -> None:
        """Safe state, always: vent, close cameras, write the status."""
        self._finalizing = True
        self.state.stable = False
        self._phase("done", f"session {status}")
        try:
            if self.pressure_mode == "controller":
                try:
                    self.pressure.set_mode("vent")
                    self._safe_event("safe", "pressure controller vented")
                except Exception as exc:  # noqa: BLE001 - keep cleaning up
                    log.error("could not vent the pressure controller: %s", exc)
                    self.operator.notify(f"COULD NOT VENT THE CONTROLLER ({exc}): release the pressure by hand")
            else:
                self.operator.notify("Test finished: release the pressure (vent) now.")
            try:
                self._pump()
            except Exception as exc:  # noqa: BLE001
                log.error("final log drain failed: %s", exc)
            if error is not None:
                self._safe_event("error", f"{type(error).__name__}: {error}")
        finally:
            for cam in self.cameras:
                cam.close()
            # 'interrupted' = leave 'running' so readers report interrupted and resume accepts it
            # a resumable abort (safety limit, vented) is recorded as 'interrupted': resume accepts it
            # an operator's quit leaves 'running' (readers report interrupted once the process is gone);
            # a fault that stopped a resumable run (disk full, a safety trip, vented) says so at once
            if (status == "aborted" and self.resumable) or (status == "interrupted" and self.stop_reason):
                self.writer.close(status="interrupted")
            else:
                self.writer.close(status="running" if status == "interrupted" else status)
