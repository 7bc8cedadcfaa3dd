"""Marker positions and loads measured elsewhere, as CSV: parse, validate, write.

Markers, long format (one row per marker and step; step 0 = reference configuration)::

    marker_id,step,x_m,y_m,z_m                  (or x_mm,y_mm,z_mm)
    M001,0,0.0100012,0.0000000,-0.0125000

A marker missing from a step is either absent or has empty/NaN coordinates.

Loads (one row per step)::

    step,pressure_Pa,axial_force_N,stretch        (or pressure_kPa / pressure_mmHg)

``axial_force_N`` is the force carried by the wall (the paper's eq. 8) unless the caller says
the load cell reads the total behind a pressurised cannula.

Errors are :class:`CsvFormatError` naming the file, line and column.
"""

from __future__ import annotations

import csv
import io
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from acquisition.errors import InputError
from acquisition.numbers import strict_float

__all__ = [
    "CsvFormatError",
    "MarkerTable",
    "read_markers_csv",
    "read_loads_csv",
    "write_markers_csv",
    "write_loads_csv",
    "PRESSURE_UNITS",
    "MMHG",
]

MMHG = 133.322387415  # Pa per mmHg (conventional millimetre of mercury)
PRESSURE_UNITS = {"pressure_Pa": 1.0, "pressure_kPa": 1e3, "pressure_mmHg": MMHG}
_MARKER_COLUMNS = ("marker_id", "step")
#: coordinate columns: metres (what export-markers writes) or millimetres, the unit in the header
LENGTH_UNITS = {"m": 1.0, "mm": 1e-3}
_XYZ_ALTERNATIVES = {axis: tuple(f"{axis}_{u}" for u in LENGTH_UNITS) for axis in "xyz"}
_LOAD_COLUMNS = ("step", "axial_force_N", "stretch")
COORDINATE_FORMATS = {"m": "{:.9f}", "mm": "{:.6f}"}  # 1 nm: far below any marker accuracy


class CsvFormatError(InputError):
    """A CSV file does not follow the documented format; the message names line and column."""


@dataclass(frozen=True)
class MarkerTable:
    """Marker positions parsed from CSV.

    Attributes
    ----------
    labels : ndarray of str, shape (n_markers,)
        Marker ids as written in the file, in order of first appearance.
    steps : ndarray of int, shape (n_steps,)
        Step numbers, sorted; steps[0] must be 0 (reference).
    positions : ndarray, shape (n_steps, n_markers, 3)
        Metres; NaN where a marker was not measured.
    """

    labels: np.ndarray
    steps: np.ndarray
    positions: np.ndarray


def _rows(path: Path, required: tuple[str, ...], alternatives: dict[str, tuple[str, ...]] | None = None):
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise CsvFormatError(f"{path}: no such file") from None
    except UnicodeDecodeError as exc:
        raise CsvFormatError(f"{path}: not a UTF-8 text file ({exc.reason} at byte {exc.start})") from None
    reader = csv.reader(io.StringIO(text))
    try:
        header = [h.strip() for h in next(reader)]
    except StopIteration:
        raise CsvFormatError(f"{path}: the file is empty; expected a header line {','.join(required)}") from None
    missing = [c for c in required if c not in header]
    if missing:
        raise CsvFormatError(
            f"{path}, line 1: missing column(s) {', '.join(missing)}; header is {','.join(header)!r}, "
            f"expected {','.join(required)}"
        )
    for group, options in (alternatives or {}).items():
        present = [c for c in options if c in header]
        if len(present) != 1:
            unknown = [h for h in header if h.startswith(group + "_") and h not in options]
            hint = f" (unknown unit column {unknown[0]!r})" if unknown else ""
            raise CsvFormatError(
                f"{path}, line 1: expected exactly one of the columns {', '.join(options)}; "
                f"found {', '.join(present) or 'none'}{hint}; header is {','.join(header)!r}"
            )
    index = {name: i for i, name in enumerate(header)}
    for line_no, row in enumerate(reader, start=2):
        if not row or all(not cell.strip() for cell in row):
            continue
        if len(row) < len(header):
            row = row + [""] * (len(header) - len(row))
        yield line_no, {name: row[i].strip() for name, i in index.items()}


