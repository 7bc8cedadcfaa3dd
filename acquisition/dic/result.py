"""What every DIC reader returns: 3-D points per step in metres, and the typed error of a bad file.

Frames and units (``docs/decisions/0001-units.md``, ``0002-frames-and-shapes.md``): points are in the frame the
other lab's software reported them in (DuoDIC/MultiDIC: camera 1's frame; VIC-3D: its own reference frame), converted
to metres; nothing is rotated. A point index means the same material point at every step (DIC tracks a fixed grid or
mesh); NaN marks a point not measured at a step.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["DICImportError", "DICPoints", "LENGTH_UNITS", "length_scale"]

#: length unit -> metres
LENGTH_UNITS = {"m": 1.0, "mm": 1e-3, "um": 1e-6}


class DICImportError(ValueError):
    """A DIC result or calibration file cannot be read: the message names the file and what is wrong."""


def length_scale(unit: str, where: str) -> float:
    """Metres per ``unit`` (``"m"``, ``"mm"`` or ``"um"``); DICImportError naming ``where`` otherwise."""
    key = str(unit).strip().lower().replace("µ", "u")
    if key not in LENGTH_UNITS:
        raise DICImportError(f"{where}: unit must be one of {sorted(LENGTH_UNITS)}; got {unit!r}")
    return LENGTH_UNITS[key]


@dataclass(frozen=True)
class DICPoints:
    """3-D DIC points of one test, one row per step.

    Attributes
    ----------
    points : ndarray, shape (n_steps, n_points, 3)
        Positions, m (the reader converts the file's unit); NaN where a point is missing at a step.
    quality : ndarray, shape (n_steps, n_points), or None
        The source's per-point match quality, in its own meaning (``quality_name``; NaN where missing).
    triangles : ndarray, shape (n_triangles, 3), int, or None
        0-based point indices of the source's surface mesh, if it has one.
    quality_name : str
        What ``quality`` is, e.g. ``"corrComb (DuoDIC combined correlation cost, lower is better)"``.
    source : str
        The file (or files) read.
    step_names : tuple of str
        One label per step (file names for per-step exports, ``"0".."n-1"`` otherwise).
    """

    points: np.ndarray
    quality: np.ndarray | None = None
    triangles: np.ndarray | None = None
    quality_name: str = ""
    source: str = ""
    step_names: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        pts = np.asarray(self.points, dtype=float)
        if pts.ndim != 3 or pts.shape[-1] != 3:
            raise DICImportError(f"{self.source}: points must have shape (n_steps, n_points, 3); got {pts.shape}")
        object.__setattr__(self, "points", pts)
        if self.quality is not None:
            q = np.asarray(self.quality, dtype=float)
            if q.shape != pts.shape[:2]:
                raise DICImportError(f"{self.source}: quality must have shape {pts.shape[:2]}; got {q.shape}")
            object.__setattr__(self, "quality", q)
        if self.triangles is not None:
            tri = np.asarray(self.triangles)
            if tri.ndim != 2 or tri.shape[1] != 3 or (tri.size and (tri.min() < 0 or tri.max() >= pts.shape[1])):
                raise DICImportError(f"{self.source}: triangles must be (n_triangles, 3) indices into "
                                     f"{pts.shape[1]} points; got shape {tri.shape}")
            object.__setattr__(self, "triangles", tri.astype(np.int64))
        names = tuple(self.step_names) or tuple(str(i) for i in range(pts.shape[0]))
        if len(names) != pts.shape[0]:
            raise DICImportError(f"{self.source}: {len(names)} step names for {pts.shape[0]} steps")
        object.__setattr__(self, "step_names", names)

    @property
    def n_steps(self) -> int:
        return self.points.shape[0]

    @property
    def n_points(self) -> int:
        return self.points.shape[1]

    def displacements(self, reference: int = 0) -> np.ndarray:
        """Displacement of every point from step ``reference``, shape (n_steps, n_points, 3), m (NaN propagates)."""
        return self.points - self.points[reference]
