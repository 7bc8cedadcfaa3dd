"""Flat-window refraction: cameras in air looking into the bath through a flat glass window.

Everything here is in the camera frame of one camera (optical centre at the origin). The window
is a glass plate between the planes ``w . x = distance`` (air/glass) and
``w . x = distance + thickness`` (glass/water), ``w`` its unit normal pointing into the bath.
Snell's law keeps the ray in the plane spanned by ``w`` and the point, with the invariant
``n_air sin(a_air) = n_glass sin(a_glass) = n_water sin(a_water)``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from reconstruction import Camera, Window

__all__ = ["FlatWindow", "tilted_window", "project_refracted", "rays_in_water"]


@dataclass(frozen=True)
class FlatWindow:
    """A flat window in front of one camera (camera frame, metres).

    Attributes
    ----------
    normal : ndarray, shape (3,)
        Unit normal pointing into the bath, camera frame.
    distance : float
        Distance of the air/glass plane from the optical centre, m.
    thickness : float
        Glass thickness, m.
    n_air, n_glass, n_water : float
        Refractive indices.
    """

    normal: np.ndarray
    distance: float = 0.08
    thickness: float = 3e-3
    n_air: float = 1.0
    n_glass: float = 1.52
    n_water: float = 1.333

    def __post_init__(self) -> None:
        w = np.asarray(self.normal, float).reshape(3)
        norm = np.linalg.norm(w)
        if not norm > 0:
            raise ValueError(f"FlatWindow.normal must be a non-zero 3-vector; got {self.normal}")
        object.__setattr__(self, "normal", w / norm)

    def to_window(self, camera: Camera) -> Window:
        """The same window as a world-frame :class:`reconstruction.refraction.Window` for ``camera``."""
        nw = camera.R.T @ self.normal
        return Window(nw, self.distance + nw @ camera.center, (self.thickness,), (self.n_glass,), self.n_water, self.n_air)


def tilted_window(tilt: float, *, azimuth: float = 0.0, **kwargs) -> FlatWindow:
    """Window whose normal is the optical axis tilted by ``tilt`` rad towards image direction ``azimuth`` (rad)."""
    w = np.array([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), np.cos(tilt)])
    return FlatWindow(w, **kwargs)


def project_refracted(camera: Camera, window: FlatWindow, points: np.ndarray) -> np.ndarray:
    """Pixels ``(..., 2)`` of world points ``(..., 3)`` in the bath seen through ``window``.

    Points not beyond the window give NaN. The physics is the reconstruction's own
    (:class:`reconstruction.refraction.Window`), so simulator and reconstruction share one model.
    """
    return replace(camera, window=window.to_window(camera)).project(points)


def rays_in_water(camera: Camera, window: FlatWindow, normalised: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rays in the bath for undistorted normalised image coordinates ``(..., 2)``.

    Returns
    -------
    origins : ndarray, shape (..., 3)
        Exit points on the glass/water plane, camera frame, m.
    directions : ndarray, shape (..., 3)
        Unit directions in water, camera frame.
    """
    xy = np.asarray(normalised, float)
    d = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], -1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    w = window.normal
    origin = np.zeros_like(d)
    n_prev = window.n_air
    for plane, n_next in ((window.distance, window.n_glass), (window.distance + window.thickness, window.n_water)):
        cos_i = d @ w
        t = (plane - origin @ w) / cos_i
        origin = origin + t[..., None] * d
        r = n_prev / n_next
        cos_t = np.sqrt(1 - r * r * (1 - cos_i**2))
        d = r * d + (cos_t - r * cos_i)[..., None] * w
        n_prev = n_next
    return origin, d
