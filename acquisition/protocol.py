"""Protocol, rig-configuration and specimen files: TOML on disk -> frozen dataclasses in SI.

A protocol is data. Everything is validated before anything moves: an unknown key, a
pressure above the rig's safety limit, an empty block, an impossible stretch or a value of
the wrong type raises :class:`ConfigError` with one message naming the file and the key
(``paper-protocol.toml: [[block]] #2 .stretch: expected a number >= 1; got 0.9``).

Units live at the edge. A pressure may be given with its unit in the key
(``pressure_max_mmHg``, ``pressures_kPa``, ``band_Pa``) or without it plus a ``unit`` key in the
same table (``unit = "mmHg"``); lengths in specimen files are in mm (``radius_mm``). Inside
the dataclasses everything is SI: Pa, m, s; stretches are dimensionless ``L/L0``.

Protocol file layout (see ``examples/paper-protocol.toml``)::

    [protocol]          name, description
    [preconditioning]   pressure_cycles, pressure_max_<u>, stretch_cycles, stretch_max,
                        cycle_s, imaged
    [stability]         band_<u>, dwell_s, timeout_s
    [test]              stretches = [...], pressures_<u> = [...]    (same levels at each stretch)
    [[block]]           stretch, pressures_<u>                      (or explicit blocks)
    [capture]           cameras = ["all"] or names, timeout_s
    [calibration]       views (board poses captured before the test), board (description)
    [reference]         capture = true: first capture the stress-free reference state
                        (L/L0 = 1, p = 0) as block 0 (identification's reference step)
"""

from __future__ import annotations

import difflib
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = [
    "ConfigError",
    "WindowConfig",
    "PRESSURE_UNITS",
    "Preconditioning",
    "Stability",
    "TestBlock",
    "CaptureSettings",
    "CalibrationViews",
    "Protocol",
    "PortConfig",
    "CameraConfig",
    "SafetyLimits",
    "RigConfig",
    "SpecimenFile",
    "load_protocol",
    "parse_protocol",
    "load_rig",
    "parse_rig",
    "load_specimen",
    "parse_specimen",
]

MMHG = 133.322387415  # Pa
#: A protocol that would run longer than this is refused before anything moves, s.
MAX_DURATION_S = 86400.0
#: Shortest preconditioning cycle a pressure controller can follow, s.
MIN_CYCLE_S = 0.1
#: Most cameras a rig file may declare.
MAX_CAMERAS = 64
#: Lower bounds of the time one step, one camera frame and one calibration view take, s.
_STEP_FLOOR_S, _FRAME_S, _VIEW_FLOOR_S = 0.5, 0.05, 1.0
PRESSURE_UNITS: dict[str, float] = {"Pa": 1.0, "kPa": 1000.0, "mmHg": MMHG}


class ConfigError(ValueError):
    """A protocol, rig or specimen file is invalid; the message names the file and the key."""


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
        """Raise :class:`ConfigError` if the protocol would take more than a day (estimate in the message)."""
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

    def camera_names(self, rig: RigConfig) -> list[str]:
        """Names of the cameras to capture on ``rig``."""
        if "all" in self.capture.cameras:
            return [c.name for c in rig.cameras]
        return list(self.capture.cameras)


@dataclass(frozen=True)
class PortConfig:
    """One serial instrument.

    Attributes
    ----------
    port : str
        Device path (``/dev/ttyUSB0``), or ``"sim"`` for the simulated rig.
    serial_number : str
        Expected identity ('' = accept any); checked on connect and on resume.
    mode : str
        ``"controller"`` (the rig sets pressure, Mensor ``Setpt``) or ``"manual"`` (operator).
    baudrate : int
        0 = the driver's default (Mensor 9600, Mark-10 115200).
    measures : str
        Load cell only: ``"wall"`` or ``"total"`` (force on the wall alone, or including the
        pressure end-thrust).
    settings : dict
        Anything else for the driver.
    """

    port: str
    serial_number: str = ""
    mode: str = "manual"
    baudrate: int = 0
    measures: str = "wall"
    settings: dict = field(default_factory=dict, compare=False)


