"""Flat multi-layer window between a camera in air and the bath: exact Snell refraction, vectorised.

A :class:`Window` is a stack of flat parallel layers, described in the world frame (metres): the
first surface (air side) is the plane ``normal . X = offset``; ``normal`` is a unit vector pointing
from the camera into the bath; the layers (``thicknesses``, ``indices``) follow, and the last
medium (``n_bath``) fills everything beyond. The camera sits in a medium of index ``n_air``.

Snell's law keeps a refracted ray in the plane spanned by the normal and the point, with the
invariant ``s = n_k sin(a_k)`` equal in every medium. For a point at depth ``h`` (along the normal,
from the optical centre) and radial offset ``rho``, the ray with invariant ``s`` reaches

    rho(s) = sum_k L_k s / sqrt(n_k^2 - s^2),   L = (D, t_1, ..., t_m, h - D - sum t)

which increases and is convex in ``s``: Newton's method from above converges monotonically. All
points are solved at once (batched Newton), to machine precision.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Window", "refracted_directions", "window_rays", "solve_invariant"]


@dataclass(frozen=True)
class Window:
    """A flat window of one or more layers, world frame.

    Attributes
    ----------
    normal : ndarray, shape (3,)
        Unit normal of the layers pointing from the camera into the bath (world frame).
    offset : float
        The first (air-side) surface is ``normal . X = offset``, m.
    thicknesses : tuple of float
        Layer thicknesses, m (e.g. ``(0.006,)`` for one glass plate).
    indices : tuple of float
        Refractive index of each layer (same length as ``thicknesses``).
    n_bath : float
        Refractive index of the medium beyond the last layer (water).
    n_air : float
        Refractive index on the camera side.
    """

    normal: np.ndarray
    offset: float
    thicknesses: tuple = (0.006,)
    indices: tuple = (1.52,)
    n_bath: float = 1.333
    n_air: float = 1.0

    def __post_init__(self) -> None:
        w = np.asarray(self.normal, dtype=float).reshape(-1)
        if w.size != 3 or not np.linalg.norm(w) > 0 or not np.all(np.isfinite(w)):
            raise ValueError(f"Window.normal must be a finite non-zero 3-vector; got {self.normal!r}")
        t = tuple(float(v) for v in np.atleast_1d(self.thicknesses))
        n = tuple(float(v) for v in np.atleast_1d(self.indices))
        if len(t) != len(n):
            raise ValueError(f"Window: thicknesses and indices must have the same length; got {len(t)} and {len(n)}")
        if any(not (v >= 0) for v in t):
            raise ValueError(f"Window.thicknesses must be >= 0 m; got {t}")
        if any(not (v >= 1.0) for v in (*n, self.n_bath, self.n_air)):
            raise ValueError(f"Window refractive indices must be >= 1; got layers {n}, bath {self.n_bath}, air {self.n_air}")
        if not np.isfinite(self.offset):
            raise ValueError(f"Window.offset must be finite (m); got {self.offset}")
        object.__setattr__(self, "normal", w / np.linalg.norm(w))
        object.__setattr__(self, "offset", float(self.offset))
        object.__setattr__(self, "thicknesses", t)
        object.__setattr__(self, "indices", n)
        object.__setattr__(self, "n_bath", float(self.n_bath))
        object.__setattr__(self, "n_air", float(self.n_air))

    @property
    def total_thickness(self) -> float:
        """Sum of the layer thicknesses, m."""
        return float(sum(self.thicknesses))

    @property
    def is_void(self) -> bool:
        """True when every index equals ``n_air``: the window bends nothing."""
        return all(n == self.n_air for n in (*self.indices, self.n_bath))

    def distance_from(self, center: np.ndarray) -> float:
        """Distance (m) from a camera centre ``(3,)`` to the first surface along the normal."""
        return float(self.offset - self.normal @ np.asarray(center, dtype=float))

    def with_offset(self, offset: float) -> "Window":
        """A copy moved along its normal to ``offset`` (m)."""
        return Window(self.normal, offset, self.thicknesses, self.indices, self.n_bath, self.n_air)

    def to_dict(self) -> dict:
        """Plain dict (SI units) for files and session attributes."""
        return {
            "normal": [float(v) for v in self.normal], "offset_m": self.offset,
            "thicknesses_m": list(self.thicknesses), "indices": list(self.indices),
            "n_bath": self.n_bath, "n_air": self.n_air,
        }

    @classmethod
    def from_dict(cls, d: dict) -> "Window":
        """Inverse of :meth:`to_dict`."""
        return cls(np.asarray(d["normal"], float), float(d["offset_m"]), tuple(d["thicknesses_m"]),
                   tuple(d["indices"]), float(d.get("n_bath", 1.333)), float(d.get("n_air", 1.0)))


def _layers(window: Window, distance: float) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(m+2,)`` and fixed lengths ``(m+1,)`` (air gap, layers) of the stack."""
    n = np.array([window.n_air, *window.indices, window.n_bath])
    lengths = np.array([distance, *window.thicknesses])
    return n, lengths


