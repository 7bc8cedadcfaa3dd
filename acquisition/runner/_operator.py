"""The person at the rig, as the runner sees them: the :class:`Operator` interface and the unattended
:class:`AutoOperator`."""

from __future__ import annotations

import enum
from collections.abc import Callable, Sequence
from typing import Protocol as _Protocol


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
    fails after the runner's automatic retries it aborts (vents); a stage fault it clears (a few times
    per session, then it quits resumably). ``set_pressure`` /
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
        if "clear" in options:  # a stage fault: clear it and retry the move (the runner bounds how often)
            return "clear"
        return self.on_interrupt if self.on_interrupt in options else options[-1]

    def notify(self, message: str) -> None:
        self.messages.append(message)

    def ask_text(self, prompt: str) -> str:
        return ""