def _number(path: Path, line: int, column: str, text: str, *, allow_empty: bool = False) -> float:
    if text == "" or text.lower() == "nan":
        if allow_empty:
            return math.nan
        raise CsvFormatError(f"{path}, line {line}, column {column}: missing value")
    try:
        value = strict_float(text)  # not float(): "1_0.5" would be 10.5
    except ValueError:
        raise CsvFormatError(f"{path}, line {line}, column {column}: {text!r} is not a number") from None
    if math.isinf(value):
        raise CsvFormatError(f"{path}, line {line}, column {column}: {text!r} is not finite")
    return value


MAX_STEP = 2**31 - 1  # step numbers are stored as 32-bit integers
MAX_COORDINATE_MM = 1e5  # 100 m: beyond any rig; larger values are unit or format mistakes


def _step(path: Path, line: int, text: str) -> int:
    value = _number(path, line, "step", text)
    if value != int(value) or value < 0 or value > MAX_STEP:
        raise CsvFormatError(f"{path}, line {line}, column step: {text!r} is not a step number "
                             f"(0, 1, 2, ... up to {MAX_STEP})")
    return int(value)


def _coordinate(path: Path, line: int, column: str, text: str, scale: float) -> float:
    """A coordinate in metres (``scale``: metres per unit of the column)."""
    value = _number(path, line, column, text, allow_empty=True) * scale
    if abs(value) > MAX_COORDINATE_MM * 1e-3:
        unit = column.rsplit("_", 1)[-1]
        raise CsvFormatError(f"{path}, line {line}, column {column}: {text!r} {unit} is not a marker coordinate "
                             f"(expected within {MAX_COORDINATE_MM * 1e-3:g} m of the origin; µm or nm given?)")
    return value


def read_markers_csv(path: str | os.PathLike) -> MarkerTable:
    """Parse a long-format marker CSV (coordinates in m or mm, said by the header) into positions in metres."""
    path = Path(path)
    labels: dict[str, int] = {}
    records: dict[tuple[int, int], tuple[float, float, float]] = {}
    seen_at: dict[tuple[str, int], int] = {}
    columns, scale = None, 1.0
    for line, row in _rows(path, _MARKER_COLUMNS, _XYZ_ALTERNATIVES):
        if columns is None:
            unit = next(u for u in LENGTH_UNITS if f"x_{u}" in row)
            columns, scale = tuple(f"{axis}_{unit}" for axis in "xyz"), LENGTH_UNITS[unit]
            if not all(c in row for c in columns):
                raise CsvFormatError(f"{path}, line 1: x, y and z must be in the same unit; expected "
                                     f"{','.join(columns)}")
        label = row["marker_id"]
        if not label:
            raise CsvFormatError(f"{path}, line {line}, column marker_id: missing value")
        step = _step(path, line, row["step"])
        if (label, step) in seen_at:
            raise CsvFormatError(
                f"{path}, line {line}: duplicate marker {label!r} at step {step} (first on line {seen_at[label, step]})"
            )
        seen_at[label, step] = line
        xyz = tuple(_coordinate(path, line, c, row[c], scale) for c in columns)
        if any(math.isnan(v) for v in xyz) and not all(math.isnan(v) for v in xyz):
            raise CsvFormatError(f"{path}, line {line}: marker {label!r} has some coordinates missing; give all or none")
        index = labels.setdefault(label, len(labels))
        records[index, step] = xyz
    if not records:
        raise CsvFormatError(f"{path}: no marker rows after the header")
    steps = np.array(sorted({s for _, s in records}), dtype=int)
    if steps[0] != 0:
        raise CsvFormatError(f"{path}: no rows for step 0 (the reference configuration)")
    step_index = {s: i for i, s in enumerate(steps)}
    positions = np.full((len(steps), len(labels), 3), np.nan)
    keys = np.array([(step_index[s], m) for m, s in records], dtype=int)
    positions[keys[:, 0], keys[:, 1]] = np.array(list(records.values()))
    return MarkerTable(np.array(list(labels), dtype=str), steps, positions)


