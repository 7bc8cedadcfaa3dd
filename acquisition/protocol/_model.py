"""The protocol as data: its time limits and the frozen protocol dataclasses (SI)."""

from __future__ import annotations

from dataclasses import dataclass, field

from acquisition.protocol._rig_model import RigConfig
from acquisition.protocol._units import MMHG, ConfigError

#: A protocol that would run longer than this is refused before anything moves, s.
MAX_DURATION_S = 86400.0
#: Most steps a protocol may have: an inflation/extension test has tens to hundreds.
MAX_STEPS = 10_000
#: Most captures of the stress-free reference (``[reference] repeats``): beyond this, drift outweighs averaging.
MAX_REFERENCE_REPEATS = 20
#: Shortest preconditioning cycle a pressure controller can follow, s.
MIN_CYCLE_S = 0.1
#: Lower bounds of the time one step, one camera frame and one calibration view take, s.
_STEP_FLOOR_S, _FRAME_S, _VIEW_FLOOR_S = 0.5, 0.05, 1.0


# ----------------------------------------------------------------------------- dataclasses
@dataclass(frozen=True)
class Preconditioning:
    """Preconditioning cycles, logged but not imaged unless ``imaged``.

    Attributes
    ----------
    pressure_cycles : int
        Number of pressurisation cycles 0 -> ``pressure_max``.
    pressure_max : float
        Pa.
    stretch_cycles : int
        Number of axial-stretch cycles 1 -> ``stretch_max``.
    stretch_max : float
        L/L0, dimensionless.
    cycle_s : float
        Duration of one cycle (up and down), s.
    imaged : bool
        Capture the cameras at the top of each cycle.
    """

    pressure_cycles: int = 0
    pressure_max: float = 0.0
    stretch_cycles: int = 0
    stretch_max: float = 1.0
    cycle_s: float = 10.0
    imaged: bool = False


@dataclass(frozen=True)
class Stability:
    """When a pressure level counts as reached.

    Attributes
    ----------
    band : float
        Pa; the pressure must stay within ``target +- band`` ...
    dwell_s : float
        ... for this long, s.
    timeout_s : float
        Give up waiting (the operator is asked) after this long, s.
    """

    band: float = 0.5 * MMHG
    dwell_s: float = 5.0
    timeout_s: float = 120.0


@dataclass(frozen=True)
class TestBlock:
    """Pressure levels (Pa, shape (n_levels,)) imaged at one axial stretch (L/L0)."""

    __test__ = False  # not a pytest class

    stretch: float
    pressures: tuple[float, ...]


@dataclass(frozen=True)
class CalibrationViews:
    """Calibration-board views captured before preconditioning (stored in the session).

    Attributes
    ----------
    views : int
        Number of board poses (0 = none; calibrate from another session or folder).
    board : str
        Description of the board for the operator and the record (e.g. "ChArUco 8x6, 4.5 mm").
    """

    views: int = 0
    board: str = ""


@dataclass(frozen=True)
class CaptureSettings:
    """Which cameras to capture (``("all",)`` = every camera of the rig) and the timeout, s."""

    cameras: tuple[str, ...] = ("all",)
    timeout_s: float = 5.0


