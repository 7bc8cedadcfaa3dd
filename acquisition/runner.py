"""The session runner: executes a :class:`~acquisition.protocol.Protocol` on the rig, step by step.

A small executor in the spirit of bluesky plans with ``finalize_wrapper``: whatever happens
(completion, operator abort, instrument fault, exception, Ctrl-C) the clean-up runs: the
pressure controller is vented (or the operator told to release the pressure), the cameras are
closed and the session file gets its status.

Sequence: preconditioning (logged, imaged only if the protocol asks), then for each block
(axial stretch) and each pressure level: set the stretch (stage or operator), set the
pressure (controller ``Setpt`` or operator), wait until the pressure is stable (band + dwell,
from the sampler), capture every camera and the instrument readings together, write the step
(flushed + fsynced). The continuous instrument log is drained from the sampler into the
session file as it happens (every ``tick_s``).

Pausing: :meth:`SessionRunner.request_pause` (the CLI calls it on Ctrl-C) pauses at the next
safe point (never inside a capture or a file write) and asks the operator to resume, retake the
last step, quit (leave the session resumable) or abort. An instrument fault (timeout,
disconnect, device error) pauses the session with a message and resumes by itself when the
instrument is back.

Collaborators are duck-typed so the runner stays independent of the concrete drivers:

- ``pressure``: ``identity``, ``is_controller``, ``set_mode(str)``, ``set_setpoint(Pa)``
- ``sampler``: ``latest(ch)``, ``drain(ch)``, ``drain_events()``, ``status(ch)``, ``healthy``,
  ``is_stable(band, dwell, target)``, ``history(ch, seconds)``
  (``acquisition.instruments.Sampler``)
- ``writer``: :class:`acquisition.session.SessionWriter`
- ``cameras``: :class:`acquisition.cameras.Camera` objects (open)
- ``operator``: :class:`Operator`
"""

from __future__ import annotations

import enum
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol as _Protocol

import numpy as np

from acquisition.cameras import Camera, CaptureError, capture_all
from acquisition.instrument_errors import InstrumentError
from acquisition.protocol import MMHG, Protocol, SafetyLimits

__all__ = [
    "RunnerError",
    "SessionAborted",
    "SessionQuit",
    "DiskFull",
    "Operator",
    "AutoOperator",
    "RunnerState",
    "SessionRunner",
    "completed_steps",
]

log = logging.getLogger(__name__)

CHANNELS = ("pressure", "force")


class RunnerError(RuntimeError):
    """The runner cannot continue (safety limit, repeated capture failure...)."""


class SessionAborted(RunnerError):
    """The session was aborted (by the operator or a safety limit); the runner's status is 'aborted'.

    ``resumable``: the completed steps are sound and the cause can be fixed (a safety limit that
    tripped, a capture that kept failing): the file stays resumable. An operator's abort is final.
    """

    def __init__(self, message: str, *, resumable: bool = False):
        super().__init__(message)
        self.resumable = resumable


class DiskFull(RunnerError):
    """Not enough free space for the next write: stopped at a step boundary, resumable."""


class SessionQuit(RunnerError):
    """The operator stopped the session to resume it later; status stays resumable ('interrupted')."""


class Choice(str, enum.Enum):
    RESUME = "resume"
    RETAKE = "retake"
    QUIT = "quit"
    ABORT = "abort"
    WAIT = "wait"
    CAPTURE = "capture"
    RETRY = "retry"


class Operator(_Protocol):
    """The person at the rig (a terminal prompt, or a script in tests and unattended runs)."""

    def set_pressure(self, target: float) -> None:
        """Manual pressure: ask the operator to set ``target`` Pa (returns when they say it is set)."""

    def set_stretch(self, stretch: float) -> None:
        """No stage: ask the operator to set the axial stretch L/L0 (returns when done)."""

    def precondition(self, message: str) -> None:
        """Manual preconditioning: ask the operator to do it (returns when done)."""

    def place_board(self, index: int, n_views: int) -> None:
        """Ask for calibration-board pose ``index`` (0-based) of ``n_views`` (returns when placed)."""

    def remove_board(self) -> None:
        """Ask for the board to be removed (returns when the specimen is in view)."""

    def choose(self, reason: str, options: Sequence[str]) -> str:
        """Ask the operator to pick one of ``options`` (``reason`` explains why)."""

    def notify(self, message: str) -> None:
        """Tell the operator something (no answer expected)."""

    def ask_text(self, prompt: str) -> str:
        """Ask for free text (an operator note)."""


