"""What an inflation/extension test can say about a law: the Cramér-Rao bound of the homogeneous-tube measurement.

The measurement (``tube_forward``): each marker's 3-D position at the reference and every step, i.i.d. isotropic
Gaussian with standard deviation sigma (sigma / sqrt(N) at the reference when N captures of it are averaged,
``MeasurementNoise.reference_repeats``); the pressure and the force reading at every loaded step with 0.1 % of
reading (floors 3 Pa, 2 mN). The unknowns: the law's parameters, and the nuisances an estimator must estimate too —
the reference radius R, the state of each step, the axial stretch (per step, or per block when the machine set
it), the axis (two offsets, two tilts, the axial origin), and every marker's material coordinates (theta, Z).

The state of a step is parametrised by its circumferential stretch ``lam_theta`` instead of its true pressure: the
map between them is one-to-one for given parameters, and the bound of the parameters does not depend on how the
nuisances are parametrised. Markers then depend on the geometry only, the readings on (parameters, R, stretches):

    I = J_m^T J_m / sigma^2 (markers; analytic)  +  J_l^T diag(1/sigma_l^2) J_l (readings; central differences)

Each marker's two unknowns are eliminated from its own rows by a 2x2 Schur complement (vectorised over the
markers), then the parameter block of the inverse of the reduced information is the bound.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from .models import get_model
from .tube_forward import MeasurementNoise, TubeGeometry, TubeSteps, solve_lam_theta, tube_loads

log = logging.getLogger(__name__)

__all__ = ["TubeExperiment", "BoundResult", "cramer_rao_bound", "geometry_layout", "marker_jacobians",
           "reduced_marker_information", "load_jacobian", "information_matrix", "unknown_scales", "SINGULAR_CONDITION",
           "Z95"]

#: Condition number (of the information scaled by the unknowns' magnitudes) above which the bound is not trusted.
SINGULAR_CONDITION = 1e12
#: Two-sided 95 % quantile of the normal distribution.
Z95 = 1.959963984540054
#: Readings of an exact-load experiment get this relative standard deviation (numerically infinite information).
_EXACT = 1e-12
AXIS_NAMES = ("offset_x", "offset_y", "tilt_x", "tilt_y", "axial_origin")


@dataclass(frozen=True)
class TubeExperiment:
    """Everything about a test but the law: specimen geometry, steps, marker layout, noise.

    Attributes
    ----------
    geometry : TubeGeometry
    steps : TubeSteps
    theta, Z : ndarray, shape (n,)
        Material coordinates of the markers (rad, m).
    noise : MeasurementNoise
    stretch_per : {"step", "block"}
        One unknown axial stretch per step, or one per block (the machine set it).
    """

    geometry: TubeGeometry
    steps: TubeSteps
    theta: np.ndarray
    Z: np.ndarray
    noise: MeasurementNoise
    stretch_per: str = "step"

    def __post_init__(self) -> None:
        th, z = np.atleast_1d(np.asarray(self.theta, float)), np.atleast_1d(np.asarray(self.Z, float))
        if th.shape != z.shape or th.ndim != 1:
            raise ValueError(f"theta and Z must have the same shape (n,); got {th.shape} and {z.shape}")
        if self.stretch_per not in ("step", "block"):
            raise ValueError(f"stretch_per must be 'step' or 'block'; got {self.stretch_per!r}")
        object.__setattr__(self, "theta", th)
        object.__setattr__(self, "Z", z)

    @property
    def stretch_index(self) -> np.ndarray:
        """Index (K,) of each step's axial-stretch unknown."""
        if self.stretch_per == "step":
            return np.arange(self.steps.n_steps)
        return np.unique(self.steps.block, return_inverse=True)[1]


