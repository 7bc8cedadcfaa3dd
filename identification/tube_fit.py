"""Maximum-likelihood fit of the homogeneous-tube measurement model: the estimator that reaches the bound.

The unknowns are those of ``information``: the law's parameters, R, the circumferential stretch of each step, the
axial stretches, the axis (offsets, tilts, axial origin) and each marker's (theta, Z). The markers' own unknowns
are profiled out in closed form (for given geometry, ``theta = atan2(sum rho_s y_s, sum rho_s x_s)`` and
``Z = sum lam_s z_s / sum lam_s^2`` in the axis frame minimise the marker's squared residuals exactly), so that
``scipy.optimize.least_squares`` works on the few global unknowns of the profile likelihood.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from .information import AXIS_NAMES, TubeExperiment, unknown_scales
from .models import get_model
from .tube_forward import axis_rotation, marker_positions, solve_lam_theta, tube_loads

log = logging.getLogger(__name__)

__all__ = ["TubeObservations", "TubeFitResult", "simulate_observations", "profile_markers", "fit_tube"]


@dataclass(frozen=True)
class TubeObservations:
    """What a test measures.

    Attributes
    ----------
    positions : ndarray, shape (K + 1, n, 3), m
        Marker positions, the reference first.
    pressure, force : ndarray, shape (K,)
        Pressure [Pa] and force [N] readings of the loaded steps.
    """

    positions: np.ndarray
    pressure: np.ndarray
    force: np.ndarray


@dataclass(frozen=True)
class TubeFitResult:
    """Result of ``fit_tube``.

    Attributes
    ----------
    parameters : dict
        The law's parameters (SI).
    nuisances : dict
        ``R`` [m], ``lam_theta`` (K,), ``lam_z`` (M,), and the axis (``offset_x``... [m, rad]).
    theta, Z : ndarray, shape (n,)
        The markers' material coordinates (rad, m).
    cost : float
        Half the sum of squared normalised residuals (about half the number of observations at the truth).
    success : bool
    message : str
    nfev : int
    """

    parameters: dict
    nuisances: dict
    theta: np.ndarray
    Z: np.ndarray
    cost: float
    success: bool
    message: str
    nfev: int


def simulate_observations(model, params, experiment: TubeExperiment, rng: np.random.Generator,
                          axis=(0.0, 0.0, 0.0, 0.0, 0.0)) -> TubeObservations:
    """Noisy observations of an experiment (the same measurement model as the bound)."""
    model = get_model(model)
    params = model.check_parameters(params)
    geo, steps = experiment.geometry, experiment.steps
    lt = solve_lam_theta(model, params, steps, geo)
    pos = marker_positions(geo.radius, lt, steps.stretch, experiment.theta, experiment.Z, axis)
    p, f = tube_loads(model, params, lt, steps.stretch, geo)
    sp, sf = experiment.noise.load_sigma(p, f)
    return TubeObservations(pos + experiment.noise.marker_sigma * rng.standard_normal(pos.shape),
                            p + sp * rng.standard_normal(p.shape), f + sf * rng.standard_normal(f.shape))


def profile_markers(positions: np.ndarray, radius: float, lam_theta, lam_z, axis):
    """Each marker's best (theta, Z) for a given geometry, and the residuals.

    Parameters
    ----------
    positions : ndarray, shape (S, n, 3)
        S = K + 1 states, the reference first.
    lam_theta, lam_z : ndarray, shape (K,)
    axis : (ox, oy, tilt_x, tilt_y, z0)

    Returns
    -------
    theta, Z : ndarray, shape (n,)
    residuals : ndarray, shape (S, n, 3)
        Measured minus modelled positions, in the axis frame (same norm as in the world).
    """
    ox, oy, tx, ty, z0 = axis
    y = (positions - np.array([ox, oy, z0])) @ axis_rotation(tx, ty)  # (S, n, 3) in the axis frame
    rho = radius * np.concatenate([[1.0], lam_theta])[:, None]  # (S, 1)
    lz = np.concatenate([[1.0], lam_z])[:, None]
    theta = np.arctan2(np.sum(rho * y[..., 1], axis=0), np.sum(rho * y[..., 0], axis=0))
    z = np.sum(lz * y[..., 2], axis=0) / np.sum(lz * lz)
    q = np.stack(np.broadcast_arrays(rho * np.cos(theta), rho * np.sin(theta), lz * z), axis=-1)
    return theta, z, y - q


def _initial_geometry(positions: np.ndarray, stretch: np.ndarray) -> np.ndarray:
    """R, lam_theta (K,), lam_z (K,), axis (5) from the positions: centroid axis, radial distances, z regressions."""
    ref = positions[0]
    centre = ref[:, :2].mean(axis=0)
    radial = np.linalg.norm(positions[..., :2] - centre, axis=-1).mean(axis=1)  # (S,)
    slopes, intercepts = [], []
    for s in range(1, positions.shape[0]):
        a, b = np.polyfit(ref[:, 2], positions[s, :, 2], 1)
        slopes.append(a)
        intercepts.append(b)
    slopes, intercepts = np.array(slopes), np.array(intercepts)
    far = int(np.argmax(np.abs(slopes - 1.0)))
    z0 = intercepts[far] / (1.0 - slopes[far]) if abs(slopes[far] - 1.0) > 1e-6 else 0.0
    lz = np.where(np.isfinite(slopes), slopes, stretch)
    return np.concatenate([[radial[0]], radial[1:] / radial[0], lz, [centre[0], centre[1], 0.0, 0.0, z0]])


def fit_tube(model, observations: TubeObservations, experiment: TubeExperiment, start=None,
             max_nfev: int = 400) -> TubeFitResult:
    """Maximum-likelihood estimate of the law and all nuisances from one test.

    Parameters
    ----------
    model : str or Model
    observations : TubeObservations
    experiment : TubeExperiment
        Its geometry (H, wall, force reading; R only as a scale), steps (stretch structure), noise (the weights).
        Its marker layout is not used: the markers' coordinates are estimated.
    start : mapping, optional
        Starting parameters (SI); default the model's generic initial guess.
    max_nfev : int
        Limit of least-squares function evaluations.

    Returns
    -------
    TubeFitResult
    """
    model = get_model(model)
    names = model.parameter_names
    start = model.check_parameters(start if start is not None else model.initial_guess)
    geo, steps, idx, noise = experiment.geometry, experiment.steps, experiment.stretch_index, experiment.noise
    pos = np.asarray(observations.positions, dtype=float)
    k, m, n_p = steps.n_steps, int(idx.max()) + 1, len(names)
    if pos.ndim != 3 or pos.shape[0] != k + 1 or pos.shape[2] != 3:
        raise ValueError(f"positions must have shape ({k + 1}, n, 3); got {pos.shape}")
    g0 = _initial_geometry(pos, steps.stretch)
    lz0 = np.array([g0[1 + k:1 + 2 * k][idx == j].mean() for j in range(m)])
    x_si = np.concatenate([[start[p] for p in names], g0[:1 + k], lz0, g0[1 + 2 * k:]])
    d = unknown_scales(np.array([start[p] for p in names]), geo.radius, 1 + k + m + 5, k, m)
    sp, sf = noise.load_sigma(observations.pressure, observations.force)

    def unpack(x):
        v = x * d
        return dict(zip(names, v[:n_p])), v[n_p], v[n_p + 1:n_p + 1 + k], v[n_p + 1 + k:n_p + 1 + k + m], v[-5:]

    def residuals(x):
        par, radius, lt, lz_u, axis = unpack(x)
        _, _, res = profile_markers(pos, radius, lt, lz_u[idx], axis)
        with np.errstate(all="ignore"):
            try:
                p, f = tube_loads(model, par, lt, lz_u[idx], geo, radius=radius)
            except ValueError:  # a trial step that closes the lumen
                p, f = np.full(k, 1e12), np.full(k, 1e12)
        loads = np.concatenate([(p - observations.pressure) / sp, (f - observations.force) / sf])
        return np.concatenate([res.ravel() / noise.marker_sigma, np.nan_to_num(loads, nan=1e12)])

    sol = least_squares(residuals, x_si / d, method="lm", x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12,
                        max_nfev=max_nfev)
    par, radius, lt, lz_u, axis = unpack(sol.x)
    theta, z, _ = profile_markers(pos, radius, lt, lz_u[idx], axis)
    nuisances = {"R": float(radius), "lam_theta": lt, "lam_z": lz_u, **dict(zip(AXIS_NAMES, axis.tolist()))}
    log.debug("fit_tube: cost %.6g after %d evaluations (%s)", sol.cost, sol.nfev, sol.message)
    return TubeFitResult({p: float(v) for p, v in par.items()}, nuisances, theta, z, float(sol.cost),
                         bool(sol.success), str(sol.message), int(sol.nfev))
