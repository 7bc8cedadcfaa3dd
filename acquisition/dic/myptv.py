"""MyPTV's calibration point pairs (``camN_cal_points``, github.com/ronshnapp/MyPTV): one row per dot, whitespace
separated ``x y X Y Z``: the dot's image position (px, MyPTV's pixel coordinates, taken as OpenCV's) and its position
on the calibration target (mm, the target's frame). MyPTV's ``target_file`` lists the target's dots as ``X Y Z`` (mm).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .result import DICImportError, length_scale

__all__ = ["parse_myptv_cal_points", "read_myptv_cal_points", "read_myptv_target"]


def _numbers(text: str, width: int, where: str) -> np.ndarray:
    rows = [ln.split() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    bad = next((i for i, r in enumerate(rows) if len(r) != width), None)
    if bad is not None:
        raise DICImportError(f"{where}: line {bad + 1} has {len(rows[bad])} fields; expected {width}")
    try:
        return np.array(rows, dtype=float).reshape(len(rows), width)
    except ValueError as exc:
        raise DICImportError(f"{where}: not numbers ({exc})") from None


def parse_myptv_cal_points(text: str, unit: str = "mm", where: str = "cal_points") -> tuple[np.ndarray, np.ndarray]:
    """``x y X Y Z`` rows -> pixels (n, 2) px and target points (n, 3) m."""
    values = _numbers(text, 5, where)
    return values[:, :2], values[:, 2:] * length_scale(unit, where)


def read_myptv_cal_points(path, unit: str = "mm") -> tuple[np.ndarray, np.ndarray]:
    """A MyPTV ``camN_cal_points`` file -> pixels (n, 2) px and target points (n, 3) m."""
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise DICImportError(f"{path}: cannot read ({exc})") from None
    return parse_myptv_cal_points(text, unit, str(path))


def read_myptv_target(path, unit: str = "mm") -> np.ndarray:
    """A MyPTV ``target_file`` (``X Y Z`` rows) -> the target's dots (n, 3), m."""
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise DICImportError(f"{path}: cannot read ({exc})") from None
    return _numbers(text, 3, str(path)) * length_scale(unit, str(path))