def solve_invariant(n: np.ndarray, lengths: np.ndarray, depth: np.ndarray, rho: np.ndarray,
                    *, max_iterations: int = 60) -> np.ndarray:
    """Snell invariant ``s`` of the ray reaching radial offset ``rho`` at ``depth`` (batched Newton).

    Parameters
    ----------
    n : ndarray, shape (m+2,)
        Indices: camera medium, layers, bath.
    lengths : ndarray, shape (m+1,)
        Path depths (along the normal) of the camera medium and the layers, m.
    depth, rho : ndarray, shape (...)
        Point depth along the normal and radial offset from the normal through the centre, m;
        ``depth`` must exceed ``sum(lengths)`` (points in the bath).

    Returns
    -------
    ndarray, shape (...)
        ``s`` in ``[0, min(n))``.
    """
    depth = np.asarray(depth, dtype=float)
    rho = np.asarray(rho, dtype=float)
    L = np.concatenate([np.broadcast_to(lengths, depth.shape + lengths.shape),
                        (depth - lengths.sum())[..., None]], axis=-1)  # (..., m+2)
    n_min, n_max = float(n.min()), float(n.max())
    # start above the root: f(s) >= depth s / sqrt(n_max^2 - s^2), so this s gives f >= rho;
    # f is increasing and convex, hence Newton from above descends monotonically onto the root.
    s = n_max * rho / np.maximum(np.hypot(rho, depth), 1e-300)
    s = np.clip(s, 0.0, n_min * (1 - 1e-15))
    for _ in range(max_iterations):
        cos_term = np.sqrt(n**2 - s[..., None] ** 2)  # (..., m+2) = n_k cos a_k
        f = np.sum(L * s[..., None] / cos_term, axis=-1) - rho
        df = np.sum(L * n**2 / cos_term**3, axis=-1)
        step = f / df
        s_new = np.clip(s - step, 0.0, n_min * (1 - 1e-15))
        done = np.all(np.abs(s_new - s) <= 1e-14)
        s = s_new
        if done:
            break
    return s


def refracted_directions(window: Window, R: np.ndarray, center: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Air-side ray directions (camera frame) towards world points seen through ``window``.

    Parameters
    ----------
    window : Window
    R : ndarray, shape (3, 3)
        World -> camera rotation.
    center : ndarray, shape (3,)
        Optical centre, world frame, m.
    points : ndarray, shape (..., 3)
        World points, m.

    Returns
    -------
    directions : ndarray, shape (..., 3)
        Unit directions in the camera frame of the ray leaving the camera; the pinhole projection of
        these gives the pixel.
    beyond : ndarray of bool, shape (...)
        True for points beyond the last surface (in the bath); others should be NaN.
    """
    pts = np.asarray(points, dtype=float)
    w = window.normal
    D = window.distance_from(center)
    v = pts - center
    h = v @ w
    radial = v - h[..., None] * w
    rho = np.linalg.norm(radial, axis=-1)
    u = radial / np.where(rho > 0, rho, 1.0)[..., None]
    beyond = (h > D + window.total_thickness) & (D > 0)
    hh = np.where(beyond, h, D + window.total_thickness + 1.0)
    n, lengths = _layers(window, max(D, 0.0))
    s = solve_invariant(n, lengths, hh, np.where(beyond, rho, 0.0))
    sin_a = s / window.n_air
    d_world = np.sqrt(1.0 - sin_a**2)[..., None] * w + sin_a[..., None] * u
    return d_world @ R.T, beyond


def _refract(d: np.ndarray, w: np.ndarray, n1: float, n2: float) -> np.ndarray:
    """Unit directions ``(..., 3)`` after crossing a plane of normal ``w`` from index n1 into n2."""
    cos_i = d @ w
    r = n1 / n2
    cos_t = np.sqrt(np.maximum(1.0 - r * r * (1.0 - cos_i**2), 0.0))
    return r * d + (cos_t - r * cos_i)[..., None] * w


def window_rays(window: Window, center: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rays in the bath for air-side rays from ``center`` with world directions ``(..., 3)``.

    Returns
    -------
    origins : ndarray, shape (..., 3)
        Points where the rays enter the bath (last surface), world frame, m.
    directions : ndarray, shape (..., 3)
        Unit directions in the bath, world frame.
    """
    d = np.asarray(directions, dtype=float)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    w = window.normal
    origin = np.broadcast_to(np.asarray(center, dtype=float), d.shape).copy()
    plane = window.offset
    n_prev = window.n_air
    for thickness, n_next in zip((0.0, *window.thicknesses), (*window.indices, window.n_bath)):
        plane = plane + thickness
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (plane - origin @ w) / (d @ w)
        origin = origin + t[..., None] * d
        d = _refract(d, w, n_prev, n_next)
        n_prev = n_next
    return origin, d
