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
scatter, identifiability per band from the same resolution measure as the global fit (``fit``).

Pure functions over arrays; SI units (m, Pa).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np
from scipy.optimize import least_squares

from .errors import IdentificationError
from .mesh import SurfaceMesh, build_mesh
from .models import Model, get_model
from .models._base import pk2_components
from .fit import GAP_FOR_FLAGS, TYPICAL, identify_prepared
from .regional_result import RegionalResult, with_profile_uncertainty
from .vfm import VFMData, prepare
from .virtual_fields import VirtualFields

__all__ = ["RegionalData", "RegionalResult", "band_edges", "band_fields", "legendre_basis", "prepare_regional",
           "identify_regional", "reprepare", "refit", "with_profile_uncertainty"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RegionalData:
    """Virtual-work balance with band-supported fields, and the profile basis of the regional parameters.

    Attributes
    ----------
    data : VFMData
        From ``vfm.prepare`` with ``band_fields``.
    edges : ndarray, shape (n_bands + 1,)
        Edges of the profile cells in the reference axial coordinate of the mesh (m, from ``mesh.axis.origin``): the
        bands (``kind="bands"``), or the cells whose centres the smooth profile is reported at (``"legendre"``).
    point_band : ndarray, shape (n_points,) int
        Cell of every integration point of ``data`` (its triangle's reference centroid).
    homogeneous : VFMData or None
        The same measurements with the paper's two global fields (the homogeneous fit, for comparison and start);
        None for the bootstrap's replicates.
    kind : {"bands", "legendre"}
    basis : ndarray, shape (n_points, n_coefficients)
        The regional parameter at every integration point is g(basis @ c) with c its coefficients and g = exp for
        positive parameters (log-profile), the identity (times a scale) otherwise. Bands: one-hot of ``point_band``;
        legendre: P_k(s) with s = -1 at ``z_range[0]``, +1 at ``z_range[1]``.
    eval_basis : ndarray, shape (n_bands, n_coefficients)
        The same at the cell centres (the reported profile).
    constant : ndarray, shape (n_coefficients,)
        Coefficients of a constant profile equal to 1 (the start from the homogeneous fit).
    field_edges : ndarray
        Edges (m) of the bands supporting the virtual fields (the profile bands for ``"bands"``).
    z_range : tuple of float
        Axial range (m) of the Legendre variable.
    options : dict
        How ``data`` was prepared (to prepare re-simulated measurements identically).
    """

    data: VFMData
    edges: np.ndarray
    point_band: np.ndarray
    homogeneous: VFMData | None
    kind: str = "bands"
    basis: np.ndarray | None = None
    eval_basis: np.ndarray | None = None
    constant: np.ndarray | None = None
    field_edges: np.ndarray | None = None
    z_range: tuple = (0.0, 1.0)
    options: dict = field(default_factory=dict)

    @property
    def n_bands(self) -> int:
        """Number of profile cells (bands, or the points a smooth profile is reported at)."""
        return len(self.edges) - 1

    @property
    def n_coefficients(self) -> int:
        return int(self.basis.shape[1])

    @property
    def centres(self) -> np.ndarray:
        """Band centres, shape (n_bands,), m (mesh axial coordinate)."""
        return 0.5 * (self.edges[1:] + self.edges[:-1])

    def world_points(self, z) -> np.ndarray:
        """World positions (n, 3) m of the axis points at mesh axial coordinates ``z`` (n,) m."""
        ax = self.data.mesh.axis
        return ax.origin[None] + np.asarray(z, dtype=float)[:, None] * ax.direction[None]


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


def _point_z(mesh: SurfaceMesh, n_points: int, quadrature: int, n_layers: int) -> np.ndarray:
    """Reference axial coordinate (m) of every integration point's triangle centroid, in the point order of
    ``vfm.prepare`` (layers, triangles, quadrature), shape (n_points,)."""
    zc = np.nanmean(mesh.z[mesh.triangles], axis=1)
    z = np.tile(np.repeat(zc, quadrature), n_layers)
    if z.size != n_points:
        raise IdentificationError(f"the prepared data have {n_points} integration points; expected "
                                  f"{z.size} from {mesh.n_triangles} triangles x {quadrature} x {n_layers}")
    return z


def _cell_of(z: np.ndarray, edges: np.ndarray) -> np.ndarray:
    return np.clip(np.searchsorted(edges, z, side="right") - 1, 0, len(edges) - 2)


def legendre_basis(z, z_range: Sequence[float], n_coefficients: int) -> np.ndarray:
    """Legendre polynomials P_0..P_{K-1} of s = 2 (z - z0) / (z1 - z0) - 1, shape (n, K); z (n,) m."""
    z0, z1 = (float(v) for v in z_range)
    s = 2.0 * (np.asarray(z, dtype=float) - z0) / (z1 - z0) - 1.0
    return np.polynomial.legendre.legvander(s, int(n_coefficients) - 1)


#: Legendre profiles: cells the profile is reported at. Its virtual fields are those of K equal bands for K
#: coefficients: measured on exact data, more field bands (6, or 2K) let a profile too smooth for the truth (a local
#: weakening) drag the shared alphas (alpha22 to 0 with K = 1, 6 bands; beta off by 3x), while K bands kept them within
#: 5 % and the profile's RMS error at 12 / 9 % (K = 3 / 5) against 27 / 11 %.
LEGENDRE_PROFILE_CELLS = 16


def _profile_spec(mesh: SurfaceMesh, n_bands, legendre, edges, z_range):
    """(kind, profile cell edges, field band edges, z_range, n_coefficients) of a ``prepare_regional`` call."""
    if (n_bands is None) == (legendre is None):
        raise ValueError(f"give exactly one of n_bands (axial bands) and legendre (coefficients of a smooth profile); "
                         f"got n_bands={n_bands!r}, legendre={legendre!r}")
    zr = (mesh.z_bottom, mesh.z_top) if z_range is None else tuple(float(v) for v in z_range)
    if n_bands is not None:
        e = band_edges(mesh, n_bands) if edges is None else np.asarray(edges, dtype=float)
        return "bands", e, e, zr, len(e) - 1
    if isinstance(legendre, bool) or not isinstance(legendre, (int, np.integer)) or not 1 <= legendre <= 12:
        raise ValueError(f"legendre must be a number of coefficients from 1 to 12; got {legendre!r}")
    cells = np.linspace(zr[0], zr[1], LEGENDRE_PROFILE_CELLS + 1)
    fe = np.linspace(zr[0], zr[1], int(legendre) + 1) if edges is None else edges
    return "legendre", cells, np.asarray(fe, dtype=float), zr, int(legendre)


def prepare_regional(positions: np.ndarray, pressure: np.ndarray, axial_force: np.ndarray, *, thickness: float,
                     n_bands: int | None = None, legendre: int | None = None, mesh: SurfaceMesh | None = None,
                     wall: str = "membrane", quadrature: int = 1, n_layers: int = 4, toward: np.ndarray | None = None,
                     edges: Sequence[float] | None = None, z_range: Sequence[float] | None = None,
                     homogeneous: bool = True, **prepare_options) -> RegionalData:
    """``vfm.prepare`` with band-supported virtual fields, for a profile of ``n_bands`` equal axial bands or of
    ``legendre`` Legendre coefficients of the (log) parameter along the axis.

    Parameters are those of ``vfm.prepare`` (positions (n_steps, n_markers, 3) m, pressure (n_steps,) Pa,
    axial_force (n_steps,) N, thickness m); ``fields`` is set here. ``edges`` (m): the field bands (default: equal
    bands between the measured ends; ``legendre`` of them for a Legendre profile); ``z_range`` (m): of the
    Legendre variable (default the measured ends); ``homogeneous``: also prepare the paper's global fields.
    """
    if "fields" in prepare_options:
        raise ValueError("prepare_regional builds its own band fields; do not pass fields")
    if mesh is None:
        x = np.asarray(positions, dtype=float)
        ref = x[prepare_options.get("reference_step", 0)] if x.ndim == 3 else x
        mesh = build_mesh(ref, toward=toward)
    kind, cells, field_edges, zr, n_coef = _profile_spec(mesh, n_bands, legendre, edges, z_range)
    common = dict(thickness=thickness, wall=wall, quadrature=quadrature, n_layers=n_layers, toward=toward,
                  **prepare_options)
    data = prepare(positions, pressure, axial_force, fields=band_fields(mesh, field_edges), mesh=mesh, **common)
    layers = 1 if wall == "membrane" else int(n_layers)
    zp = _point_z(data.points_mesh, data.c.shape[1], int(quadrature), layers)
    point_band = _cell_of(zp, cells)
    centres = 0.5 * (cells[1:] + cells[:-1])
    if kind == "bands":
        basis, eval_basis, constant = np.eye(n_coef)[point_band], np.eye(n_coef), np.ones(n_coef)
    else:
        basis, eval_basis = legendre_basis(zp, zr, n_coef), legendre_basis(centres, zr, n_coef)
        constant = np.eye(n_coef)[0]
    return RegionalData(data=data, edges=cells, point_band=point_band,
                        homogeneous=prepare(positions, pressure, axial_force, mesh=mesh, **common) if homogeneous
                        else None, kind=kind, basis=basis, eval_basis=eval_basis, constant=constant,
                        field_edges=field_edges, z_range=zr, options=dict(common))


def reprepare(rd: RegionalData, positions: np.ndarray, pressure: np.ndarray, axial_force: np.ndarray,
              mesh: SurfaceMesh, smoothing=None, reject_outliers: bool = False) -> RegionalData:
    """``rd``'s preparation (same bands, basis, smoothing degrees unless ``smoothing`` is given, no homogeneous
    fields) of other measurements on ``mesh`` (the bootstrap's re-simulated ones; shapes as ``prepare_regional``)."""
    options = dict(rd.options, smoothing=rd.data.smoothing if smoothing is None else smoothing,
                   reject_outliers=reject_outliers, ends=rd.data.ends)
    spec = {"n_bands": rd.n_bands} if rd.kind == "bands" else {"legendre": rd.n_coefficients}
    edges = rd.field_edges.copy()  # the same inner edges; the outer ones follow the re-measured boundary
    edges[0], edges[-1] = mesh.z_bottom, mesh.z_top
    return prepare_regional(positions, pressure, axial_force, mesh=mesh, edges=edges, z_range=rd.z_range,
                            homogeneous=False, **spec, **options)


class _Layout:
    """Optimisation vector x <-> parameters: coefficients of the regional ones (log-profile for positive ones), the
    others shared (log for positive ones)."""

    def __init__(self, model: Model, regional: tuple, rd: RegionalData, start: Mapping[str, float]):
        self.model, self.regional, self.rd = model, regional, rd
        self.k = rd.n_coefficients
        self.shared = tuple(n for n in model.parameter_names if n not in regional)
        self.names = [(n, b) for n in regional for b in range(self.k)] + [(n, None) for n in self.shared]
        idx = {n: i for i, n in enumerate(model.parameter_names)}
        self.log = np.array([model.positive[idx[n]] for n, _ in self.names])
        self.scale = np.array([1.0 if lg else max(abs(start[n]), TYPICAL.get(n, 1.0))
                               for (n, _), lg in zip(self.names, self.log)])
        lo = np.array([model.lower[idx[n]] if model.lower else -np.inf for n, _ in self.names], dtype=float)
        hi = np.array([model.upper[idx[n]] if model.upper else np.inf for n, _ in self.names], dtype=float)
        # a non-constant coefficient of a bounded non-log profile is not bounded itself
        loose = np.array([b is not None and rd.constant[b] == 0 for _, b in self.names])
        lo, hi = np.where(loose, -np.inf, lo), np.where(loose, np.inf, hi)
        x0 = self.to_x(start)
        self.lower = np.where(self.log, x0 - 12.0, lo / self.scale)
        self.upper = np.where(self.log, x0 + 12.0, hi / self.scale)

    def to_x(self, start: Mapping[str, float]) -> np.ndarray:
        """Start vector: every regional profile constant at its ``start`` value."""
        v = np.array([start[n] for n, _ in self.names], dtype=float)
        x = np.where(self.log, np.log(np.where(v > 0, v, 1.0)), v / self.scale)
        const = np.array([1.0 if b is None else self.rd.constant[b] for _, b in self.names])
        return x * const

    def shared_values(self, x: np.ndarray) -> np.ndarray:
        tail = slice(len(self.regional) * self.k, None)
        return np.where(self.log[tail], np.exp(x[tail]), x[tail] * self.scale[tail])

    def profile(self, x: np.ndarray, basis: np.ndarray) -> dict:
        """Regional parameter values at the rows of ``basis`` (n, n_coefficients): dict of (n,) arrays (SI)."""
        out = {}
        for j, n in enumerate(self.regional):
            sl = slice(j * self.k, (j + 1) * self.k)
            lin = basis @ x[sl]
            out[n] = np.exp(lin) if self.log[sl.start] else lin * self.scale[sl.start]
        return out

    def point_values(self, x: np.ndarray) -> dict:
        """Parameter dict for ``pk2_components``: (n_points,) arrays for regional ones, floats for shared ones."""
        out = self.profile(x, self.rd.basis)
        out.update({n: float(v) for n, v in zip(self.shared, self.shared_values(x))})
        return out

    def profile_stderr(self, x: np.ndarray, cov: np.ndarray, basis: np.ndarray) -> dict:
        """Delta-method standard errors (SI) of ``profile(x, basis)`` from the covariance of x."""
        values, out = self.profile(x, basis), {}
        for j, n in enumerate(self.regional):
            sl = slice(j * self.k, (j + 1) * self.k)
            sd = np.sqrt(np.clip(np.einsum("ik,kl,il->i", basis, cov[sl, sl], basis), 0.0, None))
            out[n] = np.abs(values[n]) * sd if self.log[sl.start] else self.scale[sl.start] * sd
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


def _solve(rd: RegionalData, model: Model, layout: _Layout, x0: np.ndarray, max_nfev: int = 200):
    """Bounded least squares on the normalised gaps; returns (x, residual function, least_squares result)."""
    scale = rd.data.scale[:, None]

    def residual(x):
        with np.errstate(over="ignore", invalid="ignore"):
            r = ((_ivw(rd, model, layout.point_values(x)) - rd.data.evw) / scale).ravel()
        return np.clip(np.where(np.isfinite(r), r, 1e6), -1e6, 1e6)

    x0 = np.clip(x0, layout.lower + 1e-9, layout.upper - 1e-9)
    with np.errstate(over="ignore", invalid="ignore"):
        sol = least_squares(residual, x0, jac="3-point", bounds=(layout.lower, layout.upper), method="trf",
                            x_scale=1.0, xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=max_nfev)
    return sol.x, residual, sol


def _covariance(residual, x: np.ndarray, cost: float):
    """Gauss-Newton covariance of x from a central-difference Jacobian: (cov_x, (J^T J)^-1, m)."""
    n = x.size
    h = 1e-6
    J = np.stack([(residual(x + h * e) - residual(x - h * e)) / (2 * h) for e in np.eye(n)], axis=1)
    m = J.shape[0]
    inv = np.linalg.pinv(J.T @ J, rcond=1e-13)
    s2 = 2.0 * cost / max(m - n, 1)
    return s2 * inv, inv, m


def identify_regional(rd: RegionalData, model: str | Model, *, regional: Sequence[str] | None = None,
                      initial: Mapping[str, float] | None = None) -> RegionalResult:
    """Identify the profiles of the ``regional`` parameters (default: the stress-like ones) with the others shared.

    Parameters
    ----------
    rd : RegionalData
        From ``prepare_regional`` (bands or a Legendre profile).
    model : str or Model
    regional : sequence of str, optional
        Parameters that vary between bands (e.g. ``("beta",)`` or all of Fung's for a fully regional fit).
    initial : mapping, optional
        Start (SI); default: the homogeneous fit (``fit.identify_prepared`` on ``rd.homogeneous``), every band
        at its values.

    Standard errors are Gauss-Newton (too small on noisy markers); ``regional_uncertainty.with_bootstrap`` replaces
    them by a parametric bootstrap that covers the truth.
    """
    model = get_model(model)
    regional = _check_regional(model, regional)
    if rd.homogeneous is None:
        raise ValueError("rd was prepared with homogeneous=False; identify_regional needs the homogeneous fields")
    hom = identify_prepared(rd.homogeneous, model)
    start = model.check_parameters(dict(initial) if initial is not None else dict(hom.parameters))
    layout = _Layout(model, regional, rd, start)
    x, residual, sol = _solve(rd, model, layout, layout.to_x(start))
    cost = float(sol.cost)
    cov, inv, m = _covariance(residual, x, cost)
    nc = len(regional) * layout.k
    profiles = layout.profile(x, rd.eval_basis)
    stderr = layout.profile_stderr(x, cov, rd.eval_basis)
    res_rel = {n: GAP_FOR_FLAGS * np.sqrt(m) * se / np.where(profiles[n] != 0, np.abs(profiles[n]), 1.0)
               for n, se in layout.profile_stderr(x, inv, rd.eval_basis).items()}
    shared = {n: float(v) for n, v in zip(layout.shared, layout.shared_values(x))}
    dpdx = np.where(layout.log[nc:], layout.shared_values(x), layout.scale[nc:])
    shared_se = {n: float(v) for n, v in zip(layout.shared, np.abs(dpdx) * np.sqrt(np.clip(np.diag(cov)[nc:], 0, None)))}
    flags = []
    rms = float(np.sqrt(np.mean(sol.fun**2)))
    if rms > 0.05:
        flags.append(f"poor fit: the RMS virtual-work gap is {rms:.1%} of the external work")
    if sol.status <= 0:
        flags.append(f"the optimiser did not report convergence: {sol.message}")
    coefficients = {n: x[j * layout.k:(j + 1) * layout.k].copy() for j, n in enumerate(regional)}
    empty = {n: np.zeros(rd.n_bands) for n in regional}
    result = RegionalResult(
        model=model.name, regional=regional, edges=rd.edges.copy(), centres=rd.centres, profiles=profiles,
        stderr=stderr, parameters=shared, parameter_stderr=shared_se, pooled={}, contrast=empty, z_score=empty,
        differs=np.zeros(rd.n_bands, dtype=bool), resolution=res_rel, flags=tuple(flags), cost=cost,
        residuals=sol.fun.reshape(rd.data.evw.shape), field_names=rd.data.field_names, converged=sol.status > 0,
        message=str(sol.message), homogeneous=hom, kind=rd.kind, coefficients=coefficients, covariance=cov)
    return with_profile_uncertainty(result, stderr, shared_se, 1.959964, "gauss-newton")


def refit(rd: RegionalData, result: RegionalResult, max_nfev: int = 60) -> tuple[dict, dict, float, bool]:
    """Re-identify ``rd`` (a ``reprepare``d replicate) from ``result``'s coefficients, with no homogeneous fit nor
    errors: (profiles dict of (n_bands,) SI, shared dict, RMS normalised gap, converged) for the bootstrap."""
    model = get_model(result.model)
    start = dict(result.homogeneous.parameters, **result.parameters)
    layout = _Layout(model, result.regional, rd, start)
    x0 = np.concatenate([result.coefficients[n] for n in result.regional] + [layout.to_x(start)[len(
        result.regional) * layout.k:]])
    x, _, sol = _solve(rd, model, layout, x0, max_nfev=max_nfev)
    shared = dict(zip(layout.shared, layout.shared_values(x)))
    return layout.profile(x, rd.eval_basis), shared, float(np.sqrt(np.mean(sol.fun**2))), sol.status > 0
