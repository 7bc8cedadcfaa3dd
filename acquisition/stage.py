"""Axial stretch <-> stage position, and the ``stage(stretch)`` callable the session runner drives.

The specimen is mounted between a fixed cannula and one on the motorised carriage. With ``x0_m`` the
carriage position at which the specimen has its gauge length ``L0`` (stretch 1), a carriage position
``x`` gives the axial stretch

    lambda_z = (L0 + d (x - x0)) / L0,        x = x0 + d (lambda_z - 1) L0,

with ``d = direction = +1`` when increasing the carriage position lengthens the specimen and -1 when it
shortens it. Everything is in SI.
"""

from __future__ import annotations

import logging
import math
from typing import Any, Protocol

log = logging.getLogger(__name__)


def _finite(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number; got {value!r}")
    return float(value)


def _gauge(gauge_length_m: float) -> float:
    L0 = _finite("gauge_length_m", gauge_length_m)
    if L0 <= 0:
        raise ValueError(f"gauge_length_m must be > 0 m; got {L0}")
    return L0


def stretch_from_position(position_m: float, *, gauge_length_m: float, x0_m: float, direction: int = 1) -> float:
    """Axial stretch ``(L0 + direction * (x - x0)) / L0`` of a carriage position ``x`` (m)."""
    L0 = _gauge(gauge_length_m)
    _check_direction(direction)
    return (L0 + direction * (_finite("position_m", position_m) - _finite("x0_m", x0_m))) / L0


def position_from_stretch(stretch: float, *, gauge_length_m: float, x0_m: float, direction: int = 1) -> float:
    """Carriage position (m) giving the axial stretch ``stretch``: ``x0 + direction * (stretch - 1) * L0``."""
    L0 = _gauge(gauge_length_m)
    _check_direction(direction)
    lam = _finite("stretch", stretch)
    if lam <= 0:
        raise ValueError(f"stretch must be > 0 (L/L0); got {lam}")
    return _finite("x0_m", x0_m) + direction * (lam - 1.0) * L0


def _check_direction(direction: int) -> None:
    if direction not in (1, -1):
        raise ValueError(f"direction must be +1 (position increases the length) or -1; got {direction!r}")


class PositionStage(Protocol):
    """What :class:`StretchStage` needs from a stage driver (e.g. :class:`acquisition.zaber.ZaberStage`)."""

    def move_to(self, position_m: float, *, wait: bool = True, timeout: float = 60.0) -> None: ...

    def position(self) -> float: ...


class StretchStage:
    """A positioning stage seen as the runner's ``stage(stretch)`` callable.

    Parameters
    ----------
    stage : PositionStage
        Driver with ``move_to(position_m, wait=, timeout=)`` and ``position()`` in m.
    gauge_length_m : float
        Specimen gauge length L0 (m), e.g. the specimen file's length.
    x0_m : float, optional
        Carriage position (m) at stretch 1; None until :meth:`zero_here` is called.
    direction : {+1, -1}
        +1 if increasing the carriage position lengthens the specimen.
    timeout_s : float
        Time allowed for one move, s.
    """

    def __init__(self, stage: PositionStage, *, gauge_length_m: float, x0_m: float | None = None,
                 direction: int = 1, timeout_s: float = 60.0) -> None:
        self.stage = stage
        self.gauge_length_m = _gauge(gauge_length_m)
        _check_direction(direction)
        self.direction = direction
        self.x0_m = None if x0_m is None else _finite("x0_m", x0_m)
        if not timeout_s > 0:
            raise ValueError(f"timeout_s must be > 0 s; got {timeout_s}")
        self.timeout_s = float(timeout_s)

    def zero_here(self) -> float:
        """Take the current carriage position as stretch 1 (the specimen at its gauge length); returns it (m)."""
        self.x0_m = float(self.stage.position())
        log.info("stage: stretch 1 at carriage position %.6g m (L0 = %.6g m)", self.x0_m, self.gauge_length_m)
        return self.x0_m

    def _x0(self) -> float:
        if self.x0_m is None:
            raise RuntimeError("x0_m is not set: give x0_m or call zero_here() with the specimen at its gauge length")
        return self.x0_m

    def position_for(self, stretch: float) -> float:
        """Carriage position (m) for ``stretch``."""
        return position_from_stretch(stretch, gauge_length_m=self.gauge_length_m, x0_m=self._x0(),
                                     direction=self.direction)

    def check(self, stretch: float) -> None:
        """Raise ValueError if ``stretch`` needs a position outside the stage's soft limits (nothing moves).

        Lets a caller validate every stretch of a protocol before the session starts.
        """
        config = getattr(self.stage, "config", None)
        position = self.position_for(stretch)
        if config is not None:
            try:
                config.check_position(position)
            except ValueError as exc:
                raise ValueError(f"stretch {stretch:g} (L0 = {self.gauge_length_m:.6g} m, x0 = {self._x0():.6g} m)"
                                 f" is out of reach: {exc}") from exc

    def __call__(self, stretch: float) -> None:
        """Move to ``stretch`` and wait until the carriage is there."""
        self.stage.move_to(self.position_for(stretch), wait=True, timeout=self.timeout_s)

    def clear_fault(self) -> list[str]:
        """Acknowledge the stage's latched fault (Zaber ``warnings clear``); the flags that were set."""
        clear = getattr(self.stage, "clear_warnings", None)
        return list(clear()) if clear is not None else []

    def stop(self) -> None:
        """Stop the carriage (never refused for a fault)."""
        stop = getattr(self.stage, "stop", None)
        if stop is not None:
            stop()

    def stretch(self) -> float:
        """Current axial stretch, from the carriage position."""
        return stretch_from_position(self.stage.position(), gauge_length_m=self.gauge_length_m, x0_m=self._x0(),
                                     direction=self.direction)

    def settings(self) -> dict[str, Any]:
        """JSON-able description for the session file (SI)."""
        inner = self.stage.settings() if hasattr(self.stage, "settings") else {}
        return {"gauge_length_m": self.gauge_length_m, "x0_m": self.x0_m, "direction": self.direction,
                "timeout_s": self.timeout_s, "stage": inner}