@dataclass(frozen=True)
class CameraConfig:
    """One camera: ``backend`` in {'sim', 'folder', 'opencv', 'basler'} and its ``settings``."""

    name: str
    backend: str
    settings: dict = field(default_factory=dict, compare=False)


@dataclass(frozen=True)
class SafetyLimits:
    """Pa, L/L0, N."""

    max_pressure: float = 200 * MMHG
    max_stretch: float = 1.6
    max_force: float = 50.0

    def __post_init__(self) -> None:
        # A limit that is NaN or infinite can never trip: refuse it wherever the limits come from.
        for name, floor in (("max_pressure", 0.0), ("max_stretch", 1.0), ("max_force", 0.0)):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > floor):
                raise ConfigError(f"safety limit {name} must be a finite number > {floor:g}; got {value!r}")


@dataclass(frozen=True)
class WindowConfig:
    """A flat window between the cameras and the bath (rig file ``[window]`` table); SI.

    The air-side surface of the glass is the plane ``normal . X = plane_distance`` in the world
    frame (the calibration's), ``normal`` (unit) pointing from the cameras into the bath; the glass
    (``glass_thickness``, ``glass_index``) follows, then the bath (``bath_index``).
    """

    glass_thickness: float
    glass_index: float
    bath_index: float
    plane_distance: float
    normal: tuple[float, float, float]
    air_index: float = 1.0

    def to_dict(self) -> dict[str, Any]:
        """The session's record, in the keys of ``reconstruction.refraction.Window.to_dict`` (SI)."""
        return {"normal": list(self.normal), "offset_m": self.plane_distance, "thicknesses_m": [self.glass_thickness],
                "indices": [self.glass_index], "n_bath": self.bath_index, "n_air": self.air_index}


@dataclass(frozen=True)
class SimulationConfig:
    """The simulated specimen behind a ``port = "sim"`` rig (ignored by real rigs).

    ``material`` names one of rig_sim's constitutive laws, used with the seed paper's Table-1
    parameters; ``clamped`` solves the tube with both ends on cannulae (heterogeneous strain)
    instead of the homogeneous membrane.
    """

    material: str = "fung"
    n_markers: int = 300
    clamped: bool = False
    seed: int = 0


SIMULATED_MATERIALS = ("fung", "delfino", "hgo", "neohookean")


@dataclass(frozen=True)
class RigConfig:
    name: str
    pressure: PortConfig
    load_cell: PortConfig
    cameras: tuple[CameraConfig, ...]
    safety: SafetyLimits = field(default_factory=SafetyLimits)
    simulation: SimulationConfig = field(default_factory=SimulationConfig)
    text: str = field(default="", compare=False, repr=False)
    source: str = field(default="<rig>", compare=False, repr=False)
    #: How this rig holds its specimens: "clamped" (tied on cannulae), "free", or "" (not said).
    ends: str = ""
    #: The flat window the cameras look through into the bath (``[window]``), None = none.
    window: WindowConfig | None = None

    @property
    def simulated(self) -> bool:
        return self.pressure.port == "sim" or self.load_cell.port == "sim"


@dataclass(frozen=True)
class SpecimenFile:
    """Specimen description; lengths in m (file in mm)."""

    specimen_id: str
    radius: float
    length: float
    thickness: float
    notes: str = ""
    #: How this specimen is held: "clamped" (tied on cannulae), "free", or "" (not said).
    ends: str = ""


#: Accepted values of the ``ends`` keys (rig ``[rig]`` table, specimen file).
END_CONDITIONS = ("clamped", "free")


def _human_duration(seconds: float) -> str:
    if seconds >= 86400 * 365:
        return f"{seconds / (86400 * 365.25):.3g} years"
    if seconds >= 86400:
        return f"{seconds / 86400:.3g} days"
    return f"{seconds / 3600:.3g} h"


# ----------------------------------------------------------------------------- TOML helpers
def _read(path: str | Path) -> tuple[dict, str, str]:
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read file ({exc.strerror})") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        column = exc.start - (raw.rfind(b"\n", 0, exc.start) + 1) + 1
        raise ConfigError(f"{path}: line {line}, column {column}: byte 0x{raw[exc.start]:02x} is not UTF-8 text; "
                          "save the file as UTF-8 (it looks like Latin-1 or another legacy encoding)") from None
    return _loads(text, path.name), text, path.name