@dataclass(frozen=True)
class Protocol:
    """A whole test protocol, SI units; ``text`` is the file as read (stored in the session)."""

    name: str
    blocks: tuple[TestBlock, ...]
    preconditioning: Preconditioning = field(default_factory=Preconditioning)
    stability: Stability = field(default_factory=Stability)
    capture: CaptureSettings = field(default_factory=CaptureSettings)
    calibration: CalibrationViews = field(default_factory=CalibrationViews)
    description: str = ""
    has_reference: bool = False  # blocks[0] is the stress-free reference capture (L/L0 = 1, p = 0)
    text: str = field(default="", compare=False, repr=False)
    source: str = field(default="<protocol>", compare=False, repr=False)

    @property
    def steps(self) -> list[tuple[int, float, float]]:
        """Every imaged step in order: ``(block, stretch, target_pressure_Pa)``."""
        return [(b, blk.stretch, p) for b, blk in enumerate(self.blocks) for p in blk.pressures]

    @property
    def reference_repeats(self) -> int:
        """Captures of the stress-free reference (the steps of block 0 when ``has_reference``; else 1): the
        identification averages them into one reference (``[reference] repeats``)."""
        return len(self.blocks[0].pressures) if self.has_reference else 1

    @property
    def n_steps(self) -> int:
        return sum(len(b.pressures) for b in self.blocks)

    def check_against(self, rig: RigConfig) -> None:
        """Raise :class:`ConfigError` if the protocol exceeds the rig's safety limits or cameras."""
        lim = rig.safety
        src = self.source
        pc = self.preconditioning
        if pc.pressure_cycles and pc.pressure_max > lim.max_pressure:
            raise ConfigError(
                f"{src}: [preconditioning].pressure_max: {pc.pressure_max / MMHG:.1f} mmHg is above the rig's "
                f"safety limit {lim.max_pressure / MMHG:.1f} mmHg ({rig.source}: [safety])"
            )
        if pc.stretch_cycles and pc.stretch_max > lim.max_stretch:
            raise ConfigError(
                f"{src}: [preconditioning].stretch_max: {pc.stretch_max} is above the rig's stretch limit "
                f"{lim.max_stretch} ({rig.source}: [safety].max_stretch)"
            )
        for i, blk in enumerate(self.blocks[int(self.has_reference):]):
            top = max(blk.pressures)
            if top > lim.max_pressure:
                raise ConfigError(
                    f"{src}: block #{i + 1} .pressures: {top / MMHG:.1f} mmHg is above the rig's safety limit "
                    f"{lim.max_pressure / MMHG:.1f} mmHg ({rig.source}: [safety])"
                )
            if blk.stretch > lim.max_stretch:
                raise ConfigError(
                    f"{src}: block #{i + 1} .stretch: {blk.stretch} is above the rig's stretch limit "
                    f"{lim.max_stretch} ({rig.source}: [safety].max_stretch)"
                )
        names = [c.name for c in rig.cameras]
        for cam in self.capture.cameras:
            if cam != "all" and cam not in names:
                raise ConfigError(
                    f"{src}: [capture].cameras: camera {cam!r} is not in the rig ({rig.source}); "
                    f"expected one of {names} or 'all'"
                )

    def min_duration_s(self, n_cameras: int = 1) -> float:
        """A lower bound of the time the protocol takes, s (cycles, dwell and capture; no waiting)."""
        pc = self.preconditioning
        cycles = (pc.pressure_cycles + pc.stretch_cycles) * pc.cycle_s
        steps = self.n_steps * (self.stability.dwell_s + _STEP_FLOOR_S + _FRAME_S * n_cameras)
        views = self.calibration.views * (_VIEW_FLOOR_S + _FRAME_S * n_cameras)
        return cycles + steps + views

    def check_duration(self, n_cameras: int = 1) -> None:
        """Raise :class:`ConfigError` if the protocol has more than :data:`MAX_STEPS` steps or would take more
        than a day (estimate in the message)."""
        total = self.min_duration_s(n_cameras)
        if total > MAX_DURATION_S:
            pc = self.preconditioning
            raise ConfigError(
                f"{self.source}: the protocol would take at least {_human_duration(total)} "
                f"({pc.pressure_cycles + pc.stretch_cycles} preconditioning cycles x {pc.cycle_s:g} s, "
                f"{self.n_steps} steps x >= {self.stability.dwell_s + _STEP_FLOOR_S:g} s, "
                f"{self.calibration.views} calibration views, {n_cameras} camera(s)); the limit is "
                f"{_human_duration(MAX_DURATION_S)}: split it into several sessions"
            )
        if self.n_steps > MAX_STEPS:
            raise ConfigError(
                f"{self.source}: the protocol has {self.n_steps:,} steps (at most {MAX_STEPS:,}) and would take at "
                f"least {_human_duration(total)} ({self.n_steps:,} steps x >= "
                f"{self.stability.dwell_s + _STEP_FLOOR_S + _FRAME_S * n_cameras:g} s with {n_cameras} camera(s)): "
                "split it into several sessions")

    def camera_names(self, rig: RigConfig) -> list[str]:
        """Names of the cameras to capture on ``rig``."""
        if "all" in self.capture.cameras:
            return [c.name for c in rig.cameras]
        return list(self.capture.cameras)


def _human_duration(seconds: float) -> str:
    if seconds >= 86400 * 365:
        return f"{seconds / (86400 * 365.25):.3g} years"
    if seconds >= 86400:
        return f"{seconds / 86400:.3g} days"
    if seconds < 3600:
        return f"{seconds / 60:.3g} min"
    return f"{seconds / 3600:.3g} h"
