"""Protocol files: TOML -> :class:`Protocol`, validated before anything moves."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from acquisition.protocol._model import (
    MAX_REFERENCE_REPEATS,
    MIN_CYCLE_S,
    CalibrationViews,
    CaptureSettings,
    Preconditioning,
    Protocol,
    Stability,
    TestBlock,
)
from acquisition.protocol._rig_model import RigConfig
from acquisition.protocol._toml import _is, _loads, _read, _Table
from acquisition.protocol._units import MMHG, ConfigError


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
        repeats = _repeats(t, has_reference)
        if has_reference:
            blocks.insert(0, TestBlock(1.0, (0.0,) * repeats))
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


def _repeats(t: _Table, has_reference: bool) -> int:
    """``[reference].repeats``: how many times the reference state is captured (averaged by the identification)."""
    if not t.has("repeats"):
        return 1
    value = t.get("repeats", 1, int)
    if value < 1:
        t.fail("repeats", f"expected the number of captures of the reference, an integer >= 1; got {value}")
    if value > MAX_REFERENCE_REPEATS:
        t.fail("repeats", f"{value} captures of the reference is not useful: expected at most {MAX_REFERENCE_REPEATS} "
                          "(averaging N captures divides the reference's marker noise by sqrt(N); 4 halve it)")
    if value > 1 and not has_reference:
        t.fail("repeats", f"repeats = {value} needs capture = true (the reference is not captured)")
    return int(value)


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
