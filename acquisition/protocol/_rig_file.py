"""Rig-configuration and specimen files: TOML -> :class:`RigConfig`, :class:`SpecimenFile`."""

from __future__ import annotations

import math
from pathlib import Path

from acquisition.plausibility import MAX_IMAGE_SIDE_PX, SPECIMEN_RANGES, WORK_BYTES_PER_PIXEL, human_bytes
from acquisition.protocol._rig_model import (
    END_CONDITIONS,
    MAX_CAMERAS,
    SIMULATED_MATERIALS,
    CameraConfig,
    PortConfig,
    RigConfig,
    SafetyLimits,
    SimFaults,
    SimulationConfig,
    SpecimenFile,
    StageConfig,
    WindowConfig,
)
from acquisition.protocol._toml import _is, _loads, _read, _Table

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
    calibration = ""
    if meta is not None:
        name = meta.get("name", name, str)
        ends = _ends(meta)
        calibration = meta.get("calibration", "", str)
        if calibration and not Path(calibration).expanduser().exists():
            meta.fail("calibration", f"{calibration!r} does not exist (a cameras file: .toml, .yaml or an OpenPTV "
                                     f"folder; paths are relative to the folder vfmlab runs in: {Path.cwd()})")
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
        _check_frame_size(c, settings)
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
                                      t.integer("seed", simulation.seed),
                                      _sim_faults(t.table("faults"), [c.name for c in cams]))
        t.done()
    window = _window(top.table("window"))
    stage = _stage(top.table("stage"))
    top.done()
    return RigConfig(name, pressure, load_cell, tuple(cams), safety, simulation, text, source, ends, window, stage,
                     calibration)


def _sim_faults(t: _Table | None, cameras: list[str]) -> SimFaults:
    """``[simulation.faults]``: camera names per image fault, and the load cell's drift (N/s)."""
    if t is None:
        return SimFaults()
    lists = []
    for key in ("defocus", "saturate", "no_markers"):
        names = t.get(key, [], list)
        for n in names:
            if n not in cameras:
                t.fail(key, f"expected names of [[camera]] entries {cameras}; got {n!r}")
        lists.append(tuple(names))
    drift = t.number("force_drift_N_per_s", 0.0)
    blur = t.number("defocus_px", SimFaults.defocus_px, lo=0.0, lo_open=True)
    t.done()
    return SimFaults(lists[0], lists[1], lists[2], force_drift=drift, defocus_px=blur)


def _stage(t: _Table | None) -> StageConfig | None:
    """``[stage]``: the motorised axial stage; lengths in mm in the file, m in the result."""
    if t is None:
        return None
    port = t.get("port", kind=str)
    microstep = t.number("microstep_um", lo=0.0, lo_open=True) * 1e-6
    lo, hi = t.number("min_mm") * 1e-3, t.number("max_mm") * 1e-3
    if not lo < hi:
        t.fail("max_mm", f"expected max_mm > min_mm = {lo * 1e3:g}; got {hi * 1e3:g}")
    x0 = t.number("x0_mm") * 1e-3
    if not lo <= x0 <= hi:
        t.fail("x0_mm", f"expected a position within [min_mm, max_mm] = [{lo * 1e3:g}, {hi * 1e3:g}]; "
                        f"got {x0 * 1e3:g}")
    direction = t.integer("direction", 1, lo=-1)
    if direction not in (1, -1):
        t.fail("direction", f"expected +1 (a larger position lengthens the specimen) or -1; got {direction}")
    stage = StageConfig(port, microstep, lo, hi, x0, direction, t.integer("device", 1, lo=1),
                        t.integer("axis", 1, lo=1), t.get("home", True, bool),
                        t.number("timeout_s", 60.0, lo=0.0, lo_open=True), t.get("serial_number", "", str),
                        t.integer("baudrate", 0, lo=1))
    t.done()
    return stage


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


def _check_frame_size(c: _Table, settings: dict) -> None:
    """``settings.width``/``height``, when given: whole pixels within 1..MAX_IMAGE_SIDE_PX (memory in the message)."""
    w, h = settings.get("width", 640), settings.get("height", 480)
    for key, value in (("width", w), ("height", h)):
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_IMAGE_SIDE_PX:
            size = (f" (one {w:,} x {h:,} px frame is {human_bytes(w * h)}, about {human_bytes(WORK_BYTES_PER_PIXEL * w * h)} of "
                    "memory to capture)" if all(isinstance(v, (int, float)) and v > 0 for v in (w, h)) else "")
            c.fail("settings", f"{key} must be a whole number of pixels in 1..{MAX_IMAGE_SIDE_PX:,}; got {value!r}{size}")


def parse_specimen(data: dict | str, source: str = "<specimen>") -> SpecimenFile:
    if isinstance(data, str):
        data = _loads(data, source)
    top = _Table(data, source, "")
    t = top.table("specimen", required=True)
    sid = t.get("id", kind=str)
    if not sid.strip():
        t.fail("id", "expected a non-empty specimen id")
    dims = [t.number(k, lo=0.0, lo_open=True) * 1e-3 for k in ("radius_mm", "length_mm", "thickness_mm")]
    for key, value in zip(("radius", "length", "thickness"), dims):
        lo, hi = SPECIMEN_RANGES[key]
        if not lo <= value <= hi:
            t.fail(f"{key}_mm", f"expected a plausible {key} of {lo * 1e3:g}..{hi * 1e3:g} mm; got {value * 1e3:g}")
    if dims[2] >= dims[0]:
        t.fail("thickness_mm", f"wall thickness {dims[2] * 1e3:g} mm must be smaller than the radius "
                               f"{dims[0] * 1e3:g} mm")
    notes = t.get("notes", "", str)
    ends = _ends(t)
    t.done()
    top.done()
    return SpecimenFile(sid, dims[0], dims[1], dims[2], notes, ends)
