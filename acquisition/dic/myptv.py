"""MyPTV's files (github.com/ronshnapp/MyPTV), whitespace-separated numbers, one row per item.

- ``camN_cal_points``: one row per dot, ``x y X Y Z``: the dot's image position (px, OpenCV's pixel coordinates: x =
  column, y = row, 0-based, integers at pixel centres) and its position on the calibration target (mm, the target's
  frame). ``target_file`` lists the target's dots as ``X Y Z`` (mm).
- ``blobs_camN`` (MyPTV's segmentation): ``row column size_row size_column mass frame``: the blob's centre is the
  brightness-weighted mean of its pixels' (row, column) indices. MyPTV's matching swaps the first two columns
  (``reverse_eta_zeta=True`` in its workflow) to meet the calibration's (x, y); so does :func:`parse_myptv_blobs`.
  Within a frame, blobs are numbered 0, 1, ... in file order (the numbers a particles file refers to).
- ``particles`` (MyPTV's matching): ``X Y Z i_1 ... i_n error frame``: the particle (mm, the calibration's lab
  frame), the blob it uses in each camera (-1 = none), MyPTV's matching uncertainty (mm) and the frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .result import DICImportError, length_scale

__all__ = ["MyPTVParticles", "parse_myptv_blobs", "parse_myptv_cal_points", "parse_myptv_particles",
           "read_myptv_blobs", "read_myptv_cal_points", "read_myptv_particles", "read_myptv_target"]


@dataclass(frozen=True)
class MyPTVParticles:
    """MyPTV's matched particles (a ``particles`` file).

    Attributes
    ----------
    points : ndarray, shape (n, 3)
        Particle positions, m (the calibration's lab frame).
    blobs : ndarray of int, shape (n, n_cameras)
        The blob each particle uses in each camera: its 0-based index among that frame's blobs, -1 = none.
    error : ndarray, shape (n,)
        MyPTV's matching uncertainty, m.
    frames : ndarray of int, shape (n,)
    """

    points: np.ndarray
    blobs: np.ndarray
    error: np.ndarray
    frames: np.ndarray


def _numbers(text: str, width: int, where: str, *, at_least: bool = False) -> np.ndarray:
    """Rows of ``width`` numbers (``at_least``: ``width`` or more, all rows alike) -> (n, width or more)."""
    rows = [ln.split() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if at_least and rows and len(rows[0]) >= width:
        width = len(rows[0])
    bad = next((i for i, r in enumerate(rows) if len(r) != width), None)
    if bad is not None:
        raise DICImportError(f"{where}: line {bad + 1} has {len(rows[bad])} fields; expected {width}")
    try:
        return np.array(rows, dtype=float).reshape(len(rows), width)
    except ValueError as exc:
        raise DICImportError(f"{where}: not numbers ({exc})") from None


def _read_text(path: Path) -> str:
    try:
        return path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise DICImportError(f"{path}: cannot read ({exc})") from None


def _frame_numbers(column: np.ndarray, where: str) -> np.ndarray:
    if not np.all(np.isfinite(column) & (column == np.round(column)) & (column >= 0)):
        raise DICImportError(f"{where}: the frame column must hold whole numbers >= 0")
    return column.astype(np.int64)


def parse_myptv_cal_points(text: str, unit: str = "mm", where: str = "cal_points") -> tuple[np.ndarray, np.ndarray]:
    """``x y X Y Z`` rows -> pixels (n, 2) px and target points (n, 3) m."""
    values = _numbers(text, 5, where)
    return values[:, :2], values[:, 2:] * length_scale(unit, where)


def read_myptv_cal_points(path, unit: str = "mm") -> tuple[np.ndarray, np.ndarray]:
    """A MyPTV ``camN_cal_points`` file -> pixels (n, 2) px and target points (n, 3) m."""
    path = Path(path)
    return parse_myptv_cal_points(_read_text(path), unit, str(path))


def read_myptv_target(path, unit: str = "mm") -> np.ndarray:
    """A MyPTV ``target_file`` (``X Y Z`` rows) -> the target's dots (n, 3), m."""
    path = Path(path)
    return _numbers(_read_text(path), 3, str(path)) * length_scale(unit, str(path))


def parse_myptv_blobs(text: str, where: str = "blobs") -> dict[int, np.ndarray]:
    """``row column size_row size_column mass frame`` rows -> {frame: blob centres (n, 2) px as (x = column,
    y = row)}, each frame's blobs in file order."""
    values = _numbers(text, 6, where, at_least=True)
    frames = _frame_numbers(values[:, 5], where)
    return {int(f): values[frames == f][:, 1::-1].copy() for f in np.unique(frames)}


def read_myptv_blobs(path) -> dict[int, np.ndarray]:
    """A MyPTV ``blobs_camN`` file -> {frame: blob centres (n, 2) px (x, y), file order}."""
    path = Path(path)
    return parse_myptv_blobs(_read_text(path), str(path))


def parse_myptv_particles(text: str, n_cameras: int, unit: str = "mm", where: str = "particles") -> MyPTVParticles:
    """``X Y Z i_1 ... i_n error frame`` rows (``n = n_cameras``) -> :class:`MyPTVParticles` (m)."""
    if int(n_cameras) < 2:
        raise DICImportError(f"{where}: n_cameras must be >= 2; got {n_cameras}")
    n = int(n_cameras)
    values = _numbers(text, n + 5, where)
    idx = values[:, 3:3 + n]
    if not np.all((idx == np.round(idx)) & (idx >= -1)):
        raise DICImportError(f"{where}: columns 4-{n + 3} must be blob numbers (whole, -1 = none)")
    scale = length_scale(unit, where)
    return MyPTVParticles(values[:, :3] * scale, idx.astype(np.int64), values[:, n + 3] * scale,
                          _frame_numbers(values[:, n + 4], where))


def read_myptv_particles(path, n_cameras: int, unit: str = "mm") -> MyPTVParticles:
    """A MyPTV ``particles`` file of ``n_cameras`` cameras -> :class:`MyPTVParticles` (m)."""
    path = Path(path)
    return parse_myptv_particles(_read_text(path), n_cameras, unit, str(path))