def _loads(text: str, source: str) -> dict:
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: not valid TOML ({exc})") from exc


class _Table:
    """A TOML table being consumed: every key must be taken, leftovers are unknown keys."""

    def __init__(self, data: Any, source: str, where: str):
        self.source, self.where = source, where
        if not isinstance(data, dict):
            self.fail("", f"expected a table; got {type(data).__name__}")
        self.data = dict(data)
        self.seen: set[str] = set()
        self.known: set[str] = set()  # every key this table may hold (for "did you mean")
        self.unit_used = False

    def loc(self, key: str) -> str:
        return f"{self.source}: {self.where}" + (f".{key}" if key else "")

    def fail(self, key: str, msg: str):
        raise ConfigError(f"{self.loc(key)}: {msg}")

    def has(self, key: str) -> bool:
        return key in self.data

    def misspelt(self, key: str) -> str | None:
        """An unexpected key of the table that looks like a misspelling of ``key``."""
        strays = [k for k in self.data if k not in self.seen and k not in self.known]
        close = difflib.get_close_matches(key, strays, n=1, cutoff=0.75)
        return close[0] if close else None

    def missing(self, key: str, extra: str = "") -> None:
        stray = self.misspelt(key)
        if stray is not None:
            self.fail(stray, f"unknown key {stray!r}; did you mean {key!r}?")
        self.fail(key, "missing required key" + extra)

    def get(self, key: str, default: Any = ..., kind: type | tuple = object) -> Any:
        self.seen.add(key)
        self.known.add(key)
        if key not in self.data:
            if default is ...:
                self.missing(key)
            return default
        value = self.data[key]
        if not _is(value, kind):
            self.fail(key, f"expected {_kind_name(kind)}; got {type(value).__name__} {value!r}")
        return value

    def number(self, key: str, default: Any = ..., lo: float | None = None, hi: float | None = None,
               lo_open: bool = False) -> float:
        value = self.get(key, default, (int, float))
        if value is default and default is not ...:
            return default
        value = float(value)
        if not math.isfinite(value):
            self.fail(key, f"expected a finite number; got {value}")
        if lo is not None and (value < lo or (lo_open and value == lo)):
            self.fail(key, f"expected a number {'>' if lo_open else '>='} {lo}; got {value:g}")
        if hi is not None and value > hi:
            self.fail(key, f"expected a number <= {hi}; got {value:g}")
        return value

    def integer(self, key: str, default: Any = ..., lo: int = 0) -> int:
        value = self.get(key, default, int)
        if value is default and default is not ...:
            return default
        if value < lo:
            self.fail(key, f"expected an integer >= {lo}; got {value}")
        return int(value)

    def pressure(self, base: str, default: Any = ..., many: bool = False) -> Any:
        """A pressure (or list) given as ``base_<unit>`` or ``base`` + table key ``unit``; Pa."""
        self.known.update([base, "unit"] + [f"{base}_{u}" for u in PRESSURE_UNITS])
        keys = [k for k in (f"{base}_{u}" for u in PRESSURE_UNITS) if k in self.data]
        if base in self.data:
            keys.append(base)
        if len(keys) > 1:
            self.fail(keys[1], f"given twice (also as {keys[0]!r}); give one of them")
        if not keys:
            if default is ...:
                stray = self.misspelt(f"{base}_mmHg") or self.misspelt(f"{base}_kPa") or self.misspelt(base)
                if stray is not None:
                    self.fail(stray, f"unknown key {stray!r}; did you mean {base}_mmHg (or {base}_kPa, {base}_Pa)?")
                self.fail(f"{base}_mmHg", f"missing required key (or {base}_kPa, {base}_Pa, {base} + unit)")
            return default
        key = keys[0]
        if key == base:
            if "unit" not in self.data:
                self.fail(key, f"no unit: write {base}_mmHg / {base}_kPa / {base}_Pa, or add unit = \"mmHg\"")
            unit = self.get("unit", kind=str)
            if unit not in PRESSURE_UNITS:
                self.fail("unit", f"expected one of {sorted(PRESSURE_UNITS)}; got {unit!r}")
            self.unit_used = True
        else:
            unit = key[len(base) + 1:]
        scale = PRESSURE_UNITS[unit]
        if many:
            values = self.get(key, kind=list)
            if not values:
                self.fail(key, "empty list: expected at least one pressure level")
            for i, v in enumerate(values):
                if not _is(v, (int, float)) or not math.isfinite(float(v)):
                    self.fail(f"{key}[{i}]", f"expected a number; got {type(v).__name__} {v!r}")
                if v < 0:
                    self.fail(f"{key}[{i}]", f"expected a gauge pressure >= 0; got {v:g} {unit}")
            return tuple(float(v) * scale for v in values)
        value = self.get(key, kind=(int, float))
        if not math.isfinite(value):
            self.fail(key, f"expected a finite pressure; got {value} {unit}")
        if value < 0:
            self.fail(key, f"expected a pressure >= 0; got {value:g} {unit}")
        return float(value) * scale

    def table(self, key: str, required: bool = False) -> _Table | None:
        self.known.add(key)
        if key not in self.data:
            if required:
                stray = self.misspelt(key)
                if stray is not None:
                    self.fail(stray, f"unknown table [{stray}]; did you mean [{key}]?")
                self.fail(key, "missing required table")
            self.seen.add(key)
            return None
        self.seen.add(key)
        return _Table(self.data[key], self.source, f"[{key}]" if not self.where else f"{self.where}.{key}")

    def done(self) -> None:
        if "unit" in self.data and not self.unit_used:
            unit = self.data["unit"]
            self.fail("unit", f"unit = {unit!r} is ignored: no pressure key of this table uses it (they carry their "
                              "unit in the key, e.g. pressures_mmHg); remove it, or drop the unit from the key")
        unknown = [k for k in self.data if k not in self.seen]
        if unknown:
            where = f"{self.where}." if self.where else ""
            close = difflib.get_close_matches(unknown[0], sorted(self.known - set(self.data)), n=1, cutoff=0.6)
            hint = (f"; did you mean {close[0]!r}?" if close
                    else "; check the spelling (units go in the key, e.g. pressures_mmHg)")
            self.fail("", f"unknown key {where}{unknown[0]!r}" + (f" (and {unknown[1:]})" if unknown[1:] else "")
                      + hint)