@dataclass(frozen=True)
class BoundResult:
    """The Cramér-Rao bound of a law's parameters for one experiment.

    Attributes
    ----------
    model : str
    values : dict
        The parameters the bound is computed at (SI).
    std : dict
        Lower bound of the standard deviation of any unbiased estimator (SI units of each parameter).
    std_percent : dict
        ``std`` in % of the value.
    covariance : ndarray, shape (n_p, n_p)
        Parameter block of the inverse information (SI), in ``values``' order.
    condition : float
        Condition number of the reduced information scaled by the unknowns' magnitudes.
    singular : bool
        ``condition > SINGULAR_CONDITION``: the bound is numerically meaningless (e.g. exact loads).
    warning : str
        Empty, or why the bound is not to be trusted.
    nuisance_std : dict
        Bound of the nuisances (R, stretches, axis), SI.
    """

    model: str
    values: dict
    std: dict
    std_percent: dict
    covariance: np.ndarray
    condition: float
    singular: bool
    warning: str = ""
    nuisance_std: dict = field(default_factory=dict)

    def half_width_percent(self) -> dict:
        """95 % half-width (1.96 sigma) of each parameter, % of its value."""
        return {k: Z95 * v for k, v in self.std_percent.items()}


def geometry_layout(experiment: TubeExperiment) -> list[str]:
    """Names of the geometric unknowns: R, lam_theta_k (K), lam_z_m (M), the 5 axis unknowns."""
    k = experiment.steps.n_steps
    m = int(experiment.stretch_index.max()) + 1
    return (["R"] + [f"lam_theta_{i + 1}" for i in range(k)] + [f"lam_z_{i + 1}" for i in range(m)]
            + list(AXIS_NAMES))


def marker_jacobians(radius: float, lam_theta, lam_z, stretch_index, theta, Z) -> tuple[np.ndarray, np.ndarray]:
    """Analytic derivatives of the marker positions at the nominal axis (no offset, no tilt, origin 0).

    Parameters
    ----------
    radius : float
    lam_theta, lam_z : ndarray, shape (K,)
    stretch_index : ndarray of int, shape (K,)
        Axial-stretch unknown of each step (M = max + 1 of them).
    theta, Z : ndarray, shape (n,)

    Returns
    -------
    j_geometry : ndarray, shape (n, 3 (K + 1), 1 + K + M + 5)
        By (R, lam_theta_1..K, lam_z_1..M, ox, oy, tilt_x, tilt_y, z0); rows (state, xyz), the reference first.
    j_local : ndarray, shape (n, 3 (K + 1), 2)
        By each marker's own (theta, Z).
    """
    lt = np.concatenate([[1.0], lam_theta])  # (S,)
    lz = np.concatenate([[1.0], lam_z])
    k, m, n, s = lt.size - 1, int(np.max(stretch_index)) + 1, theta.size, lt.size
    c, sn = np.cos(theta)[:, None], np.sin(theta)[:, None]  # (n, 1)
    rho = radius * lt[None, :]  # (1, S)
    qx, qy, qz = rho * c, rho * sn, lz[None, :] * Z[:, None]  # (n, S)
    zero, one = np.zeros((n, s)), np.ones((n, s))
    jg = np.zeros((n, s, 3, 1 + k + m + 5))
    jg[:, :, 0, 0], jg[:, :, 1, 0] = lt * c, lt * sn  # R
    steps = np.arange(1, s)
    jg[:, steps, 0, steps], jg[:, steps, 1, steps] = radius * c, radius * sn  # lam_theta_k acts on state k
    jg[:, steps, 2, 1 + k + np.asarray(stretch_index)] = Z[:, None]  # lam_z
    axis = np.stack([np.stack([one, zero, zero], -1),  # ox
                     np.stack([zero, one, zero], -1),  # oy
                     np.stack([zero, -qz, qy], -1),  # tilt_x: e_x x q
                     np.stack([qz, zero, -qx], -1),  # tilt_y: e_y x q
                     np.stack([zero, zero, one], -1)], -1)  # z0
    jg[..., 1 + k + m:] = axis
    jl = np.stack([np.stack([-rho * sn, rho * c, zero], -1),
                   np.stack([zero, zero, np.broadcast_to(lz, (n, s))], -1)], -1)
    return jg.reshape(n, 3 * s, -1), jl.reshape(n, 3 * s, 2)


