"""The specimen axis: its frame and the cylindrical coordinates about it.

Frames: world frame of the rig (m). An ``Axis`` defines a specimen frame whose z axis is the
specimen axis, oriented towards the load-cell end; cylindrical coordinates (r, theta, z) are taken
in that frame. Fitting an axis to markers: ``step_axes.fit_axis`` (one cloud), ``step_axes.refit_axes``
(every step).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Axis", "MIN_MARKERS", "to_cylindrical", "wrap_angle"]

#: Fewest finite markers an axis is fitted to.
MIN_MARKERS = 12


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Wrap angles (rad) into [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


@dataclass(frozen=True)
class Axis:
    """A specimen axis in the world frame.

    Attributes
    ----------
    origin : ndarray, shape (3,)
        A point on the axis (m), at the mean axial position of the fitted markers.
    basis : ndarray, shape (3, 3)
        Rows: specimen-frame unit vectors (x', y', z') in world components; z' is the axis,
        pointing to the load-cell end.
    radius : float
        Mean distance of the fitted markers to the axis (m).
    rms : float
        RMS deviation of the marker radii from ``radius`` (m).
    """

    origin: np.ndarray
    basis: np.ndarray
    radius: float
    rms: float

    @property
    def direction(self) -> np.ndarray:
        return self.basis[2]


def _frame(direction: np.ndarray) -> np.ndarray:
    d = direction / np.linalg.norm(direction)
    helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = helper - (helper @ d) * d
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(d, x), d])


def to_cylindrical(points: np.ndarray, axis: Axis) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World points ``(..., 3)`` -> specimen cylindrical ``(r, theta, z)``, each of shape ``(...)``."""
    local = (np.asarray(points, dtype=float) - axis.origin) @ axis.basis.T
    return np.hypot(local[..., 0], local[..., 1]), np.arctan2(local[..., 1], local[..., 0]), local[..., 2]