def _is(value: Any, kind: type | tuple) -> bool:
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if isinstance(value, bool) and bool not in kinds:
        return False  # TOML true is not a number
    return isinstance(value, kinds)


def _kind_name(kind: type | tuple) -> str:
    kinds = kind if isinstance(kind, tuple) else (kind,)
    names = {int: "an integer", float: "a number", str: "a string", bool: "true/false", list: "a list",
             dict: "a table", object: "a value"}
    if set(kinds) == {int, float}:
        return "a number"
    return " or ".join(names.get(k, k.__name__) for k in kinds)


# ----------------------------------------------------------------------------- protocol
def load_protocol(path: str | Path, rig: RigConfig | None = None) -> Protocol:
    """Read and validate a protocol file (and check it against ``rig``'s limits if given)."""
    data, text, source = _read(path)
    return parse_protocol(data, text=text, source=source, rig=rig)


def parse_protocol(data: dict | str, text: str = "", source: str = "<protocol>",
                   rig: RigConfig | None = None) -> Protocol:
    """Validate a parsed protocol (dict, or TOML text) -> :class:`Protocol` (SI)."""
    if isinstance(data, str):
        text = data
        data = _loads(data, source)
    top = _Table(data, source, "")
    meta = top.table("protocol")
    name, description = Path(source).stem, ""
    if meta is not None:
        name = meta.get("name", name, str)
        description = meta.get("description", "", str)
        meta.done()

    max_stretch = rig.safety.max_stretch if rig is not None else math.inf
    pre = _preconditioning(top.table("preconditioning"))
    stab = _stability(top.table("stability"))

    blocks: list[TestBlock] = []
    t = top.table("test")
    if t is not None:
        stretches = t.get("stretches", kind=list)
        if not stretches:
            t.fail("stretches", "empty list: expected at least one axial stretch")
        pressures = t.pressure("pressures", many=True)
        for i, s in enumerate(stretches):
            blocks.append(TestBlock(_stretch(t, f"stretches[{i}]", s), pressures))
        t.done()
    raw_blocks = top.get("block", [], list)
    if raw_blocks and blocks:
        top.fail("block", "give either [test] (stretches x pressures) or [[block]] entries, not both")
    for i, raw in enumerate(raw_blocks):
        b = _Table(raw, source, f"[[block]] #{i + 1} ")
        stretch = _stretch(b, "stretch", b.get("stretch"))
        blocks.append(TestBlock(stretch, b.pressure("pressures", many=True)))
        b.done()
    if not blocks:
        top.fail("", "no test blocks: add a [test] table (stretches, pressures_mmHg) or [[block]] entries")
    if "stability" in data:
        _check_band(stab, blocks, source, rig)
    for i, blk in enumerate(blocks):
        if blk.stretch > max_stretch:
            raise ConfigError(f"{source}: block #{i + 1} .stretch: {blk.stretch:g} is above the rig's stretch "
                              f"limit {max_stretch:g}")

    cap = CaptureSettings()
    t = top.table("capture")
    if t is not None:
        cams = t.get("cameras", ["all"], list)
        if not cams:
            t.fail("cameras", "empty list: expected camera names or [\"all\"]")
        for i, c in enumerate(cams):
            if not isinstance(c, str):
                t.fail(f"cameras[{i}]", f"expected a camera name (string); got {c!r}")
        cap = CaptureSettings(tuple(cams), t.number("timeout_s", cap.timeout_s, lo=0.0, lo_open=True))
        t.done()
    has_reference = False
    t = top.table("reference")
    if t is not None:
        has_reference = t.get("capture", False, bool)
        if has_reference:
            blocks.insert(0, TestBlock(1.0, (0.0,)))
        t.done()

    calib = CalibrationViews()
    t = top.table("calibration")
    if t is not None:
        calib = CalibrationViews(t.integer("views", 0), t.get("board", "", str))
        t.done()
    top.done()
    proto = Protocol(name, tuple(blocks), pre, stab, cap, calib, description=description, text=text,
                     source=source, has_reference=has_reference)
    if rig is not None:
        proto.check_against(rig)
    proto.check_duration(len(proto.camera_names(rig)) if rig is not None else 1)
    return proto