def reduced_marker_information(j_geometry: np.ndarray, j_local: np.ndarray, sigma: float) -> np.ndarray:
    """Information of the markers on the geometric unknowns, each marker's (theta, Z) eliminated.

    ``sum_i [A_i - B_i C_i^-1 B_i^T] / sigma^2`` with ``A = Jg^T Jg``, ``B = Jg^T Jl``, ``C = Jl^T Jl`` (2x2 per
    marker, inverted in closed form). Shapes as ``marker_jacobians``; returns (n_g, n_g).
    """
    a = np.einsum("nrg,nrh->gh", j_geometry, j_geometry)
    b = np.einsum("nrg,nrl->ngl", j_geometry, j_local)
    cc = np.einsum("nrl,nrm->nlm", j_local, j_local)
    det = cc[:, 0, 0] * cc[:, 1, 1] - cc[:, 0, 1] * cc[:, 1, 0]
    inv = np.stack([np.stack([cc[:, 1, 1], -cc[:, 0, 1]], -1), np.stack([-cc[:, 1, 0], cc[:, 0, 0]], -1)], -2)
    inv = inv / det[:, None, None]
    return (a - np.einsum("ngl,nlm,nhm->gh", b, inv, b)) / sigma**2


def load_jacobian(model, params: dict, experiment: TubeExperiment, lam_theta, rel_step: float = 1e-6):
    """Readings (pressure, force) and their derivatives by (parameters, R, lam_theta, lam_z), central differences.

    Returns
    -------
    readings : ndarray, shape (2K,)
        Pressures then force readings at the nominal state.
    jacobian : ndarray, shape (2K, n_p + 1 + K + M)
        Columns: the parameters in model order, R, lam_theta_1..K, lam_z_1..M.
    """
    model = get_model(model)
    geo, steps, idx = experiment.geometry, experiment.steps, experiment.stretch_index
    names = model.parameter_names
    lz_unknown = np.array([steps.stretch[idx == j][0] for j in range(idx.max() + 1)])
    x0 = np.concatenate([[params[p] for p in names], [geo.radius], lam_theta, lz_unknown])
    n_p, k = len(names), steps.n_steps

    def readings(x):
        par = dict(zip(names, x[:n_p]))
        lt, lz = x[n_p + 1:n_p + 1 + k], x[n_p + 1 + k:][idx]
        return np.concatenate(tube_loads(model, par, lt, lz, geo, radius=x[n_p]))

    y0 = readings(x0)
    jac = np.empty((2 * k, x0.size))
    for j in range(x0.size):  # a few tens of columns: parameters and stretches are few (markers are analytic)
        h = rel_step * max(abs(x0[j]), 1e-3 if j < n_p else geo.radius)
        xp, xm = x0.copy(), x0.copy()
        xp[j] += h
        xm[j] -= h
        jac[:, j] = (readings(xp) - readings(xm)) / (2.0 * h)
    return y0, jac


def unknown_scales(params_values: np.ndarray, radius: float, n_geometry: int, k: int, m: int) -> np.ndarray:
    """Magnitudes that make the unknowns dimensionless (parameters, R, stretches, axis)."""
    par = np.where(np.abs(params_values) > 0, np.abs(params_values), 1.0)
    axis = np.array([radius, radius, 1.0, 1.0, radius])
    geo = np.concatenate([[radius], np.ones(k + m), axis])
    return np.concatenate([par, geo])


