"""What the live view shows of a run (:class:`RunnerState`) and how far a session's plan got."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


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