def _preconditioning(t: _Table | None) -> Preconditioning:
    if t is None:
        return Preconditioning()
    pc = t.integer("pressure_cycles", 0)
    pmax = t.pressure("pressure_max", 0.0)
    sc = t.integer("stretch_cycles", 0)
    smax = t.number("stretch_max", 1.0, lo=1.0)
    if pc and pmax <= 0:
        t.fail("pressure_max_mmHg", f"pressure_cycles = {pc} needs a pressure_max > 0")
    if sc and smax <= 1.0:
        t.fail("stretch_max", f"stretch_cycles = {sc} needs a stretch_max > 1; got {smax:g}")
    pre = Preconditioning(pc, pmax, sc, smax, t.number("cycle_s", 10.0, lo=MIN_CYCLE_S),
                          t.get("imaged", False, bool))
    t.done()
    return pre


def _stability(t: _Table | None) -> Stability:
    stab = Stability()
    if t is None:
        return stab
    stab = Stability(t.pressure("band", stab.band), t.number("dwell_s", stab.dwell_s, lo=0.0),
                     t.number("timeout_s", stab.timeout_s, lo=0.0, lo_open=True))
    if stab.band <= 0:
        t.fail("band_mmHg", "expected a band > 0")
    t.done()
    return stab


def _check_band(stab: Stability, blocks: list[TestBlock], source: str, rig: RigConfig | None) -> None:
    """The stability band must tell neighbouring levels apart and sit well inside the safety limit."""
    gaps = [b - a for blk in blocks for a, b in zip(sorted(set(blk.pressures)), sorted(set(blk.pressures))[1:])]
    if gaps and stab.band >= 0.5 * min(gaps):
        raise ConfigError(f"{source}: [stability].band: {stab.band / MMHG:.3g} mmHg is not smaller than half the "
                          f"smallest step between pressure levels ({min(gaps) / MMHG:.3g} mmHg): a level could be "
                          "captured at its neighbour's pressure; narrow the band")
    if rig is not None and stab.band >= 0.1 * rig.safety.max_pressure:
        raise ConfigError(f"{source}: [stability].band: {stab.band / MMHG:.3g} mmHg is not small against the rig's "
                          f"safety limit {rig.safety.max_pressure / MMHG:.3g} mmHg (expected < 10 % of it)")