def information_matrix(model, params, experiment: TubeExperiment) -> tuple[np.ndarray, list[str]]:
    """The information of (parameters, geometry) with the markers' own unknowns eliminated, SI.

    Returns the matrix (n_p + n_g, n_g + n_p) and the names of its unknowns.
    """
    model = get_model(model)
    params = model.check_parameters(params)
    geo, steps, idx = experiment.geometry, experiment.steps, experiment.stretch_index
    lam_theta = solve_lam_theta(model, params, steps, geo)
    names = list(model.parameter_names) + geometry_layout(experiment)
    n_p, k = len(model.parameter_names), steps.n_steps
    jg, jl = marker_jacobians(geo.radius, lam_theta, steps.stretch, idx, experiment.theta, experiment.Z)
    if experiment.noise.reference_repeats != 1:  # the reference rows (first 3) whitened by their own, lower noise
        gain = np.sqrt(float(experiment.noise.reference_repeats))
        jg, jl = jg.copy(), jl.copy()
        jg[:, :3] *= gain
        jl[:, :3] *= gain
    info = np.zeros((len(names), len(names)))
    info[n_p:, n_p:] = reduced_marker_information(jg, jl, experiment.noise.marker_sigma)
    y, jac = load_jacobian(model, params, experiment, lam_theta)
    noise = experiment.noise
    if noise.exact_loads:
        sp, sf = _EXACT * np.maximum(np.abs(y[:k]), 1.0), _EXACT * np.maximum(np.abs(y[k:]), 1e-3)
    else:
        sp, sf = noise.load_sigma(y[:k], y[k:])
    weights = 1.0 / np.concatenate([sp, sf]) ** 2
    cols = n_p + 1 + k + int(idx.max()) + 1
    info[:cols, :cols] += jac.T @ (weights[:, None] * jac)
    return info, names


def cramer_rao_bound(model, params, experiment: TubeExperiment) -> BoundResult:
    """Cramér-Rao bound of the law's parameters for one inflation/extension experiment.

    Parameters
    ----------
    model : str or Model
        ``identification.models`` name (``"fung"``, ``"delfino"``, ``"hgo"``...).
    params : mapping
        The law's parameters (SI) at which the bound is computed (the truth of a simulation, or a prior).
    experiment : TubeExperiment

    Returns
    -------
    BoundResult
        Bound per parameter (SI and % of value), covariance, condition number, singular flag and warning.
    """
    model = get_model(model)
    params = model.check_parameters(params)
    info, names = information_matrix(model, params, experiment)
    n_p, k = len(model.parameter_names), experiment.steps.n_steps
    values = np.array([params[p] for p in model.parameter_names])
    d = unknown_scales(values, experiment.geometry.radius, len(names) - n_p, k, int(experiment.stretch_index.max()) + 1)
    scaled = info * np.outer(d, d)  # the information of the dimensionless unknowns x / d
    eig = np.linalg.eigvalsh(scaled)
    condition = float(eig[-1] / eig[0]) if eig[0] > 0 else float("inf")
    singular = not condition < SINGULAR_CONDITION
    warning = ""
    if singular:
        warning = (f"the information matrix is numerically singular (condition {condition:.2g} > "
                   f"{SINGULAR_CONDITION:.0g}): the bound is not meaningful"
                   + (" (exact loads: give the readings their noise)" if experiment.noise.exact_loads else ""))
        log.warning(warning)
    cov = np.linalg.pinv(scaled, rcond=1e-18, hermitian=True) * np.outer(d, d) if singular else \
        np.linalg.inv(scaled) * np.outer(d, d)
    std_all = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    std = dict(zip(model.parameter_names, std_all[:n_p].tolist()))
    std_percent = {p: 100.0 * std[p] / abs(params[p]) if params[p] != 0 else float("inf")
                   for p in model.parameter_names}
    return BoundResult(model.name, dict(params), std, std_percent, cov[:n_p, :n_p], condition, singular, warning,
                       dict(zip(names[n_p:], std_all[n_p:].tolist())))