def read_loads_csv(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Parse a loads CSV into ``{"step", "pressure" (Pa), "axial_force" (N), "stretch"}`` arrays ``(n_steps,)``,
    sorted by step."""
    path = Path(path)
    rows = {}
    pressure_column = None
    for line, row in _rows(path, _LOAD_COLUMNS, {"pressure": tuple(PRESSURE_UNITS)}):
        if pressure_column is None:
            pressure_column = next(c for c in PRESSURE_UNITS if c in row)
        step = _step(path, line, row["step"])
        if step in rows:
            raise CsvFormatError(f"{path}, line {line}: duplicate step {step} (first on line {rows[step][0]})")
        pressure = _number(path, line, pressure_column, row[pressure_column]) * PRESSURE_UNITS[pressure_column]
        force = _number(path, line, "axial_force_N", row["axial_force_N"], allow_empty=True)
        stretch = _number(path, line, "stretch", row["stretch"])
        if stretch <= 0:
            raise CsvFormatError(f"{path}, line {line}, column stretch: must be positive; got {stretch}")
        rows[step] = (line, pressure, force, stretch)
    if not rows:
        raise CsvFormatError(f"{path}: no load rows after the header")
    steps = np.array(sorted(rows), dtype=int)
    table = np.array([rows[s][1:] for s in steps], dtype=float)
    return {"step": steps, "pressure": table[:, 0], "axial_force": table[:, 1], "stretch": table[:, 2]}


def write_markers_csv(
    path: str | os.PathLike, labels: np.ndarray, steps: np.ndarray, positions: np.ndarray, units: str = "m"
) -> None:
    """Write positions ``(n_steps, n_markers, 3)`` (m) as long-format CSV in ``units`` ("m" or "mm", named in
    the header: x_m or x_mm); NaN -> empty cells."""
    if units not in LENGTH_UNITS:
        raise ValueError(f"write_markers_csv: units must be one of {', '.join(LENGTH_UNITS)}; got {units!r}")
    positions = np.asarray(positions, dtype=float)
    n_steps, n_markers, _ = positions.shape
    if len(labels) != n_markers or len(steps) != n_steps:
        raise ValueError(
            f"write_markers_csv: labels ({len(labels)}) and steps ({len(steps)}) must match positions {positions.shape}"
        )
    with open(path, "w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow([*_MARKER_COLUMNS, *(f"{axis}_{units}" for axis in "xyz")])
        fmt = COORDINATE_FORMATS[units]
        for i, step in enumerate(steps):
            for j, label in enumerate(labels):
                xyz = positions[i, j] / LENGTH_UNITS[units]
                cells = ["" if np.isnan(v) else fmt.format(v) for v in xyz]
                writer.writerow([label, int(step), *cells])


def write_loads_csv(path: str | os.PathLike, steps: np.ndarray, pressure: np.ndarray, axial_force: np.ndarray,
                    stretch: np.ndarray) -> None:
    """Write loads, one row per step (``steps`` (n,) int; ``pressure`` Pa, ``axial_force`` N, ``stretch`` (n,)),
    as ``step,pressure_Pa,axial_force_N,stretch``: what :func:`read_loads_csv` reads back. Values are written
    with the shortest text that reads back to the same float (no digits lost); NaN force -> empty cell."""
    columns = [np.asarray(c) for c in (steps, pressure, axial_force, stretch)]
    if any(c.shape != columns[0].shape or c.ndim != 1 for c in columns):
        raise ValueError("write_loads_csv: steps, pressure, axial_force and stretch must have the same shape (n,); "
                         f"got {[c.shape for c in columns]}")
    with open(path, "w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(["step", "pressure_Pa", "axial_force_N", "stretch"])
        for step, p, f, lam in zip(*columns):
            writer.writerow([int(step), repr(float(p)), "" if np.isnan(f) else repr(float(f)), repr(float(lam))])