class AutoOperator:
    """Unattended operator (``--yes``): accepts defaults, never blocks.

    On a Ctrl-C pause it answers ``on_interrupt`` (default "quit": the session stays resumable);
    when stability times out it captures anyway (with a warning event); when a capture still
    fails after the runner's automatic retries it aborts (vents). ``set_pressure`` /
    ``set_stretch`` call the optional hooks (the simulated rig's hand on the valve).
    """

    def __init__(self, set_pressure: Callable[[float], None] | None = None,
                 set_stretch: Callable[[float], None] | None = None,
                 on_interrupt: str = "quit", place_board: Callable[[int, int], None] | None = None,
                 remove_board: Callable[[], None] | None = None):
        self._set_pressure, self._set_stretch = set_pressure, set_stretch
        self._place_board, self._remove_board = place_board, remove_board
        self.on_interrupt = on_interrupt
        self.messages: list[str] = []

    def set_pressure(self, target: float) -> None:
        if self._set_pressure is not None:
            self._set_pressure(target)

    def set_stretch(self, stretch: float) -> None:
        if self._set_stretch is not None:
            self._set_stretch(stretch)

    def precondition(self, message: str) -> None:
        self.messages.append(message)

    def place_board(self, index: int, n_views: int) -> None:
        if self._place_board is not None:
            self._place_board(index, n_views)

    def remove_board(self) -> None:
        if self._remove_board is not None:
            self._remove_board()

    def choose(self, reason: str, options: Sequence[str]) -> str:
        self.messages.append(reason)
        if "retry" in options:
            return "abort"
        if "capture" in options:
            return "capture"
        return self.on_interrupt if self.on_interrupt in options else options[-1]

    def notify(self, message: str) -> None:
        self.messages.append(message)

    def ask_text(self, prompt: str) -> str:
        return ""


@dataclass
class RunnerState:
    """What the live view shows (a snapshot; SI units).

    Attributes
    ----------
    phase : str
        'starting', 'preconditioning', 'setting', 'stabilising', 'capturing', 'paused', 'done'.
    step, n_steps : int
        Index of the planned step in progress (0-based) and the number of planned steps.
    block, stretch, target : current block index, L/L0, target pressure (Pa).
    pressure, force : latest readings (Pa, N), NaN if none.
    stable : bool
    markers : dict camera -> number of markers detected at the last capture.
    warnings : list of recent warnings (newest last).
    elapsed_s, remaining_s : float
    message : str
    """

    phase: str = "starting"
    step: int = 0
    n_steps: int = 0
    steps_done: int = 0
    block: int = -1
    stretch: float = math.nan
    target: float = math.nan
    pressure: float = math.nan
    force: float = math.nan
    stable: bool = False
    markers: dict[str, int] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    elapsed_s: float = 0.0
    remaining_s: float = math.nan
    message: str = ""
    instruments: dict[str, str] = field(default_factory=dict)


def completed_steps(steps: dict[str, np.ndarray]) -> int:
    """Number of planned protocol steps already captured in a session's step table.

    Rows are written in protocol order; a retake (``supersedes >= 0``) and preconditioning
    captures (``block < 0``) do not advance the plan.
    """
    if not len(steps.get("block", ())):
        return 0
    return int(np.count_nonzero((steps["block"] >= 0) & (steps["supersedes"] < 0)))


