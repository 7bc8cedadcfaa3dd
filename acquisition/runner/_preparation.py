"""What the runner does before the test steps: the calibration-board views and the preconditioning.

A mixin of :class:`~acquisition.runner.SessionRunner`: it uses the runner's actuation, capture,
pause and record-keeping methods.
"""

from __future__ import annotations

import numpy as np

from acquisition.cameras import CaptureError, capture_all
from acquisition.protocol import MMHG
from acquisition.runner._errors import SessionAborted


class _Preparation:
    """Calibration views and preconditioning, run once at the start of a session."""


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
                    raise SessionAborted(f"aborted after a failed capture: {exc}", resumable=True) from exc
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
