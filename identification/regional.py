"""Regional identification: material parameters that vary along the specimen axis.

The measured surface (reference axial coordinate z of the mesh, between ``z_bottom`` and ``z_top``) is split into
``n_bands`` axial bands of equal reference length. Each band b has its own value of the *regional* parameters
(by default the model's stress-like ones: beta for Fung and Delfino); the other parameters are shared. The virtual
fields make the bands separable: per band

    radial[b]  u* = sin(pi xi_b) e_r            supported on band b only (the paper's u*1 restricted to it)
    axial[b]   u* = clip(xi_b, 0, 1) e_z        0 below the band, a ramp across it, a rigid unit translation beyond

with xi_b = (z - z_b) / (z_{b+1} - z_b). The axial fields end in the unit translation of the load-cell end, so the
measured axial force does work in all of them (the load-cell field stays global: their sum weighted by the band
widths is the paper's u*2), while their virtual strain lives in band b only. Integration points belong to the band
of their triangle's reference centroid. All bands are solved jointly by bounded least squares on the normalised
virtual-work gaps of ``vfm.prepare``; standard errors come from the Gauss-Newton covariance scaled by the residual
scatter, identifiability per band from the same resolution measure as the global fit (``optimize``).

Pure functions over arrays; SI units (m, Pa).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
from scipy.optimize import least_squares

from .errors import IdentificationError
from .mesh import SurfaceMesh, build_mesh
from .models import Model, get_model
from .models._base import pk2_components
from .optimize import GAP_FOR_FLAGS, RESOLUTION_LIMIT, TYPICAL, IdentificationResult, identify_prepared
from .vfm import VFMData, prepare
from .virtual_fields import VirtualFields

__all__ = ["RegionalData", "RegionalResult", "band_edges", "band_fields", "prepare_regional", "identify_regional"]

log = logging.getLogger(__name__)

#: A band is reported as different from the others when its value departs from the pooled one by more than this
#: many standard errors *and* by more than ``MIN_CONTRAST`` (relative): the method's error on exact data
#: (1-4 % at 3-8 bands) is not news.
SIGNIFICANCE = 3.0
MIN_CONTRAST = 0.05


@dataclass(frozen=True)
class RegionalData:
    """Virtual-work balance with band-supported fields.

    Attributes
    ----------
    data : VFMData
        From ``vfm.prepare`` with ``band_fields``.
    edges : ndarray, shape (n_bands + 1,)
        Band edges in the reference axial coordinate of the mesh (m, from ``mesh.axis.origin``).
    point_band : ndarray, shape (n_points,) int
        Band of every integration point of ``data`` (its triangle's reference centroid).
    homogeneous : VFMData
        The same measurements with the paper's two global fields (the homogeneous fit, for comparison and start).
    """

    data: VFMData
    edges: np.ndarray
    point_band: np.ndarray
    homogeneous: VFMData

    @property
    def n_bands(self) -> int:
        return len(self.edges) - 1

    @property
    def centres(self) -> np.ndarray:
        """Band centres, shape (n_bands,), m (mesh axial coordinate)."""
        return 0.5 * (self.edges[1:] + self.edges[:-1])

    def world_points(self, z) -> np.ndarray:
        """World positions (n, 3) m of the axis points at mesh axial coordinates ``z`` (n,) m."""
        ax = self.data.mesh.axis
        return ax.origin[None] + np.asarray(z, dtype=float)[:, None] * ax.direction[None]


@dataclass(frozen=True)
class RegionalResult:
    """Outcome of a regional identification.

    Attributes
    ----------
    model : str
    regional : tuple of str
        Names of the parameters identified per band.
    edges, centres : ndarray, shapes (n_bands + 1,), (n_bands,)
        Band edges and centres, m, reference axial coordinate of the mesh.
    profiles, stderr : dict of ndarray, shape (n_bands,)
        Per-band values and standard errors of the regional parameters (SI).
    parameters, parameter_stderr : dict of float
        The shared parameters and their standard errors.
    pooled : dict of float
        Inverse-variance weighted mean of each regional profile.
    contrast : dict of ndarray, shape (n_bands,)
        Relative departure of each band from the median band.
    z_score : dict of ndarray, shape (n_bands,)
        That departure in standard errors (band and median combined).
    differs : ndarray, shape (n_bands,) bool
        Bands where a regional parameter departs from the median band beyond ``SIGNIFICANCE`` standard errors and
        ``MIN_CONTRAST``.
    resolution : dict of ndarray, shape (n_bands,)
        As ``IdentificationResult.resolution``, per band.
    flags : tuple of str
    cost : float
    residuals : ndarray, shape (n_fields, n_steps)
    field_names : tuple of str
    converged : bool
    message : str
    homogeneous : IdentificationResult
        The global (paper) fit of the same measurements, for comparison.
    """

    model: str
    regional: tuple
    edges: np.ndarray
    centres: np.ndarray
    profiles: dict
    stderr: dict
    parameters: dict
    parameter_stderr: dict
    pooled: dict
    contrast: dict
    z_score: dict
    differs: np.ndarray
    resolution: dict
    flags: tuple
    cost: float
    residuals: np.ndarray
    field_names: tuple
    converged: bool
    message: str
    homogeneous: IdentificationResult

    @property
    def n_bands(self) -> int:
        return len(self.centres)


def band_edges(mesh: SurfaceMesh, n_bands: int) -> np.ndarray:
    """Edges of ``n_bands`` equal bands between the measured ends, shape (n_bands + 1,), m (mesh axial coordinate)."""
    if isinstance(n_bands, bool) or not isinstance(n_bands, (int, np.integer)) or n_bands < 1:
        raise ValueError(f"n_bands must be a positive integer; got {n_bands!r}")
    return np.linspace(mesh.z_bottom, mesh.z_top, int(n_bands) + 1)


def band_fields(mesh: SurfaceMesh, edges: Sequence[float]) -> VirtualFields:
    """Band-supported virtual fields: ``radial[b]`` and ``axial[b]`` for every band (module docstring)."""
    e = np.asarray(edges, dtype=float)
    if e.ndim != 1 or e.size < 2 or np.any(np.diff(e) <= 0):
        raise ValueError(f"edges must be an increasing 1-D sequence of at least 2 axial positions in m; got {edges!r}")
    n = e.size - 1
    z = np.nan_to_num(mesh.z, nan=e[0])
    xi = np.clip((z[None] - e[:-1, None]) / np.diff(e)[:, None], 0.0, 1.0)  # (n_bands, n_markers)
    radial = np.where((xi > 0) & (xi < 1), np.sin(np.pi * xi), 0.0)
    values = np.zeros((2 * n, mesh.n_markers, 3))
    values[0::2, :, 0] = radial
    values[1::2, :, 2] = xi
    names = tuple(f"{kind}[{b}]" for b in range(n) for kind in ("radial", "axial"))
    return VirtualFields(names=names, values=values, load_end=np.tile([0.0, 1.0], n))


def _point_bands(mesh: SurfaceMesh, edges: np.ndarray, n_points: int, quadrature: int, n_layers: int) -> np.ndarray:
    """Band of every integration point, in the point order of ``vfm.prepare`` (layers, triangles, quadrature)."""
    zc = np.nanmean(mesh.z[mesh.triangles], axis=1)
    tri_band = np.clip(np.searchsorted(edges, zc, side="right") - 1, 0, len(edges) - 2)
    bands = np.tile(np.repeat(tri_band, quadrature), n_layers)
    if bands.size != n_points:
        raise IdentificationError(f"the prepared data have {n_points} integration points; expected "
                                  f"{bands.size} from {mesh.n_triangles} triangles x {quadrature} x {n_layers}")
    return bands


def prepare_regional(positions: np.ndarray, pressure: np.ndarray, axial_force: np.ndarray, *, thickness: float,
                     n_bands: int, mesh: SurfaceMesh | None = None, wall: str = "membrane", quadrature: int = 1,
                     n_layers: int = 4, toward: np.ndarray | None = None, **prepare_options) -> RegionalData:
    """``vfm.prepare`` with the band-supported fields of ``n_bands`` equal axial bands.

    Parameters are those of ``vfm.prepare`` (positions (n_steps, n_markers, 3) m, pressure (n_steps,) Pa,
    axial_force (n_steps,) N, thickness m); ``fields`` is set here.
    """
    if "fields" in prepare_options:
        raise ValueError("prepare_regional builds its own band fields; do not pass fields")
    if mesh is None:
        x = np.asarray(positions, dtype=float)
        ref = x[prepare_options.get("reference_step", 0)] if x.ndim == 3 else x
        mesh = build_mesh(ref, toward=toward)
    edges = band_edges(mesh, n_bands)
    common = dict(thickness=thickness, wall=wall, mesh=mesh, quadrature=quadrature, n_layers=n_layers, toward=toward,
                  **prepare_options)
    data = prepare(positions, pressure, axial_force, fields=band_fields(mesh, edges), **common)
    layers = 1 if wall == "membrane" else int(n_layers)
    return RegionalData(data=data, edges=edges,
                        point_band=_point_bands(mesh, edges, data.c.shape[1], int(quadrature), layers),
                        homogeneous=prepare(positions, pressure, axial_force, **common))


class _Layout:
    """Optimisation vector x <-> parameters: regional ones per band, the others shared; log for positive ones."""

    def __init__(self, model: Model, regional: tuple, n_bands: int, start: Mapping[str, float]):
        self.model, self.regional, self.n_bands = model, regional, n_bands
        self.shared = tuple(n for n in model.parameter_names if n not in regional)
        self.names = [(n, b) for n in regional for b in range(n_bands)] + [(n, None) for n in self.shared]
        idx = {n: i for i, n in enumerate(model.parameter_names)}
        self.log = np.array([model.positive[idx[n]] for n, _ in self.names])
        self.scale = np.array([1.0 if lg else max(abs(start[n]), TYPICAL.get(n, 1.0))
                               for (n, _), lg in zip(self.names, self.log)])
        lo = np.array([model.lower[idx[n]] if model.lower else -np.inf for n, _ in self.names], dtype=float)
        hi = np.array([model.upper[idx[n]] if model.upper else np.inf for n, _ in self.names], dtype=float)
        x0 = self.to_x(start)
        self.lower = np.where(self.log, x0 - 12.0, lo / self.scale)
        self.upper = np.where(self.log, x0 + 12.0, hi / self.scale)

    def to_x(self, start: Mapping[str, float]) -> np.ndarray:
        v = np.array([start[n] for n, _ in self.names], dtype=float)
        return np.where(self.log, np.log(np.where(v > 0, v, 1.0)), v / self.scale)

    def to_p(self, x: np.ndarray) -> np.ndarray:
        return np.where(self.log, np.exp(x), x * self.scale)

    def point_values(self, x: np.ndarray, point_band: np.ndarray) -> dict:
        """Parameter dict for ``pk2_components``: (n_points,) arrays for regional ones, floats for shared ones."""
        p = self.to_p(x)
        nb = self.n_bands
        out = {n: p[k * nb:(k + 1) * nb][point_band] for k, n in enumerate(self.regional)}
        out.update({n: float(v) for n, v in zip(self.shared, p[len(self.regional) * nb:])})
        return out


def _ivw(rd: RegionalData, model: Model, values: Mapping) -> np.ndarray:
    """IVW (J), shape (n_fields, n_steps), with per-point parameter arrays."""
    c = rd.data.c
    s11, s22, s12 = pk2_components(model, c[..., 0], c[..., 1], c[..., 2], values)
    S = np.stack(np.broadcast_arrays(s11, s22, s12), -1)
    return np.einsum("fspc,spc->fs", rd.data.work_density, S)


def _check_regional(model: Model, regional: Sequence[str] | None) -> tuple:
    if regional is None:
        regional = tuple(n for n, lin in zip(model.parameter_names, model.linear) if lin) or model.parameter_names[:1]
    regional = tuple(regional)
    unknown = [n for n in regional if n not in model.parameter_names]
    if unknown or not regional:
        raise ValueError(f"regional must name parameters of model {model.name!r} {model.parameter_names}; "
                         f"got {regional!r}")
    return regional


def _solve(rd: RegionalData, model: Model, layout: _Layout, x0: np.ndarray):
    """Bounded least squares on the normalised gaps; returns (x, residual function, least_squares result)."""
    scale = rd.data.scale[:, None]

    def residual(x):
        with np.errstate(over="ignore", invalid="ignore"):
            r = ((_ivw(rd, model, layout.point_values(x, rd.point_band)) - rd.data.evw) / scale).ravel()
        return np.clip(np.where(np.isfinite(r), r, 1e6), -1e6, 1e6)

    x0 = np.clip(x0, layout.lower + 1e-9, layout.upper - 1e-9)
    with np.errstate(over="ignore", invalid="ignore"):
        sol = least_squares(residual, x0, jac="3-point", bounds=(layout.lower, layout.upper), method="trf",
                            x_scale=1.0, xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=200)
    return sol.x, residual, sol


def _covariance(residual, x: np.ndarray, cost: float):
    """Gauss-Newton covariance of x from a central-difference Jacobian: (cov_x, sqrt(diag((J^T J)^-1)), m)."""
    n = x.size
    h = 1e-6
    J = np.stack([(residual(x + h * e) - residual(x - h * e)) / (2 * h) for e in np.eye(n)], axis=1)
    m = J.shape[0]
    inv = np.linalg.pinv(J.T @ J, rcond=1e-13)
    s2 = 2.0 * cost / max(m - n, 1)
    return s2 * inv, np.sqrt(np.clip(np.diag(inv), 0.0, None)), m


def _pooled(v: np.ndarray, s: np.ndarray) -> tuple[float, float]:
    """Inverse-variance weighted mean and its standard error (plain mean when an error is 0)."""
    if np.all(s > 0):
        w = 1.0 / s**2
        return float(np.sum(w * v) / np.sum(w)), float(1.0 / np.sqrt(np.sum(w)))
    return float(np.mean(v)), 0.0


def _band_statistics(p: np.ndarray, se: np.ndarray, regional: tuple, n_bands: int):
    """Profiles, standard errors, pooled values, and each band's contrast and z-score against the median band.

    The median of the bands is the reference (the healthy majority of a locally diseased segment; the mean of a
    homogeneous one); its standard error is taken as sqrt(pi/2) times that of the pooled mean.
    """
    profiles, stderr, pooled, contrast, z_score = {}, {}, {}, {}, {}
    for k, n in enumerate(regional):
        sl = slice(k * n_bands, (k + 1) * n_bands)
        v, s = p[sl].copy(), se[sl].copy()
        profiles[n], stderr[n], pooled[n] = v, s, _pooled(v, s)[0]
        if n_bands == 1:
            contrast[n], z_score[n] = np.zeros(1), np.zeros(1)
            continue
        ref = float(np.median(v))
        s_diff = np.hypot(s, np.sqrt(0.5 * np.pi) * _pooled(v, s)[1])
        contrast[n] = v / ref - 1.0
        with np.errstate(divide="ignore", invalid="ignore"):
            z_score[n] = np.where(s_diff > 0, (v - ref) / s_diff, np.inf * np.sign(v - ref))
    return profiles, stderr, pooled, contrast, z_score


def _band_flags(model: Model, regional: tuple, stats, resolution: dict, edges: np.ndarray) -> list[str]:
    """Plain-words warnings per band (as the global fit: poorly identifiable, uncertain) and the differing bands."""
    profiles, stderr, pooled, contrast, z_score = stats
    flags = []
    where = [f"band {b} ({edges[b] * 1e3:.1f} to {edges[b + 1] * 1e3:.1f} mm)" for b in range(len(edges) - 1)]
    for n in regional:
        i = model.parameter_names.index(n)
        kpa = model.units[i] == "Pa"
        for b in np.flatnonzero(~np.isfinite(resolution[n]) | (resolution[n] > RESOLUTION_LIMIT)):
            flags.append(f"{n} in {where[b]} is poorly identifiable: a change of {resolution[n][b]:.2g} (relative) "
                         f"can be compensated within a {GAP_FOR_FLAGS:.0%} virtual-work gap; use fewer bands")
        for b in np.flatnonzero(stderr[n] > 0.3 * np.abs(profiles[n])):
            shown = f"{stderr[n][b] / 1e3:.3g} kPa" if kpa else f"{stderr[n][b]:.3g}"
            flags.append(f"{n} in {where[b]} is uncertain: standard error {shown} is more than 30 % of its value")
        for b in np.flatnonzero((np.abs(z_score[n]) > SIGNIFICANCE) & (np.abs(contrast[n]) > MIN_CONTRAST)):
            flags.append(f"{n} in {where[b]} differs from the median band by {contrast[n][b]:+.0%} "
                         f"({z_score[n][b]:+.1f} standard errors)")
    return flags


def identify_regional(rd: RegionalData, model: str | Model, *, regional: Sequence[str] | None = None,
                      initial: Mapping[str, float] | None = None) -> RegionalResult:
    """Identify per-band values of the ``regional`` parameters (default: the stress-like ones) with the others shared.

    Parameters
    ----------
    rd : RegionalData
        From ``prepare_regional``.
    model : str or Model
    regional : sequence of str, optional
        Parameters that vary between bands (e.g. ``("beta",)`` or all of Fung's for a fully regional fit).
    initial : mapping, optional
        Start (SI); default: the homogeneous fit (``optimize.identify_prepared`` on ``rd.homogeneous``), every band
        at its values.
    """
    model = get_model(model)
    regional = _check_regional(model, regional)
    hom = identify_prepared(rd.homogeneous, model)
    start = model.check_parameters(dict(initial) if initial is not None else dict(hom.parameters))
    layout = _Layout(model, regional, rd.n_bands, start)
    x, residual, sol = _solve(rd, model, layout, layout.to_x(start))
    cost = float(sol.cost)
    cov, d, m = _covariance(residual, x, cost)
    p = layout.to_p(x)
    dpdx = np.where(layout.log, p, layout.scale)
    se = np.abs(dpdx) * np.sqrt(np.clip(np.diag(cov), 0.0, None))
    res_dx = GAP_FOR_FLAGS * np.sqrt(m) * d
    nb, nr = rd.n_bands, len(regional)
    stats = _band_statistics(p, se, regional, nb)
    resolution = {n: res_dx[k * nb:(k + 1) * nb] for k, n in enumerate(regional)}
    flags = _band_flags(model, regional, stats, resolution, rd.edges)
    shared = {n: float(v) for n, v in zip(layout.shared, p[nr * nb:])}
    shared_se = {n: float(v) for n, v in zip(layout.shared, se[nr * nb:])}
    rms = float(np.sqrt(np.mean(sol.fun**2)))
    if rms > 0.05:
        flags.append(f"poor fit: the RMS virtual-work gap is {rms:.1%} of the external work")
    if sol.status <= 0:
        flags.append(f"the optimiser did not report convergence: {sol.message}")
    differs = np.zeros(nb, dtype=bool)
    for n in regional:
        differs |= (np.abs(stats[4][n]) > SIGNIFICANCE) & (np.abs(stats[3][n]) > MIN_CONTRAST)
    return RegionalResult(
        model=model.name, regional=regional, edges=rd.edges.copy(), centres=rd.centres, profiles=stats[0],
        stderr=stats[1], parameters=shared, parameter_stderr=shared_se, pooled=stats[2], contrast=stats[3],
        z_score=stats[4], differs=differs, resolution=resolution, flags=tuple(flags), cost=cost,
        residuals=sol.fun.reshape(rd.data.evw.shape), field_names=rd.data.field_names, converged=sol.status > 0,
        message=str(sol.message), homogeneous=hom)
