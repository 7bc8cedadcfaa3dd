"""DIC points from tables: VIC-3D (Correlated Solutions) CSV exports, and any CSV / NPZ with a column mapping.

VIC-3D exports one CSV per step, the same grid of points in the same row order in every file; its header has the
names quoted, after a comma and spaces (`` "X",  "Y",  "Z",``), its rows only commas (a real export:
tests/data/vic3d-export). Columns used (names as VIC-3D writes them, quoted or not, case-sensitive since ``x`` and
``X`` differ; the others, e.g. strains, are ignored):

- ``X``, ``Y``, ``Z``: the point in the reference state, in VIC-3D's world frame, ``unit`` (mm by default);
- ``U``, ``V``, ``W``: its displacement at this step, same unit (lower-case ``u``, ``v``, ``w`` are accepted when
  the upper-case ones are absent; VIC-3D's ``u``, ``v`` alone are image displacements in pixels and are ignored);
  the position at the step is X + U, Y + V, Z + W (without displacement columns, X, Y, Z as given);
- ``sigma``: the confidence interval of the match, px; ``-1`` marks a point not correlated at that step
  (its position becomes NaN; ``quality`` keeps sigma, NaN there).
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from acquisition.numbers import strict_float

from .result import DICImportError, DICPoints, length_scale

__all__ = ["parse_vic3d_csv", "read_vic3d_csv", "read_point_table", "parse_column_map", "points_from_columns"]


def _delimiter(header: str, first_row: str | None) -> str | None:
    """Of comma, semicolon, tab in the header: the first found as often in the first row, else the first found;
    None = whitespace separated (never spaces when one of them is there: VIC-3D writes ``"X",  "Y",`` in the header
    and ``1,2,`` in the rows)."""
    present = [d for d in (",", ";", "\t") if d in header]
    same = [d for d in present if first_row is not None and first_row.count(d) == header.count(d)]
    return (same or present or [None])[0]


def _rows(text: str, where: str) -> tuple[list[str], np.ndarray]:
    """Header and float rows of a comma / semicolon / whitespace separated table."""
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise DICImportError(f"{where}: empty table")
    delim = _delimiter(lines[0], lines[1] if len(lines) > 1 else None)
    if delim is None:
        table = [[c.strip('"') for c in ln.split()] for ln in lines]
    else:
        reader = csv.reader(io.StringIO("\n".join(lines)), delimiter=delim, skipinitialspace=True)
        table = [[c.strip().strip('"') for c in row] for row in reader]
    header, body = table[0], table[1:]
    try:
        values = np.array([[strict_float(c) for c in row] for row in body], dtype=float).reshape(len(body), len(header))
    except ValueError as exc:
        raise DICImportError(f"{where}: every row must hold {len(header)} numbers ({exc})") from None
    return header, values


def parse_vic3d_csv(text: str, unit: str = "mm", where: str = "VIC-3D CSV") -> tuple[np.ndarray, np.ndarray]:
    """One VIC-3D CSV export (as text) -> points (n_points, 3) m and sigma (n_points,) px, NaN where sigma = -1."""
    header, values = _rows(text, where)
    col = {name: i for i, name in enumerate(header)}
    missing = [c for c in ("X", "Y", "Z") if c not in col]
    if missing:
        raise DICImportError(f"{where}: no column {missing[0]!r} (VIC-3D exports X, Y, Z; header is {header})")
    xyz = values[:, [col["X"], col["Y"], col["Z"]]]
    for disp in (("U", "V", "W"), ("u", "v", "w")):
        if all(c in col for c in disp):
            xyz = xyz + values[:, [col[c] for c in disp]]
            break
    sigma = values[:, col["sigma"]] if "sigma" in col else np.zeros(len(values))
    bad = (sigma < 0) | ~np.isfinite(sigma)
    xyz[bad] = np.nan
    return xyz * length_scale(unit, where), np.where(bad, np.nan, sigma)


def read_vic3d_csv(paths, unit: str = "mm") -> DICPoints:
    """VIC-3D CSV exports, one file per step in the order given -> :class:`DICPoints` (``quality`` = sigma, px)."""
    paths = [Path(p) for p in ([paths] if isinstance(paths, (str, Path)) else paths)]
    if not paths:
        raise DICImportError("VIC-3D CSV: no files given")
    pts, sig = [], []
    for p in paths:
        try:
            text = p.read_text(encoding="utf-8-sig")
        except (OSError, UnicodeDecodeError) as exc:
            raise DICImportError(f"{p}: cannot read ({exc})") from None
        xyz, s = parse_vic3d_csv(text, unit, where=str(p))
        if pts and len(xyz) != len(pts[0]):
            raise DICImportError(f"{p}: {len(xyz)} points; the first step ({paths[0].name}) has {len(pts[0])}")
        pts.append(xyz)
        sig.append(s)
    return DICPoints(points=np.stack(pts), quality=np.stack(sig), quality_name="sigma (VIC-3D confidence, px)",
                     source=", ".join(map(str, paths)), step_names=tuple(p.name for p in paths))


_ROLES = ("id", "step", "x", "y", "z", "quality")


def parse_column_map(spec: str) -> dict[str, str]:
    """``"id=point,step=frame,x=X,y=Y,z=Z"`` -> {role: column}. Roles: id, step, x, y, z (required) and quality
    (optional); without ``id`` the rows of each step are the points in order, without ``step`` there is one step."""
    out = {}
    for part in filter(None, (p.strip() for p in str(spec).split(","))):
        role, sep, column = part.partition("=")
        role = role.strip().lower()
        if not sep or role not in _ROLES or not column.strip():
            raise DICImportError(f"columns: each entry must be ROLE=COLUMN with ROLE one of {list(_ROLES)}; "
                                 f"got {part!r}")
        out[role] = column.strip()
    for role in ("x", "y", "z"):
        if role not in out:
            raise DICImportError(f"columns: {role!r} is required (e.g. 'x=X,y=Y,z=Z'); got {spec!r}")
    return out


def _table(path: Path) -> dict[str, np.ndarray]:
    if path.suffix.lower() == ".npz":
        try:
            with np.load(path, allow_pickle=False) as z:
                return {k: np.asarray(z[k]).ravel() for k in z.files}
        except (OSError, ValueError) as exc:
            raise DICImportError(f"{path}: not a readable NPZ ({exc})") from None
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise DICImportError(f"{path}: cannot read ({exc})") from None
    header, values = _rows(text, str(path))
    return {name: values[:, i] for i, name in enumerate(header)}


def points_from_columns(cols: dict[str, np.ndarray], mapping: dict[str, str], unit: str, where: str) -> DICPoints:
    """Pure core of :func:`read_point_table`: named columns (equal lengths) -> :class:`DICPoints`."""
    for role, name in mapping.items():
        if name not in cols:
            raise DICImportError(f"{where}: no column {name!r} for {role} (columns: {sorted(cols)})")
    n = len(cols[mapping["x"]])
    xyz = np.stack([np.asarray(cols[mapping[r]], float) for r in ("x", "y", "z")], -1) * length_scale(unit, where)
    step = np.asarray(cols[mapping["step"]]) if "step" in mapping else np.zeros(n)
    steps, si = np.unique(step, return_inverse=True)
    if "id" in mapping:
        ids, pi = np.unique(np.asarray(cols[mapping["id"]]), return_inverse=True)
    else:
        counts = np.bincount(si)
        if counts.min() != counts.max():
            raise DICImportError(f"{where}: without an id column every step must have the same number of rows; "
                                 f"got {counts.min()} to {counts.max()}")
        order = np.argsort(si, kind="stable")
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        pi = np.empty(n, dtype=np.int64)
        pi[order] = np.arange(n) - starts[si[order]]
        ids = np.arange(counts.max())
    key = si * len(ids) + pi
    if len(np.unique(key)) != n:
        raise DICImportError(f"{where}: a point appears twice in one step")
    pts = np.full((len(steps), len(ids), 3), np.nan)
    pts[si, pi] = xyz
    quality = None
    if "quality" in mapping:
        quality = np.full((len(steps), len(ids)), np.nan)
        quality[si, pi] = np.asarray(cols[mapping["quality"]], float)
    return DICPoints(points=pts, quality=quality, quality_name=mapping.get("quality", ""), source=where,
                     step_names=tuple(f"{s:g}" if isinstance(s, np.floating) else str(s) for s in steps))


def read_point_table(path, columns: str, unit: str = "mm") -> DICPoints:
    """A CSV (header row; comma, semicolon, tab or space separated) or NPZ (one 1-D array per column) of points,
    one row per point and step, mapped by ``columns`` (:func:`parse_column_map`) and converted from ``unit``.

    Steps are ordered by their value in the step column, points by id; a point missing at a step is NaN there.
    """
    path = Path(path)
    if not path.is_file():
        raise DICImportError(f"{path}: no such file")
    return points_from_columns(_table(path), parse_column_map(columns), unit, str(path))