def _stretch(t: _Table, key: str, value: Any) -> float:
    if not _is(value, (int, float)) or not math.isfinite(float(value)):
        t.fail(key, f"expected an axial stretch L/L0 (number); got {type(value).__name__} {value!r}")
    value = float(value)
    if value <= 0:
        t.fail(key, f"impossible axial stretch L/L0 = {value:g}: must be > 0 (and >= 1, the specimen is not compressed)")
    if value < 1.0:
        t.fail(key, f"axial stretch L/L0 = {value:g} < 1 would compress the specimen: expected a value >= 1")
    if value > 3.0:
        t.fail(key, f"axial stretch L/L0 = {value:g} is not physical for an artery: expected a value <= 3")
    return value


# ----------------------------------------------------------------------------- rig
_BACKENDS = ("sim", "folder", "opencv", "basler")


def load_rig(path: str | Path) -> RigConfig:
    """Read and validate a rig configuration file."""
    data, text, source = _read(path)
    return parse_rig(data, text=text, source=source)


def parse_rig(data: dict | str, text: str = "", source: str = "<rig>") -> RigConfig:
    if isinstance(data, str):
        text = data
        data = _loads(data, source)
    top = _Table(data, source, "")
    meta = top.table("rig")
    name = Path(source).stem
    ends = ""
    if meta is not None:
        name = meta.get("name", name, str)
        ends = _ends(meta)
        meta.done()
    pressure = _port(top.table("pressure", required=True), is_load_cell=False)
    load_cell = _port(top.table("load_cell", required=True), is_load_cell=True)
    cams: list[CameraConfig] = []
    raw_cams = top.get("camera", [], list)
    if len(raw_cams) > MAX_CAMERAS:
        top.fail("camera", f"{len(raw_cams)} [[camera]] entries: expected at most {MAX_CAMERAS}")
    for i, raw in enumerate(raw_cams):
        c = _Table(raw, source, f"[[camera]] #{i + 1} ")
        cname = c.get("name", kind=str)
        backend = c.get("backend", kind=str)
        if backend not in _BACKENDS:
            c.fail("backend", f"expected one of {list(_BACKENDS)}; got {backend!r}")
        settings = c.get("settings", {}, dict)
        c.done()
        _check_referenced_paths(c, settings)
        if any(x.name == cname for x in cams):
            c.fail("name", f"duplicate camera name {cname!r}")
        cams.append(CameraConfig(cname, backend, dict(settings)))
    if not cams:
        top.fail("camera", "no cameras: add [[camera]] entries (name, backend)")
    safety = SafetyLimits()
    t = top.table("safety")
    if t is not None:
        limits = (t.pressure("max_pressure", safety.max_pressure), t.number("max_stretch", safety.max_stretch, lo=1.0),
                  t.number("max_force_N", safety.max_force, lo=0.0, lo_open=True))
        if limits[0] <= 0:
            t.fail("max_pressure_mmHg", "expected a limit > 0")
        if limits[1] <= 1.0:
            t.fail("max_stretch", f"expected a limit > 1 (L/L0 = 1 is the unstretched length); got {limits[1]:g}")
        safety = SafetyLimits(*limits)
        t.done()
    simulation = SimulationConfig()
    t = top.table("simulation")
    if t is not None:
        material = t.get("material", simulation.material, str)
        if material not in SIMULATED_MATERIALS:
            t.fail("material", f"expected one of {list(SIMULATED_MATERIALS)}; got {material!r}")
        simulation = SimulationConfig(material, t.integer("n_markers", simulation.n_markers, lo=10),
                                      t.get("clamped", simulation.clamped, bool),
                                      t.integer("seed", simulation.seed))
        t.done()
    window = _window(top.table("window"))
    top.done()
    return RigConfig(name, pressure, load_cell, tuple(cams), safety, simulation, text, source, ends, window)


