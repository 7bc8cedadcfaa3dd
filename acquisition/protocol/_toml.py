"""Reading TOML files for the protocol, rig and specimen parsers: every key consumed, errors that name
the file, the key, what was expected and what was given."""

from __future__ import annotations

import difflib
import math
import tomllib
from pathlib import Path
from typing import Any

from acquisition.protocol._units import PRESSURE_UNITS, ConfigError


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