class SessionRunner:
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
    """

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
                raise SessionAborted(f"aborted after a failed capture: {exc}") from exc
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
            over = [i for i in range(values.size) if self._over_limit(ch, values[i]) is not None]
            for i in over:
                self._judge(ch, float(values[i]), float(times[i]))

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
                failures += 1
                msg = f"{what}: command failed ({type(exc).__name__}: {exc})"
                self._warn(msg)
                self._event("fault", msg)
                if failures >= attempts and self.sampler.healthy:
                    raise SessionAborted(f"{what} refuses the command after {failures} attempts: {exc}") from exc
                self._hold(self.retry_delay_s)  # pauses here while the sampler sees the fault

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

    def _capture_retrying(self, what: str):
        """capture_all with the runner's retry policy (automatic retries, then the operator)."""
        failures = 0
        while True:
            self._check_pause()
            try:
                return capture_all(self.cameras, self.protocol.capture.timeout_s)
            except CaptureError as exc:
                failures += 1
                self._warn(str(exc))
                self._event("capture_failed", f"{what}: {exc}")
                if failures <= self.capture_retries:
                    self._hold(self.retry_delay_s)
                    continue
                if self.operator.choose(f"Capture failed {failures} times in a row: {exc}",
                                        ["retry", "abort"]) == "abort":
                    raise SessionAborted(f"aborted after a failed capture: {exc}") from exc
                failures = 0

    def _calibration_views(self) -> None:
        cal = self.protocol.calibration
        if not cal.views:
            return
        done = int(getattr(self.writer, "n_calibration_views", 0))
        if done >= cal.views:
            self._event("calibration_done", f"{done} calibration views already stored")
            return
        self._phase("calibrating", f"{cal.views} calibration-board views ({cal.board or 'board'})"
                    + (f", {done} already stored" if done else ""))
        self._event("calibration", self.state.message)
        for k in range(done, cal.views):
            self.state.message = f"board view {k + 1}/{cal.views}"
            self.operator.place_board(k, cal.views)
            self._pump()
            result = self._capture_retrying(f"board view {k + 1}")
            frames = {name: f.pixels for name, f in result.frames.items() if name in self.writer.camera_names}
            self._ensure_space(sum(np.asarray(im).nbytes for im in frames.values()), "the next calibration view")
            index = self._write(self.writer.add_calibration_view, frames)
            self._event("calibration_view", f"board view {k + 1}/{cal.views} stored as calibration view {index}")
        self.operator.remove_board()
        self._event("calibration_done", f"{cal.views} calibration views captured")

    def _precondition(self) -> None:
        pc = self.protocol.preconditioning
        if not (pc.pressure_cycles or pc.stretch_cycles):
            return
        self._phase("preconditioning",
                    f"{pc.pressure_cycles} x 0-{pc.pressure_max / MMHG:.0f} mmHg, "
                    f"{pc.stretch_cycles} x L/L0 1-{pc.stretch_max:g}")
        self._event("preconditioning", self.state.message)
        half = pc.cycle_s / 2
        if pc.pressure_cycles:
            self._set_stretch(1.0)
            if self.pressure_mode == "controller":
                self._command("pressure controller", self.pressure.set_mode, "control")
                for i in range(pc.pressure_cycles):
                    self.state.message = f"pressure cycle {i + 1}/{pc.pressure_cycles}"
                    self._command("pressure controller", self.pressure.set_setpoint, pc.pressure_max)
                    self._hold(half)
                    if pc.imaged:
                        self._precondition_capture(1.0, pc.pressure_max)
                    self._command("pressure controller", self.pressure.set_setpoint, 0.0)
                    self._hold(half)
            else:
                self.operator.precondition(f"Do {pc.pressure_cycles} pressure cycles 0 -> "
                                           f"{pc.pressure_max / MMHG:.0f} mmHg, then continue")
        if pc.stretch_cycles:
            if self.pressure_mode == "controller":
                self._command("pressure controller", self.pressure.set_setpoint, 0.0)
            if self.stage is not None:
                for i in range(pc.stretch_cycles):
                    self.state.message = f"stretch cycle {i + 1}/{pc.stretch_cycles}"
                    self._set_stretch(pc.stretch_max)
                    self._hold(half)
                    if pc.imaged:
                        self._precondition_capture(pc.stretch_max, 0.0)
                    self._set_stretch(1.0)
                    self._hold(half)
            else:
                self.operator.precondition(f"Do {pc.stretch_cycles} axial stretch cycles L/L0 1 -> "
                                           f"{pc.stretch_max:g}, then continue")
                self._stretch = None
        self._event("preconditioning_done", "preconditioning complete")

    def _precondition_capture(self, stretch: float, target: float) -> None:
        """Imaged preconditioning: a step row with block -1 (not part of the test plan)."""
        self._capture_and_write(-1, stretch, target, -1)

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


_NAMES = {"pressure": "pressure transducer", "force": "load cell"}


def _robust_mean(values: np.ndarray) -> float:
    """Mean of ``values`` (n,) without readings far from their neighbours (> 5 robust sigma off the median)."""
    med = float(np.median(values))
    mad = 1.4826 * float(np.median(np.abs(values - med)))
    scale = max(mad, 1e-3 * abs(med), 1e-12)
    keep = np.abs(values - med) <= 5 * scale
    return float(values[keep].mean()) if keep.any() else med
