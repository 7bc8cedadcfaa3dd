"""The homogeneous inflation/extension tube as a measurement model: loads from stretches, markers from geometry.

Conventions (decisions 0001-0003): SI units; the marker surface is the outer surface of the wall, reference radius
R; wall thickness H; circumferential stretch ``lam_theta`` of the marker surface, axial stretch ``lam_z``. Step 0
is the stress-free reference (``lam_theta = lam_z = 1``); the test steps k = 1..K follow.

* ``wall="membrane"`` (the paper's): a membrane at the marker surface; Laplace ``p r = sigma_tt h`` with
  ``r = lam_theta R``, ``h = H / (lam_theta lam_z)``; wall force ``N = sigma_zz 2 pi r h``.
* ``wall="thick"``: an incompressible cylinder with lumen radius R - H, pressure on the lumen, markers on the
  traction-free outer surface; ``p = int (sigma_tt - sigma_rr) dr / r`` and
  ``N = pi int (2 (sigma_zz - sigma_rr) - (sigma_tt - sigma_rr)) r dr + p pi r_i^2``, both integrated through the
  wall by Gauss-Legendre in the reference radius (as ``rig_sim.tube``).
* The force reading (decision 0003): ``force_measures="wall"`` reads N; ``"total"`` reads the load cell behind a
  closed pressurised cannula, ``F = N - p pi a^2`` with ``a`` the lumen radius (membrane: r; thick: r_i).

Marker i sits at material coordinates (theta_i, Z_i) (Z from the point that does not move axially, the fixed
cannula: ``uniform_markers``); in the frame
of the tube axis it is at ``q = (rho cos theta, rho sin theta, lam_z Z)``, ``rho = R lam_theta``, and in the world at
``X = (ox, oy, z0) + Rx(tx) Ry(ty) q``: the axis has two offsets, two tilts and an axial origin.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .models import get_model
from .models._base import pk2_components

__all__ = ["TubeGeometry", "TubeSteps", "MeasurementNoise", "stress_differences", "tube_loads", "solve_lam_theta",
           "uniform_markers", "axis_rotation", "marker_positions"]

WALLS = ("membrane", "thick")
FORCE_READINGS = ("wall", "total")


@dataclass(frozen=True)
class TubeGeometry:
    """Reference geometry of the specimen and what the load cell reads.

    Attributes
    ----------
    radius : float, m
        Reference radius R of the marker (outer) surface.
    thickness : float, m
        Reference wall thickness H (known, not estimated).
    wall : {"membrane", "thick"}
    force_measures : {"wall", "total"}
        Decision 0003: the load cell reads the wall force, or the wall force minus the pressure end-load.
    n_quad : int
        Gauss-Legendre points through a thick wall.
    """

    radius: float
    thickness: float
    wall: str = "membrane"
    force_measures: str = "wall"
    n_quad: int = 16

    def __post_init__(self) -> None:
        if not (self.radius > 0 and np.isfinite(self.radius)):
            raise ValueError(f"radius must be a positive length in m; got {self.radius!r}")
        if not (0 < self.thickness < self.radius):
            raise ValueError(f"thickness must be in (0, radius={self.radius!r}) m; got {self.thickness!r}")
        if self.wall not in WALLS:
            raise ValueError(f"wall must be one of {WALLS}; got {self.wall!r}")
        if self.force_measures not in FORCE_READINGS:
            raise ValueError(f"force_measures must be one of {FORCE_READINGS}; got {self.force_measures!r}")


@dataclass(frozen=True)
class TubeSteps:
    """The loaded steps of a test (the reference step 0 is implicit).

    Attributes
    ----------
    pressure : ndarray, shape (K,), Pa
    stretch : ndarray, shape (K,)
        Axial stretch set at each step.
    block : ndarray of int, shape (K,)
        Index of the block (one axial stretch set by the machine) of each step.
    """

    pressure: np.ndarray
    stretch: np.ndarray
    block: np.ndarray = field(default=None)  # type: ignore[assignment]

    def __post_init__(self) -> None:
        p = np.atleast_1d(np.asarray(self.pressure, dtype=float))
        s = np.atleast_1d(np.asarray(self.stretch, dtype=float))
        if p.ndim != 1 or p.shape != s.shape or p.size == 0:
            raise ValueError(f"pressure and stretch must have the same shape (K,), K >= 1; got {p.shape} and {s.shape}")
        if not np.all(s > 0):
            raise ValueError(f"stretch must be > 0; got {s.tolist()}")
        if self.block is None:
            _, b = np.unique(s, return_inverse=True)
        else:
            b = np.asarray(self.block, dtype=int)
            if b.shape != p.shape:
                raise ValueError(f"block must have shape {p.shape}; got {b.shape}")
        object.__setattr__(self, "pressure", p)
        object.__setattr__(self, "stretch", s)
        object.__setattr__(self, "block", b)

    @classmethod
    def from_blocks(cls, blocks) -> TubeSteps:
        """Steps from ``[(stretch, pressures), ...]``: one block of pressure levels per axial stretch."""
        p, s, b = [], [], []
        for i, (stretch, pressures) in enumerate(blocks):
            p += [float(x) for x in pressures]
            s += [float(stretch)] * len(pressures)
            b += [i] * len(pressures)
        return cls(np.array(p), np.array(s), np.array(b, dtype=int))

    @property
    def n_steps(self) -> int:
        return int(self.pressure.size)


@dataclass(frozen=True)
class MeasurementNoise:
    """Noise of the observations: isotropic Gaussian marker positions, readings with a relative error and a floor.

    Attributes
    ----------
    marker_sigma : float, m
        Standard deviation of each coordinate of each marker at every step (the reference included).
    load_relative : float
        Relative standard deviation of the pressure and force readings (0.1 % of reading).
    pressure_floor : float, Pa
    force_floor : float, N
        Constant parts of the reading standard deviations, added in quadrature to the relative part.
        ``load_relative = 0`` and zero floors mean exact loads.
    reference_repeats : int
        Captures of the stress-free reference averaged into one (``[reference] repeats``): the reference markers'
        standard deviation is ``marker_sigma / sqrt(reference_repeats)`` (``reference_sigma``).
    """

    marker_sigma: float
    load_relative: float = 1e-3
    pressure_floor: float = 3.0
    force_floor: float = 2e-3
    reference_repeats: int = 1

    def __post_init__(self) -> None:
        if not (self.marker_sigma > 0 and np.isfinite(self.marker_sigma)):
            raise ValueError(f"marker_sigma must be a positive length in m; got {self.marker_sigma!r}")
        for name in ("load_relative", "pressure_floor", "force_floor"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0; got {getattr(self, name)!r}")
        r = self.reference_repeats
        if isinstance(r, bool) or not isinstance(r, (int, np.integer)) or r < 1:
            raise ValueError(f"reference_repeats must be an integer >= 1 (captures of the reference); got {r!r}")

    @property
    def reference_sigma(self) -> float:
        """Standard deviation of each coordinate of each reference marker (m), the captures averaged."""
        return float(self.marker_sigma / np.sqrt(self.reference_repeats))

    @property
    def exact_loads(self) -> bool:
        return self.load_relative == 0 and (self.pressure_floor == 0 or self.force_floor == 0)

    def load_sigma(self, pressure, force) -> tuple[np.ndarray, np.ndarray]:
        """Standard deviations ``sqrt((relative reading)^2 + floor^2)`` of readings (K,) [Pa], [N]."""
        sp = np.hypot(self.load_relative * np.asarray(pressure, dtype=float), self.pressure_floor)
        sf = np.hypot(self.load_relative * np.asarray(force, dtype=float), self.force_floor)
        return sp, sf


def stress_differences(model, params, lam_theta, lam_z):
    """``(sigma_tt - sigma_rr, sigma_zz - sigma_rr)`` [Pa] of the incompressible law at principal stretches.

    The plane-stress Cauchy stresses of ``identification.models`` (S33 = 0 eliminates the pressure), which in a
    thick wall are the stress differences to the radial stress. Arrays broadcast.
    """
    model = get_model(model)
    c11 = np.asarray(lam_theta, dtype=float) ** 2
    c22 = np.asarray(lam_z, dtype=float) ** 2
    c11, c22 = np.broadcast_arrays(c11, c22)
    s11, s22, _ = pk2_components(model, c11, c22, np.zeros_like(c11), params)
    return c11 * s11, c22 * s22


def tube_loads(model, params, lam_theta, lam_z, geometry: TubeGeometry, radius: float | None = None):
    """Pressure and force reading that hold the tube at (lam_theta, lam_z).

    Parameters
    ----------
    lam_theta, lam_z : ndarray, shape (K,)
        Circumferential stretch of the marker surface and axial stretch.
    radius : float, optional
        Reference marker radius R instead of ``geometry.radius`` (an unknown of the bound).

    Returns
    -------
    pressure : ndarray, shape (K,), Pa
        Lumen pressure (membrane: on the marker surface).
    force : ndarray, shape (K,), N
        The load-cell reading (``geometry.force_measures``).
    """
    big_r = geometry.radius if radius is None else float(radius)
    h_ref = geometry.thickness
    lt = np.atleast_1d(np.asarray(lam_theta, dtype=float))
    lz = np.broadcast_to(np.asarray(lam_z, dtype=float), lt.shape)
    if geometry.wall == "membrane":
        stt, szz = stress_differences(model, params, lt, lz)
        p = stt * h_ref / (lt * lt * lz * big_r)
        n_wall = szz * 2.0 * np.pi * big_r * h_ref / lz
        lumen2 = (lt * big_r) ** 2
    else:
        ri_ref = big_r - h_ref
        ro = lt * big_r
        lumen2 = ro * ro - (big_r**2 - ri_ref**2) / lz
        if np.any(lumen2 <= 0):
            raise ValueError(f"lam_theta {lt.tolist()} closes the lumen at lam_z {lz.tolist()}")
        xg, wg = np.polynomial.legendre.leggauss(geometry.n_quad)
        rho = 0.5 * (big_r + ri_ref) + 0.5 * h_ref * xg  # (q,) reference radii
        w = 0.5 * h_ref * wg
        r2 = lumen2[:, None] + (rho**2 - ri_ref**2) / lz[:, None]  # (K, q)
        stt, szz = stress_differences(model, params, np.sqrt(r2) / rho, lz[:, None])
        # radial equilibrium: dr / r = rho drho / (lam_z r^2), r dr = rho drho / lam_z
        p = np.sum(stt * rho / (lz[:, None] * r2) * w, axis=1)
        n_wall = np.pi * np.sum((2.0 * szz - stt) * rho / lz[:, None] * w, axis=1) + p * np.pi * lumen2
    force = n_wall if geometry.force_measures == "wall" else n_wall - p * np.pi * lumen2
    return p, force


def solve_lam_theta(model, params, steps: TubeSteps, geometry: TubeGeometry, *, hi: float = 4.0) -> np.ndarray:
    """Circumferential stretch (K,) at each step's pressure on the stable branch (first upward crossing).

    Vectorised over the steps: a grid locates the bracket, bisection refines it to machine precision.
    Raises ValueError when a pressure is beyond the inflation limit point of the law.
    """
    lz = steps.stretch
    lo = 0.3 * np.ones_like(lz)
    if geometry.wall == "thick":
        lo = np.maximum(lo, np.sqrt((1.0 - (1.0 - geometry.thickness / geometry.radius) ** 2) / lz) * 1.0001)
    grid = lo[:, None] * (hi / lo[:, None]) ** np.linspace(0.0, 1.0, 300)[None, :]  # (K, g)
    with np.errstate(over="ignore", invalid="ignore"):
        p_grid = tube_loads(model, params, grid.ravel(), np.repeat(lz, grid.shape[1]), geometry)[0]
    g = np.where(np.isfinite(p_grid), p_grid, np.inf).reshape(grid.shape) - steps.pressure[:, None]
    up = (g[:, :-1] <= 0) & (g[:, 1:] > 0)
    if not np.all(up.any(axis=1)):
        bad = np.nonzero(~up.any(axis=1))[0].tolist()
        raise ValueError(f"pressure at steps {bad} is never reached for lam_theta in [{lo.min():.3g}, {hi}]: "
                         "beyond the inflation limit point of this law")
    i = np.argmax(up, axis=1)
    a, b = grid[np.arange(lz.size), i], grid[np.arange(lz.size), i + 1]
    for _ in range(64):
        mid = 0.5 * (a + b)
        below = tube_loads(model, params, mid, lz, geometry)[0] <= steps.pressure
        a, b = np.where(below, mid, a), np.where(below, b, mid)
    return 0.5 * (a + b)


def uniform_markers(n_markers: int, length: float, *, margin: float = 0.0,
                    fixed: str = "end") -> tuple[np.ndarray, np.ndarray]:
    """Quasi-uniform marker layout (a Fibonacci lattice) over the whole circumference and the marked length.

    Returns ``theta`` (n,) rad and ``Z`` (n,) m measured from the point that does not move axially: with
    ``fixed="end"`` (one cannula fixed, the other sets the stretch) Z is in [margin, length - margin]; with
    ``fixed="centre"`` (both cannulae move, as ``rig_sim``) in [-length/2 + margin, length/2 - margin].
    """
    if n_markers < 1:
        raise ValueError(f"n_markers must be >= 1; got {n_markers!r}")
    if not (0 <= margin < 0.5 * length):
        raise ValueError(f"margin must be in [0, length/2={0.5 * length}) m; got {margin!r}")
    if fixed not in ("end", "centre"):
        raise ValueError(f"fixed must be 'end' or 'centre'; got {fixed!r}")
    k = np.arange(n_markers)
    theta = np.mod(k * np.pi * (3.0 - np.sqrt(5.0)), 2.0 * np.pi)
    z = margin + (length - 2.0 * margin) * (k + 0.5) / n_markers
    return theta, z - 0.5 * length if fixed == "centre" else z


def axis_rotation(tilt_x: float, tilt_y: float) -> np.ndarray:
    """``Rx(tilt_x) @ Ry(tilt_y)``, shape (3, 3): the tube axis frame in the world."""
    cx, sx, cy, sy = np.cos(tilt_x), np.sin(tilt_x), np.cos(tilt_y), np.sin(tilt_y)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    return rx @ ry


def marker_positions(radius: float, lam_theta, lam_z, theta, Z, axis=(0.0, 0.0, 0.0, 0.0, 0.0)) -> np.ndarray:
    """World positions of the markers at the reference and every step.

    Parameters
    ----------
    radius : float, m
    lam_theta, lam_z : ndarray, shape (K,)
        Stretches of the loaded steps (the reference, 1 and 1, is prepended).
    theta, Z : ndarray, shape (n,)
    axis : (ox, oy, tilt_x, tilt_y, z0)

    Returns
    -------
    positions : ndarray, shape (K + 1, n, 3), m
    """
    rho = radius * np.concatenate([[1.0], np.atleast_1d(lam_theta)])[:, None]
    lz = np.concatenate([[1.0], np.atleast_1d(lam_z)])[:, None]
    q = np.stack(np.broadcast_arrays(rho * np.cos(theta), rho * np.sin(theta), lz * np.asarray(Z)), axis=-1)
    ox, oy, tx, ty, z0 = axis
    return np.array([ox, oy, z0]) + q @ axis_rotation(tx, ty).T
