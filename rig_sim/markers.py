"""Quasi-uniform placement of markers on the reference cylinder (seeded best-candidate sampling).

Markers are placed in reference cylindrical coordinates (theta, Z) on the marker surface of radius R, uniformly in
area, with Mitchell's best-candidate algorithm (blue noise): each new marker is the candidate farthest from those
already placed, distances measured on the unrolled surface (arc length R theta, periodic, and Z). This leaves no
near-duplicates, so a Delaunay mesh of the markers has no slivers caused by the layout itself.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["place_markers", "min_marker_spacing"]


def _periodic_d2(s, z, s_pts, z_pts, period):
    ds = np.abs(s[:, None] - s_pts[None, :])
    ds = np.minimum(ds, period - ds)
    dz = z[:, None] - z_pts[None, :]
    return ds * ds + dz * dz


def place_markers(n_markers: int, radius: float, z_min: float, z_max: float, *, seed: int = 0,
                  n_candidates: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """Place markers on the reference cylinder surface.

    Parameters
    ----------
    n_markers : int
        Number of markers (>= 1).
    radius : float, m
        Reference radius of the marker surface.
    z_min, z_max : float, m
        Axial extent (reference Z) of the marked region, z_min < z_max.
    seed : int
        Seed of the generator (deterministic layout).
    n_candidates : int
        Candidates per marker; more gives a more even layout.

    Returns
    -------
    theta : ndarray, shape (n_markers,), rad in [0, 2 pi)
    Z : ndarray, shape (n_markers,), m
    """
    if int(n_markers) != n_markers or n_markers < 1:
        raise ValueError(f"n_markers must be a positive integer; got {n_markers!r}")
    if not z_max > z_min:
        raise ValueError(f"z_max must exceed z_min; got z_min={z_min!r}, z_max={z_max!r}")
    n_markers = int(n_markers)
    rng = np.random.default_rng(seed)
    period = 2.0 * math.pi * radius
    s = np.empty(n_markers)
    z = np.empty(n_markers)
    s[0] = rng.uniform(0.0, period)
    z[0] = rng.uniform(z_min, z_max)
    for i in range(1, n_markers):
        cs = rng.uniform(0.0, period, n_candidates)
        cz = rng.uniform(z_min, z_max, n_candidates)
        d2 = _periodic_d2(cs, cz, s[:i], z[:i], period).min(axis=1)
        k = int(np.argmax(d2))
        s[i], z[i] = cs[k], cz[k]
    return s / radius, z


def min_marker_spacing(theta: np.ndarray, Z: np.ndarray, radius: float) -> float:
    """Smallest distance [m] between two markers on the unrolled reference surface (periodic in theta)."""
    s = np.asarray(theta) * radius
    d2 = _periodic_d2(s, np.asarray(Z), s, np.asarray(Z), 2.0 * math.pi * radius)
    np.fill_diagonal(d2, np.inf)
    return float(np.sqrt(d2.min()))
