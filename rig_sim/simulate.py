"""Simulated inflation/extension test: exact deformed tube at every step and marker positions on it.

World frame of the rig: z along the specimen axis, origin on the axis at specimen mid-length (the tube is stretched
symmetrically about it), x/y transverse; theta is measured from +x towards +y. Reference coordinates of a material
point of the marker surface: (theta, Z), Z in [-length/2, length/2]. Step 0 is the stress-free reference
(p = 0, stretch 1); then, for each axial stretch in ``stretches``, each pressure in ``pressures`` in order.
"""

from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np
from scipy.interpolate import CubicHermiteSpline

from .markers import place_markers
from .materials import check_params
from .tube import inflate_membrane, inflate_thick, transducer_force

log = logging.getLogger(__name__)

__all__ = ["MMHG", "PAPER_PRESSURES", "SimulatedTest", "simulate_test"]

#: One mmHg in Pa.
MMHG = 133.322387415
#: The paper's protocol: 8 pressure levels from 0 to 150 mmHg, in Pa.
PAPER_PRESSURES = np.linspace(0.0, 150.0, 8) * MMHG


def _ro(a):
    a = np.asarray(a)
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class SimulatedTest:
    """Ground truth of one simulated inflation/extension test.

    Attributes
    ----------
    positions : ndarray, shape (n_steps, n_markers, 3), m
        Marker positions in the rig world frame (with noise if ``noise_std`` > 0).
    exact_positions : ndarray, shape (n_steps, n_markers, 3), m
        The same without noise.
    pressure : ndarray, shape (n_steps,), Pa
        Lumen pressure (for ``wall="membrane"`` it acts on the marker surface).
    axial_force : ndarray, shape (n_steps,), N
        Wall axial force (force carried by the wall, tension positive). Homogeneous tube: sigma_zz over the wall
        section. Clamped tube: the wall force where the tube meets the cannulae (Z = +-length/2); along the tube the
        wall force varies as N(Z) = transducer_force + p pi r(Z)^2 (see ``wall_force``).
    transducer_force : ndarray, shape (n_steps,), N
        Reading of a load cell behind a closed pressurised cannula: axial_force - p pi a^2, a = lumen radius at the
        cannula (``lumen_radius``).
    stretch : ndarray, shape (n_steps,)
        Imposed overall axial stretch L / L0 (1 at step 0).
    lumen_radius : ndarray, shape (n_steps,), m
        Radius of the pressurised surface at the cannula (membrane: r at the clamp or r; thick: inner radius).
    marker_ids : ndarray, shape (n_markers,), int
    marker_theta, marker_Z : ndarray, shape (n_markers,)
        Reference cylindrical coordinates of the markers (rad, m).
    profile_Z : ndarray, shape (n_profile,), m
        Reference axial coordinates of the deformed-profile samples, over [-length/2, length/2].
    profile_r, profile_z, profile_drdZ, profile_dzdZ : ndarray, shape (n_steps, n_profile)
        Deformed marker-surface profile r(Z), z(Z) and its derivatives per step (exact cubic-Hermite data).
    reference_radius, thickness, length : float, m
        R (marker/outer surface), H, L0.
    model : str
    params : dict
        SI parameters.
    wall : str
        "membrane" or "thick".
    clamped : bool
    noise_std : float, m
        Standard deviation of the Gaussian noise on each coordinate.
    seed : int
    stress_scale : rig_sim.regional.AxialProfile or None
        Local stress multiplier m(Z) of an axially varying material (None: homogeneous).
    """

    positions: np.ndarray
    exact_positions: np.ndarray
    pressure: np.ndarray
    axial_force: np.ndarray
    transducer_force: np.ndarray
    stretch: np.ndarray
    lumen_radius: np.ndarray
    marker_ids: np.ndarray
    marker_theta: np.ndarray
    marker_Z: np.ndarray
    profile_Z: np.ndarray
    profile_r: np.ndarray
    profile_z: np.ndarray
    profile_drdZ: np.ndarray
    profile_dzdZ: np.ndarray
    reference_radius: float
    thickness: float
    length: float
    model: str
    params: dict = field(default_factory=dict)
    wall: str = "membrane"
    clamped: bool = True
    noise_std: float = 0.0
    seed: int = 0
    stress_scale: object = None

    @property
    def n_steps(self) -> int:
        return int(self.pressure.shape[0])

    @property
    def n_markers(self) -> int:
        return int(self.marker_ids.shape[0])

    def _check_step(self, step: int) -> int:
        if int(step) != step or not (-self.n_steps <= step < self.n_steps):
            raise IndexError(f"step must be an integer in [0, {self.n_steps}); got {step!r}")
        return int(step) % self.n_steps

    def profile(self, step: int, Z) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Deformed profile at reference coordinates ``Z`` (n,) m: (r, z, dr/dZ, dz/dZ), each (n,)."""
        s = self._check_step(step)
        Zq = np.asarray(Z, dtype=float)
        half = 0.5 * self.length
        if np.any(np.abs(Zq) > half * (1 + 1e-12)):
            raise ValueError(f"Z must lie within [-{half}, {half}] m (the specimen); "
                             f"got values up to {np.abs(Zq).max()}")
        rs = CubicHermiteSpline(self.profile_Z, self.profile_r[s], self.profile_drdZ[s])
        zs = CubicHermiteSpline(self.profile_Z, self.profile_z[s], self.profile_dzdZ[s])
        return rs(Zq), zs(Zq), rs(Zq, 1), zs(Zq, 1)

    def surface(self, step: int, theta, Z) -> np.ndarray:
        """Deformed marker-surface points, shape (n, 3) m in the world frame, for reference (theta (n,), Z (n,))."""
        th = np.asarray(theta, dtype=float)
        r, z, _, _ = self.profile(step, Z)
        r, z, th = np.broadcast_arrays(r, z, th)
        return np.stack([r * np.cos(th), r * np.sin(th), z], axis=-1)

    def normal(self, step: int, theta, Z) -> np.ndarray:
        """Outward unit normals of the deformed marker surface, shape (n, 3), at reference (theta (n,), Z (n,))."""
        th = np.asarray(theta, dtype=float)
        _, _, dr, dz = self.profile(step, Z)
        ls = np.hypot(dr, dz)
        dr, dz, ls, th = np.broadcast_arrays(dr, dz, ls, th)
        return np.stack([dz * np.cos(th) / ls, dz * np.sin(th) / ls, -dr / ls], axis=-1)

    def wall_force(self, step: int, Z) -> np.ndarray:
        """Wall axial force [N] through the cross-section at reference Z (n,): transducer_force + p pi r_l(Z)^2.

        Membrane walls only (r_l = r, the pressurised surface); for the homogeneous thick wall it is constant.
        """
        s = self._check_step(step)
        Zq = np.asarray(Z, dtype=float)
        if self.wall == "thick":
            return np.full(Zq.shape, self.axial_force[s])
        r, _, _, _ = self.profile(s, Zq)
        return self.transducer_force[s] + self.pressure[s] * np.pi * r * r


@functools.lru_cache(maxsize=32)
def _clamped_block(model, params_items, pressures, stretch, radius, thickness, length, bvp_nodes, bvp_tol, n_profile,
                   stress_scale=None):
    """Clamped-tube profiles for one stretch block, cached: repeated simulations (noise seeds, layouts) reuse them.

    Returns read-only arrays r, z, dr/dZ, dz/dZ of shape (n_pressures, n_profile), end wall force and clamp radius
    of shape (n_pressures,).
    """
    from .clamped import solve_clamped  # local import: the BVP solver is only needed here

    sols = solve_clamped(model, dict(params_items), np.asarray(pressures), stretch, radius=radius,
                         thickness=thickness, length=length, n_nodes=bvp_nodes, tol=bvp_tol, stress_scale=stress_scale)
    zp = np.linspace(-0.5 * length, 0.5 * length, n_profile)
    prof = np.array([np.stack(sol.evaluate(zp)) for sol in sols])  # (n_p, 4, n_profile)
    out = [prof[:, i] for i in range(4)]
    out += [np.array([sol.end_wall_force for sol in sols]), np.array([sol.clamp_radius for sol in sols])]
    return tuple(_ro(a) for a in out)


def _validate(model, params, radius, length, thickness, stretches, pressures, n_markers, wall, noise_std, margin):
    p = check_params(model, params)
    for name, v in (("radius", radius), ("length", length), ("thickness", thickness)):
        if not (isinstance(v, (int, float)) and v > 0 and math.isfinite(v)):
            raise ValueError(f"{name} must be a positive length in m; got {v!r}")
    if thickness >= radius:
        raise ValueError(f"thickness must be smaller than radius={radius}; got {thickness!r}")
    st = np.atleast_1d(np.asarray(stretches, dtype=float))
    if st.ndim != 1 or st.size == 0 or np.any(~np.isfinite(st)) or np.any(st <= 0):
        raise ValueError(f"stretches must be a non-empty 1-D sequence of positive stretches; got {stretches!r}")
    pr = np.atleast_1d(np.asarray(pressures, dtype=float))
    if pr.ndim != 1 or pr.size == 0 or np.any(~np.isfinite(pr)) or np.any(pr < 0):
        raise ValueError(f"pressures must be a non-empty 1-D sequence of pressures >= 0 in Pa; got {pressures!r}")
    if wall not in ("membrane", "thick"):
        raise ValueError(f"wall must be 'membrane' or 'thick'; got {wall!r}")
    if not (noise_std >= 0 and math.isfinite(noise_std)):
        raise ValueError(f"noise_std must be >= 0 m; got {noise_std!r}")
    if not (0 <= margin < 0.5 * length):
        raise ValueError(f"marker_margin must be in [0, length/2={0.5 * length}) m; got {margin!r}")
    return p, st, pr


def simulate_test(model: str, params: Mapping[str, float], *, radius: float = 10e-3, length: float = 35e-3,
                  thickness: float = 1.3e-3, stretches: Sequence[float] = (1.1,),
                  pressures: Sequence[float] = tuple(PAPER_PRESSURES), n_markers: int = 300, clamped: bool = True,
                  wall: str = "membrane", noise_std: float = 0.0, seed: int = 0, marker_margin: float = 4e-3,
                  n_profile: int = 401, bvp_nodes: int = 401, bvp_tol: float = 1e-8,
                  stress_scale=None) -> SimulatedTest:
    """Simulate an inflation/extension test of a cylindrical artery and its markers.

    Parameters
    ----------
    model : str
        "fung", "delfino", "hgo" or "neohookean" (``rig_sim.materials``).
    params : mapping
        SI parameters of the model, e.g. ``PAPER_PARAMETERS[model]``.
    radius : float, m
        Reference radius of the marker surface (outer surface of the wall).
    length : float, m
        Reference length L0 between the cannulae.
    thickness : float, m
        Reference wall thickness H.
    stretches : sequence of float
        Overall axial stretches L/L0, one block of pressures each.
    pressures : sequence of float, Pa
        Pressure levels applied in order at each stretch (default: 8 levels 0..150 mmHg).
    n_markers : int
        Number of markers.
    clamped : bool
        True: both ends clamped on cannulae of radius ``radius`` (heterogeneous BVP, membrane wall only).
        False: homogeneous tube.
    wall : {"membrane", "thick"}
        "membrane": thin membrane at the marker surface, pressure on it (the paper's model).
        "thick": incompressible thick wall, pressure on the lumen (radius - thickness), markers on the outer surface
        (homogeneous only).
    noise_std : float, m
        Standard deviation of i.i.d. Gaussian noise added to each coordinate of each marker at every step
        (including the reference). The paper's accuracy was 0.17e-3 m.
    seed : int
        Seeds the marker layout and (independently) the noise: changing noise_std keeps the layout.
    marker_margin : float, m
        Unmarked strip next to each cannula (markers cover |Z| <= length/2 - marker_margin).
    n_profile : int
        Samples of the stored deformed profile.
    bvp_nodes, bvp_tol : int, float
        Initial mesh size and tolerance of the clamped-tube BVP.
    stress_scale : rig_sim.regional.AxialProfile, optional
        Material varying along the axis (clamped only): local stresses m(Z) times the law's (a local beta(Z) =
        m(Z) beta for Fung). Must be hashable (simulations are cached). Default: homogeneous.

    Returns
    -------
    SimulatedTest

    Raises
    ------
    rig_sim.tube.MechanicsError
        If a pressure exceeds the model's inflation limit point or the clamped BVP does not converge.
    """
    p, st, pr = _validate(model, params, radius, length, thickness, stretches, pressures, n_markers, wall,
                          noise_std, marker_margin)
    if stress_scale is not None and not clamped:
        raise ValueError("stress_scale (a material varying along Z) needs clamped=True: the free-ended tube is "
                         "solved as a homogeneous cylinder")
    if clamped and wall == "thick":
        raise NotImplementedError("clamped=True needs wall='membrane': a clamped thick-walled tube needs a 2-D "
                                  "axisymmetric finite-element solve, which rig_sim does not provide")
    n_steps = 1 + st.size * pr.size
    Zp = np.linspace(-0.5 * length, 0.5 * length, int(n_profile))
    prof, pressure, stretch, force, lumen = _solve_blocks(
        model, p, st, pr, Zp, radius=radius, thickness=thickness, length=length, clamped=clamped, wall=wall,
        bvp_nodes=bvp_nodes, bvp_tol=bvp_tol, n_profile=n_profile, stress_scale=stress_scale)

    out = _with_markers(model, p, prof, pressure, stretch, force, lumen, Zp, radius=radius, thickness=thickness,
                        length=length, wall=wall, clamped=clamped, n_markers=n_markers, noise_std=noise_std, seed=seed,
                        marker_margin=marker_margin, stress_scale=stress_scale)
    log.debug("simulated %s test: %d steps, %d markers, clamped=%s, wall=%s", model, n_steps, n_markers, clamped, wall)
    return out


def _solve_blocks(model, p, st, pr, Zp, *, radius, thickness, length, clamped, wall, bvp_nodes, bvp_tol, n_profile,
                  stress_scale):
    """The deformed profile (dict of (n_steps, n_profile) arrays r, z, drdZ, dzdZ in m or 1), pressure (Pa),
    stretch, wall force (N) and lumen radius (m) per step (n_steps,): the reference, then one block
    of pressures ``pr`` per stretch in ``st``."""
    n_steps = 1 + st.size * pr.size
    prof = {k: np.empty((n_steps, Zp.size)) for k in ("r", "z", "drdZ", "dzdZ")}
    prof["r"][0], prof["z"][0], prof["drdZ"][0], prof["dzdZ"][0] = radius, Zp, 0.0, 1.0
    pressure = np.zeros(n_steps)
    stretch = np.ones(n_steps)
    force = np.zeros(n_steps)
    lumen = np.full(n_steps, radius if wall == "membrane" else radius - thickness)
    for b, lam in enumerate(st):
        sl = slice(1 + b * pr.size, 1 + (b + 1) * pr.size)
        pressure[sl], stretch[sl] = pr, lam
        if clamped:
            cached = _clamped_block(model, tuple(p.items()), tuple(pr.tolist()), float(lam), float(radius),
                                    float(thickness), float(length), int(bvp_nodes), float(bvp_tol), int(n_profile),
                                    stress_scale)
            for key, arr in zip(("r", "z", "drdZ", "dzdZ"), cached[:4]):
                prof[key][sl] = arr
            force[sl], lumen[sl] = cached[4], cached[5]
            continue
        if wall == "membrane":
            state = inflate_membrane(model, p, pr, lam, radius=radius, thickness=thickness)
            lt, force[sl], lumen[sl] = state.lam_theta, state.wall_force, state.radius
        else:
            state = inflate_thick(model, p, pr, lam, radius=radius, thickness=thickness)
            lt, force[sl], lumen[sl] = state.lam_outer, state.wall_force, state.inner_radius
        prof["r"][sl] = (lt * radius)[:, None]
        prof["z"][sl] = lam * Zp[None, :]
        prof["drdZ"][sl] = 0.0
        prof["dzdZ"][sl] = lam
    return prof, pressure, stretch, force, lumen


def _with_markers(model, p, prof, pressure, stretch, force, lumen, Zp, *, radius, thickness, length, wall, clamped,
                  n_markers, noise_std, seed, marker_margin, stress_scale) -> SimulatedTest:
    """The SimulatedTest of the solved steps with its markers placed (seeded layout) and their
    positions at every step, exact and with ``noise_std`` (m) of Gaussian noise."""
    n_steps = pressure.size
    rng_layout, rng_noise = (np.random.default_rng([seed, k]) for k in (0, 1))
    half = 0.5 * length - marker_margin
    theta, Zm = place_markers(n_markers, radius, -half, half, seed=int(rng_layout.integers(2**63)))
    out = SimulatedTest(
        positions=np.empty(0), exact_positions=np.empty(0), pressure=_ro(pressure), axial_force=_ro(force),
        transducer_force=_ro(transducer_force(force, pressure, lumen)), stretch=_ro(stretch),
        lumen_radius=_ro(lumen), marker_ids=_ro(np.arange(n_markers)), marker_theta=_ro(theta), marker_Z=_ro(Zm),
        profile_Z=_ro(Zp), profile_r=_ro(prof["r"]), profile_z=_ro(prof["z"]), profile_drdZ=_ro(prof["drdZ"]),
        profile_dzdZ=_ro(prof["dzdZ"]), reference_radius=float(radius), thickness=float(thickness),
        length=float(length), model=model, params=dict(p), wall=wall, clamped=bool(clamped),
        noise_std=float(noise_std), seed=int(seed), stress_scale=stress_scale,
    )
    exact = np.stack([out.surface(k, theta, Zm) for k in range(n_steps)])
    noisy = exact + rng_noise.normal(0.0, noise_std, exact.shape) if noise_std > 0 else exact.copy()
    object.__setattr__(out, "exact_positions", _ro(exact))
    object.__setattr__(out, "positions", _ro(noisy))
    return out
