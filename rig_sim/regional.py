"""Axially varying material for the clamped-tube ground truth: a local stress multiplier m(Z).

The local law is m(Z) times the reference law's stresses: for Fung and Delfino a local beta(Z) = m(Z) beta with
the dimensionless alphas unchanged (for HGO both c and k1 scale). ``AxialProfile`` is a frozen, hashable callable,
so simulations with it are cached like homogeneous ones.

    m(Z) = (1 + gradient Z) (1 - depth w(Z)),
    w(Z) = [tanh((Z - center + width/2) / edge) - tanh((Z - center - width/2) / edge)] / 2

w is a smoothed box (1 inside the weakened zone of reference length ``width`` centred at ``center``, 0 far from
it, edges of length scale ``edge``); Z is the reference axial coordinate of the rig frame (0 mid-specimen).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["AxialProfile"]


@dataclass(frozen=True)
class AxialProfile:
    """Local stress multiplier along the reference axis.

    Attributes
    ----------
    depth : float
        Fractional weakening inside the zone (0.4: the stresses, hence beta, reduced by 40 %); in [0, 1).
    center, width, edge : float, m
        Centre and reference length of the weakened zone, and the length scale of its smoothed edges.
    gradient : float, 1/m
        Linear stiffness gradient: m = 1 + gradient Z outside the zone (Z in m, 0 mid-specimen).
    """

    depth: float = 0.0
    center: float = 0.0
    width: float = 8.75e-3
    edge: float = 0.5e-3
    gradient: float = 0.0

    def __post_init__(self) -> None:
        if not (0.0 <= self.depth < 1.0):
            raise ValueError(f"depth must be a fraction in [0, 1); got {self.depth!r}")
        for name in ("width", "edge"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive length in m; got {v!r}")
        for name in ("center", "gradient"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name} must be finite; got {getattr(self, name)!r}")

    def window(self, Z) -> np.ndarray:
        """Smoothed indicator w(Z) of the weakened zone, same shape as ``Z`` (m)."""
        z = np.asarray(Z, dtype=float) - self.center
        h = 0.5 * self.width
        return 0.5 * (np.tanh((z + h) / self.edge) - np.tanh((z - h) / self.edge))

    def __call__(self, Z) -> np.ndarray:
        """m(Z) for reference Z (n,) m; shape (n,)."""
        z = np.asarray(Z, dtype=float)
        return (1.0 + self.gradient * z) * (1.0 - self.depth * self.window(z))

    def band_mean(self, edges) -> np.ndarray:
        """Mean of m over each reference band [edges[k], edges[k+1]] (m), shape (n_bands,) (Simpson, 201 points)."""
        e = np.asarray(edges, dtype=float)
        t = np.linspace(0.0, 1.0, 201)
        z = e[:-1, None] + (e[1:] - e[:-1])[:, None] * t[None]
        w = np.ones(t.size)
        w[1:-1:2], w[2:-1:2] = 4.0, 2.0
        return (self(z) * w).sum(axis=1) / w.sum()
