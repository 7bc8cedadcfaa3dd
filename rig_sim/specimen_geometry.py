"""Geometry of the simulated specimen for rendering: a surface of revolution with markers on it.

An analytic deforming cylinder stands in for the mechanics simulator: any source that gives
marker surface points, outward normals and a profile ``r(z)`` per step can be rendered.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SurfaceOfRevolution", "MarkerLayout", "random_marker_layout", "deform_cylinder"]


@dataclass(frozen=True)
class SurfaceOfRevolution:
    """Outer wall of the specimen as a profile ``r(z)`` around the world z axis.

    Attributes
    ----------
    z : ndarray, shape (n,)
        Strictly increasing axial stations, m. The tube exists for ``z[0] <= z <= z[-1]``.
    r : ndarray, shape (n,)
        Outer radius at each station, m.
    """

    z: np.ndarray
    r: np.ndarray

    def __post_init__(self) -> None:
        z = np.asarray(self.z, float).ravel()
        r = np.asarray(self.r, float).ravel()
        if z.shape != r.shape or z.size < 2:
            raise ValueError(f"SurfaceOfRevolution: z and r must be 1-D of equal length >= 2; got {z.shape}, {r.shape}")
        if np.any(np.diff(z) <= 0):
            raise ValueError("SurfaceOfRevolution: z must be strictly increasing")
        object.__setattr__(self, "z", z)
        object.__setattr__(self, "r", r)

    @classmethod
    def cylinder(cls, radius: float, length: float) -> "SurfaceOfRevolution":
        """A straight tube of ``radius`` (m) and ``length`` (m) centred on the origin."""
        return cls(np.array([-length / 2, length / 2]), np.array([radius, radius]))

    @property
    def z_min(self) -> float:
        return float(self.z[0])

    @property
    def z_max(self) -> float:
        return float(self.z[-1])

    def radius(self, z: np.ndarray) -> np.ndarray:
        """r(z), m; clamped to the end values outside the tube."""
        return np.interp(z, self.z, self.r)

    def slope(self, z: np.ndarray) -> np.ndarray:
        """dr/dz (dimensionless), piecewise constant between stations."""
        dr = np.diff(self.r) / np.diff(self.z)
        idx = np.clip(np.searchsorted(self.z, z, side="right") - 1, 0, dr.size - 1)
        return dr[idx]

    def normals(self, points: np.ndarray) -> np.ndarray:
        """Outward unit normals ``(..., 3)`` at wall points ``(..., 3)``."""
        p = np.asarray(points, float)
        theta = np.arctan2(p[..., 1], p[..., 0])
        n = np.stack([np.cos(theta), np.sin(theta), -self.slope(p[..., 2])], -1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)


@dataclass(frozen=True)
class MarkerLayout:
    """Reference (undeformed) marker positions on a cylinder, in surface coordinates.

    Attributes
    ----------
    theta : ndarray, shape (n_markers,)
        Circumferential angle, rad.
    Z : ndarray, shape (n_markers,)
        Axial position in the reference state, m.
    radius, length : float
        Reference outer radius and free length, m.
    """

    theta: np.ndarray
    Z: np.ndarray
    radius: float
    length: float

    @property
    def n_markers(self) -> int:
        return int(self.theta.size)


def random_marker_layout(
    n_markers: int = 300,
    radius: float = 0.010,
    length: float = 0.035,
    *,
    margin: float = 0.002,
    min_spacing: float | None = None,
    seed: int = 0,
) -> MarkerLayout:
    """Markers scattered over the cylinder with a minimum spacing (Poisson-disc like).

    Parameters
    ----------
    n_markers : int
    radius, length : float
        Reference outer radius and length, m.
    margin : float
        Marker-free band at each end, m.
    min_spacing : float, optional
        Minimum centre distance along the surface, m; default 0.7 x the mean spacing.
    seed : int
    """
    rng = np.random.default_rng(seed)
    area = 2 * np.pi * radius * (length - 2 * margin)
    if min_spacing is None:
        min_spacing = 0.7 * np.sqrt(area / n_markers)
    theta = np.empty(0)
    Z = np.empty(0)
    for _ in range(200):
        cand_t = rng.uniform(-np.pi, np.pi, 4 * n_markers)
        cand_z = rng.uniform(-length / 2 + margin, length / 2 - margin, 4 * n_markers)
        for t, z in zip(cand_t, cand_z):
            if theta.size >= n_markers:
                break
            dt = np.abs((theta - t + np.pi) % (2 * np.pi) - np.pi) * radius
            if theta.size == 0 or np.min(dt * dt + (Z - z) ** 2) >= min_spacing**2:
                theta = np.append(theta, t)
                Z = np.append(Z, z)
        if theta.size >= n_markers:
            break
    if theta.size < n_markers:
        raise ValueError(f"random_marker_layout: could place only {theta.size} of {n_markers} markers; lower min_spacing")
    return MarkerLayout(theta, Z, float(radius), float(length))


def deform_cylinder(
    layout: MarkerLayout, stretch_theta: np.ndarray, stretch_z: np.ndarray, *, bulge: float = 0.0, n_profile: int = 65
) -> tuple[np.ndarray, np.ndarray, list[SurfaceOfRevolution]]:
    """Analytic deforming tube: homogeneous stretches with an optional mid-length bulge.

    ``r(Z) = R * lam_theta * (1 + bulge * cos(pi Z / L))``, ``z = lam_z * Z``.

    Parameters
    ----------
    layout : MarkerLayout
    stretch_theta, stretch_z : ndarray, shape (n_steps,)
        Circumferential and axial stretch per step.
    bulge : float
        Relative amplitude of a smooth radial bulge (0 = straight tube).

    Returns
    -------
    points : ndarray, shape (n_steps, n_markers, 3)
        Marker positions ON the wall (m).
    normals : ndarray, shape (n_steps, n_markers, 3)
        Outward unit normals.
    profiles : list of SurfaceOfRevolution, length n_steps
    """
    lt = np.atleast_1d(np.asarray(stretch_theta, float))
    lz = np.atleast_1d(np.asarray(stretch_z, float))
    if lt.shape != lz.shape:
        raise ValueError(f"deform_cylinder: stretch arrays must match; got {lt.shape} and {lz.shape}")
    R, L = layout.radius, layout.length
    Zp = np.linspace(-L / 2, L / 2, n_profile)
    points, normals, profiles = [], [], []
    for a, b in zip(lt, lz):
        prof = SurfaceOfRevolution(b * Zp, R * a * (1 + bulge * np.cos(np.pi * Zp / L)))
        r = R * a * (1 + bulge * np.cos(np.pi * layout.Z / L))
        p = np.stack([r * np.cos(layout.theta), r * np.sin(layout.theta), b * layout.Z], -1)
        drdz = -R * a * bulge * np.pi / L * np.sin(np.pi * layout.Z / L) / b
        n = np.stack([np.cos(layout.theta), np.sin(layout.theta), -drdz], -1)
        points.append(p)
        normals.append(n / np.linalg.norm(n, axis=-1, keepdims=True))
        profiles.append(prof)
    return np.array(points), np.array(normals), profiles
