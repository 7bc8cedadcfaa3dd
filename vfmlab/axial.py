"""The motorised axial stage in a run: every protocol stretch checked against the soft limits, homing
with the operator's consent, and the runner's ``stage(stretch)`` (:class:`acquisition.StretchStage`).

The rig file's ``[stage]`` gives the carriage position ``x0`` at which the specimen has its gauge length;
the specimen file's length is that gauge length ``L0``: stretch ``lambda`` is the position
``x0 + direction (lambda - 1) L0`` (:mod:`acquisition.stage`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from acquisition import InstrumentError, StretchStage
from acquisition.protocol import Protocol, SpecimenFile

__all__ = ["StageSetupError", "home_if_needed", "prepare_stage", "protocol_stretches", "stretch_stage"]

log = logging.getLogger(__name__)


class StageSetupError(RuntimeError):
    """The stage cannot serve this run; ``exit_code`` 2 when the files must change."""

    def __init__(self, message: str, exit_code: int = 1):
        super().__init__(message)
        self.exit_code = exit_code


def protocol_stretches(protocol: Protocol) -> list[float]:
    """Every axial stretch the protocol sets (1, the blocks', the preconditioning's maximum), sorted."""
    pc = protocol.preconditioning
    values = {1.0, *(b.stretch for b in protocol.blocks)}
    if pc.stretch_cycles:
        values.add(pc.stretch_max)
    return sorted(values)


def stretch_stage(motor: Any, config: Any, specimen: SpecimenFile, protocol: Protocol) -> StretchStage:
    """The runner's stage for ``motor`` (a ZaberStage) with the rig file's ``[stage]`` ``config``; raises
    StageSetupError (exit code 2) if a stretch of the protocol lies outside the soft limits (nothing moves)."""
    stage = StretchStage(motor, gauge_length_m=specimen.length, x0_m=config.x0_m, direction=config.direction,
                         timeout_s=config.timeout_s)
    bad = []
    for lam in protocol_stretches(protocol):
        try:
            stage.check(lam)
        except ValueError as exc:
            bad.append(str(exc))
    if bad:
        raise StageSetupError("the stage cannot reach every stretch of the protocol (soft limits [stage] min_mm, "
                              "max_mm; x0_mm; the specimen's length_mm): " + "; ".join(bad), exit_code=2)
    return stage


def home_if_needed(motor: Any, config: Any, ask: Any, *, yes: bool) -> bool:
    """Home ``motor`` when it has no reference position: ``ask(question, options)`` the operator first unless
    ``yes``; True if it homed. A stage that needs homing with ``[stage] home = false`` is a StageSetupError."""
    try:
        status = motor.request("", faults=False)
    except InstrumentError as exc:
        raise StageSetupError(f"stage: {exc}") from None
    if not status.needs_homing:
        return False
    if not config.home:
        raise StageSetupError("stage: the axis has no reference position (flag WR) and the rig file says "
                              "[stage] home = false: home it (Zaber Launcher) or set home = true", exit_code=2)
    if not yes and ask("Home the axial stage now? The carriage runs to its home sensor (the low end of its travel): "
                       "make sure the specimen is not mounted or is free to follow.", ["home", "cancel"]) != "home":
        raise StageSetupError("cancelled by the operator before homing; nothing has moved")
    try:
        motor.home(timeout=config.timeout_s)
    except InstrumentError as exc:
        raise StageSetupError(f"stage: homing failed: {exc}") from None
    log.info("stage homed; at %.6g m", motor.position())
    return True


def prepare_stage(bench: Any, specimen: SpecimenFile, protocol: Protocol, ask: Callable[[str, list[str]], str], *,
                  yes: bool, home: bool, say: Callable[[str], None] = log.info) -> None:
    """With a motorised stage (``bench.motor``): check every protocol stretch against its soft limits and set
    ``bench.stage`` (``home=False``, nothing moves), or home it with the operator's consent (``home=True``)."""
    if bench.motor is None:
        return
    config = bench.config.stage
    if not home:
        bench.stage = stretch_stage(bench.motor, config, specimen, protocol)
    elif home_if_needed(bench.motor, config, ask, yes=yes):
        say(f"stage homed; stretch 1 at {config.x0_m * 1e3:.3f} mm")