def _window(t: _Table | None) -> WindowConfig | None:
    """The rig's ``[window]`` table: lengths in mm in the file, m in the result."""
    if t is None:
        return None
    thickness = t.number("glass_thickness_mm", lo=0.0) * 1e-3
    indices = [t.number(k, default, lo=1.0) for k, default in (("glass_index", ...), ("bath_index", ...),
                                                               ("air_index", 1.0))]
    distance = t.number("plane_distance_mm") * 1e-3
    normal = t.get("normal", kind=list)
    if len(normal) != 3 or not all(_is(v, (int, float)) and math.isfinite(float(v)) for v in normal):
        t.fail("normal", f"expected 3 finite numbers (world frame, from the cameras into the bath); got {normal!r}")
    norm = math.sqrt(sum(float(v) ** 2 for v in normal))
    if norm == 0:
        t.fail("normal", f"expected a non-zero vector; got {normal!r}")
    t.done()
    return WindowConfig(thickness, indices[0], indices[1], distance, tuple(float(v) / norm for v in normal), indices[2])


def _ends(t: _Table) -> str:
    """The optional ``ends`` key of a table: "clamped", "free" or "" when absent."""
    ends = t.get("ends", "", str)
    if ends and ends not in END_CONDITIONS:
        t.fail("ends", f"expected one of {list(END_CONDITIONS)}; got {ends!r}")
    return ends


_PATH_KEYS = ("path", "file", "folder", "directory")


def _check_referenced_paths(t: _Table, settings: dict) -> None:
    """A file or folder a camera's settings name must exist (checked now, before anything moves)."""
    for key, value in settings.items():
        if isinstance(value, str) and (key in _PATH_KEYS or key.endswith(("_path", "_file", "_dir"))):
            if not Path(value).expanduser().exists():
                t.fail(f"settings.{key}", f"{value!r} does not exist (paths are relative to the folder vfmlab "
                                          f"runs in: {Path.cwd()})")


def _port(t: _Table, is_load_cell: bool) -> PortConfig:
    port = t.get("port", kind=str)
    serial = t.get("serial_number", "", str)
    mode = "manual"
    measures = "wall"
    if is_load_cell:
        measures = t.get("measures", kind=str)
        if measures not in ("wall", "total"):
            t.fail("measures", f"expected 'wall' or 'total'; got {measures!r}")
    else:
        mode = t.get("mode", "manual", str)
        if mode not in ("controller", "manual"):
            t.fail("mode", f"expected 'controller' or 'manual'; got {mode!r}")
    baud = t.integer("baudrate", 0, lo=1)
    settings = t.get("settings", {}, dict)
    t.done()
    return PortConfig(port, serial, mode, baud, measures, dict(settings))


# ----------------------------------------------------------------------------- specimen
def load_specimen(path: str | Path) -> SpecimenFile:
    """Read and validate a specimen file (lengths in mm in the file, m in the result)."""
    data, _, source = _read(path)
    return parse_specimen(data, source=source)


def parse_specimen(data: dict | str, source: str = "<specimen>") -> SpecimenFile:
    if isinstance(data, str):
        data = _loads(data, source)
    top = _Table(data, source, "")
    t = top.table("specimen", required=True)
    sid = t.get("id", kind=str)
    if not sid.strip():
        t.fail("id", "expected a non-empty specimen id")
    dims = [t.number(k, lo=0.0, lo_open=True) * 1e-3 for k in ("radius_mm", "length_mm", "thickness_mm")]
    if dims[2] >= dims[0]:
        t.fail("thickness_mm", f"wall thickness {dims[2] * 1e3:g} mm must be smaller than the radius "
                               f"{dims[0] * 1e3:g} mm")
    notes = t.get("notes", "", str)
    ends = _ends(t)
    t.done()
    top.done()
    return SpecimenFile(sid, dims[0], dims[1], dims[2], notes, ends)
