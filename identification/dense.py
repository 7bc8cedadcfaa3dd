"""Dense clouds (DIC, issue 25): the balance on a bounded quadrature mesh after smoothing every point.

With smoothing on, what a dense cloud tells about the displacement is the smoothed field: a few dozen
coefficients per component and step fitted by least squares to all the points (linear in their number).
Above ``DENSE_POINTS`` markers per step ``vfm.prepare`` fits them (step axes, outliers and the smoothing on
all of them), then evaluates the smooth reference surface and the
smoothed displacement, with their exact derivatives, on a regular (Theta, Z) grid of ``GRID_ROWS`` x
``GRID_COLUMNS`` nodes between the innermost boundary markers (``mesh.z_bottom`` .. ``mesh.z_top``): the
kinematics, the wall layer, the virtual work and the fit then cost the same whatever the number of points.
Beyond the grid's end rows the virtual fields are zero or a rigid axial translation (no internal work), and
the end force acts across the grid's top row, so the balance is the same. A bootstrap replicate reuses the
data's alignment and step axes (``DenseQuadrature``: rigid motions, measured to leave the replicates' spread
unchanged) and re-smooths its re-noised points, re-choosing the reference radius's basis (that choice does
widen the spread of alpha12 ~4x: docs/validation/dense.md). So do the efficient weighting's moved sets
(``perturbation_settings``), but on the data's reference radius basis: their finite differences are derivatives,
which a discrete re-choice would break (and it cost ~50 ms a moved reference at 50,000 points). What the verdict, the efficient weighting and its intervals compute again on the
same markers is reused: the smooth reference radius per mesh, the quadrature state per markers and options
(``cached_state``), the fitted positions (``cached_fit``).

Frames and units: as ``kinematics`` (m, rad; cylindrical components (radial, circumferential, axial)).
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass, replace

import numpy as np
from scipy.linalg import solve_triangular

from .kinematics import QUADRATURE, SurfaceState, masked_outliers, triangle_geometry
from .mesh import SurfaceMesh, wrap_angle
from .outliers import marker_outliers
from .smoothing import (AUTO_DEGREES, MAX_BASIS_FRACTION, _displacements, _unique_rows, per_component_degrees,
                        reference_radius_degree, resolve_smoothing, smoothing_basis)
from .errors import DegenerateDataError, IdentificationError
from .step_axes import refit_axes
from .thick_fields import flat_end_fields
from .virtual_fields import VirtualFields, check_fields, paper_fields

__all__ = ["DENSE_POINTS", "DenseQuadrature", "cached_fit", "cached_state", "dense_state", "grid_fields",
           "marker_survey", "perturbation_settings", "quadrature_grid", "step_coordinates", "wants_dense"]

log = logging.getLogger(__name__)

#: Markers of the mesh above which a smoothed cloud is evaluated on the quadrature grid.
DENSE_POINTS = 3000
#: Rows (axial) and columns (circumferential) of the quadrature grid's nodes.
GRID_ROWS = 13
GRID_COLUMNS = 24


@dataclass(frozen=True)
class DenseQuadrature:
    """How a dense cloud was evaluated (``VFMData.quadrature``); a bootstrap replicate reuses it.

    Attributes
    ----------
    grid : SurfaceMesh
        The quadrature mesh: ``GRID_ROWS`` x ``GRID_COLUMNS`` nodes on the smooth reference surface; the
        integration points of the ``VFMData`` are on its triangles.
    n_points : int
        Markers of the cloud (mesh vertices) the smoothing was fitted to.
    axes : tuple of Axis
        Every step's axis.
    outliers : ndarray, shape (n_steps, n_markers) bool
        Markers set unobserved as mis-tracked.
    reference_degree : (int, int), optional
        The basis (axial degree, harmonics) of the smooth reference radius, chosen by GCV.
    keep_reference : bool
        A re-preparation reusing this evaluation (``dense_reuse``) fits its reference radius on
        ``reference_degree`` instead of choosing the basis again (``perturbation_settings``).
    """

    grid: SurfaceMesh
    n_points: int
    axes: tuple
    outliers: np.ndarray
    reference_degree: tuple[int, int] | None = None
    keep_reference: bool = False

    def describe(self) -> str:
        return (f"dense cloud: {self.n_points} points evaluated on a quadrature mesh of {self.grid.n_markers} nodes "
                f"({self.grid.n_triangles} triangles)")


def wants_dense(mesh: SurfaceMesh, smoothing, smooth_reference: bool, reference_noise_correction: bool) -> bool:
    """Whether ``prepare`` takes the quadrature path: more than ``DENSE_POINTS`` markers, smoothed, the reference
    radius smoothed too, no errors-in-variables correction."""
    return (smoothing is not None and smooth_reference and not reference_noise_correction
            and int(np.count_nonzero(mesh.used)) > DENSE_POINTS)


def perturbation_settings(settings, quadrature: DenseQuadrature):
    """``settings`` (``vfm.PrepareSettings``) for a re-preparation of a dense cloud whose markers were moved along
    a smooth basis function in the data's aligned frame (``gap_jacobian.Reprepare``, the gaps' derivatives of the
    efficient weighting): on the data's step axes, neither re-aligned nor refitted, as a bootstrap replicate
    (``dense_reuse``). A smooth move changes the alignment and the axes only by rigid motions, which leave the
    gaps unchanged; the fits of 25 axes to every point were most of each re-preparation's time
    (docs/validation/dense.md). A moved reference's radius is fitted on the data's basis (``keep_reference``): the
    finite difference of a smooth move, not of a discrete choice of basis."""
    return replace(settings, dense_reuse=replace(quadrature, keep_reference=True), axes_start=None)


def step_coordinates(aligned: np.ndarray, axes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cylindrical coordinates (n_steps, n_markers) of the aligned positions (n_steps, n_markers, 3) about each
    step's axis (as ``kinematics.step_cylindrical``)."""
    origin = np.stack([a.origin for a in axes])[:, None]  # (s, 1, 3)
    basis = np.stack([a.basis for a in axes])  # (s, 3, 3)
    d = [aligned[..., j] - origin[..., j] for j in range(3)]  # (s, n) each: components written out, ~3x faster
    x, y, z = (d[0] * basis[:, k, 0, None] + d[1] * basis[:, k, 1, None] + d[2] * basis[:, k, 2, None]
               for k in range(3))  # than a batched matmul with an inner size of 3
    return np.hypot(x, y), np.arctan2(y, x), z


def quadrature_grid(mesh: SurfaceMesh, rows: int = GRID_ROWS, columns: int = GRID_COLUMNS) -> SurfaceMesh:
    """A regular (Theta, Z) grid mesh between the measured ends of ``mesh`` (its innermost boundary markers).

    Nodes: ``rows`` x ``columns`` (node ``i columns + j`` at Z_i, Theta_j), each quad split in two triangles
    counter-clockwise in (Theta, Z); bottom and top edges the first and last rows. ``r`` is NaN until
    ``dense_state`` sets the smooth reference radius.
    """
    theta = -np.pi + 2.0 * np.pi * np.arange(columns) / columns
    z = np.linspace(mesh.z_bottom, mesh.z_top, rows)
    i, j = np.meshgrid(np.arange(rows - 1), np.arange(columns), indexing="ij")
    a, b = i * columns + j, i * columns + (j + 1) % columns
    c, d = b + columns, a + columns
    tri = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    jj = np.arange(columns)
    top0 = (rows - 1) * columns
    return SurfaceMesh(axis=mesh.axis, triangles=tri, r=np.full(rows * columns, np.nan),
                       theta=np.tile(theta, rows), z=np.repeat(z, columns), used=np.ones(rows * columns, bool),
                       bottom_edges=np.stack([jj, (jj + 1) % columns], -1),
                       top_edges=np.stack([top0 + (jj + 1) % columns, top0 + jj], -1),
                       z_bottom=float(z[0]), z_top=float(z[-1]), dropped={})


def grid_fields(fields: VirtualFields | None, mesh: SurfaceMesh, grid: SurfaceMesh, wall: str) -> VirtualFields | None:
    """The virtual fields on the grid's nodes: the default ones built there, given ones (at the markers of
    ``mesh``) interpolated along Z when they depend on Z alone (paper, flat-end and band fields: consecutive
    markers in Z differ by at most a tenth of the largest value, and the fields stay admissible on the grid's end
    rows); None otherwise (``prepare`` then takes the full path)."""
    if fields is None:
        out = flat_end_fields(grid) if wall == "thick" else paper_fields(grid)
    else:
        ok = mesh.used & np.isfinite(mesh.z)
        order = np.argsort(mesh.z[ok], kind="stable")
        z = mesh.z[ok][order]
        v = fields.values[:, ok][:, order]  # (f, n, 3)
        scale = max(float(np.abs(v).max()), 1e-300)
        if np.percentile(np.abs(np.diff(v, axis=1)), 99.9) > 0.1 * scale:
            return None  # not a function of Z alone
        zu, first = np.unique(z, return_index=True)
        vu = v[:, first]
        values = np.stack([np.stack([np.interp(grid.z, zu, vu[k, :, c]) for c in range(3)], -1)
                           for k in range(fields.n_fields)])
        out = VirtualFields(names=fields.names, values=values, load_end=fields.load_end)
        try:
            check_fields(out, grid)
        except IdentificationError:
            return None  # not admissible on the grid's end rows: the full path
        return out
    check_fields(out, grid)
    return out


def _coefficients(mesh: SurfaceMesh, degree, d: np.ndarray, weights) -> np.ndarray:
    """Least-squares coefficients (n_steps, n_basis) of every step of ``d`` (n_steps, n_markers) on
    ``smoothing_basis(mesh, degree)`` (the fit of ``smoothing.smooth_cylindrical``)."""
    basis, ok_ref = smoothing_basis(mesh, degree)
    ok = ok_ref[None] & np.isfinite(d)
    masks, inverse = _unique_rows(ok)
    n_b = basis.shape[1]
    if masks.sum(axis=1).min() <= n_b:
        raise DegenerateDataError(f"smoothing with {n_b} basis functions needs more observed markers than that; "
                                  f"some steps have {int(masks.sum(axis=1).min())}")
    if weights is None:
        gram = (basis.T[None] * masks[:, None, :]) @ basis
        bty = np.where(ok, d, 0.0) @ basis
        try:
            return np.linalg.solve(gram[inverse.ravel()], bty[..., None])[..., 0]
        except np.linalg.LinAlgError:
            pass
    w = np.ones_like(d) if weights is None else np.where(np.isfinite(weights), weights, 0.0)
    sw = np.sqrt(np.where(ok, w, 0.0))
    coef = np.zeros((d.shape[0], n_b))
    for k in range(d.shape[0]):
        m = ok[k]
        coef[k] = np.linalg.lstsq(basis[m] * sw[k, m, None], d[k, m] * sw[k, m], rcond=None)[0]
    return coef


def _basis_at(mesh: SurfaceMesh, degree, theta: np.ndarray, z: np.ndarray):
    """``smoothing_basis(mesh, degree)``'s functions and their Theta and Z derivatives at points (n,): three
    arrays (n, n_basis), the columns in the same order (harmonic-major, Legendre degree within)."""
    nz, nt = int(degree[0]), int(degree[1])
    ok_ref = mesh.used & np.isfinite(mesh.z)
    z0 = 0.5 * (np.nanmax(mesh.z[ok_ref]) + np.nanmin(mesh.z[ok_ref]))
    half = 0.5 * (np.nanmax(mesh.z[ok_ref]) - np.nanmin(mesh.z[ok_ref]))
    x = (z - z0) / half
    leg = np.polynomial.legendre.legvander(x, nz)
    eye = np.eye(nz + 1)
    dleg = np.stack([np.polynomial.legendre.legval(x, np.polynomial.legendre.legder(eye[j])) if nz else
                     np.zeros_like(x) for j in range(nz + 1)], axis=1) / half
    four = [np.ones_like(theta)] + [f(k * theta) for k in range(1, nt + 1) for f in (np.cos, np.sin)]
    dfour = [np.zeros_like(theta)] + [g for k in range(1, nt + 1)
                                      for g in (-k * np.sin(k * theta), k * np.cos(k * theta))]
    cat = np.concatenate
    return (cat([leg * f[:, None] for f in four], 1), cat([leg * f[:, None] for f in dfour], 1),
            cat([dleg * f[:, None] for f in four], 1))


def _reference_degree(mesh: SurfaceMesh, candidates=AUTO_DEGREES) -> tuple[int, int]:
    """``smoothing.reference_radius_degree`` (GCV over ``candidates``) from one Gram matrix of the largest basis,
    whose leading blocks (Legendre-degree-major columns per number of harmonics) are those of every candidate
    (``smoothing._nested_gcv`` forms one per number of harmonics); falls back to it on a singular block."""
    nz_max = max(int(c[0]) for c in candidates)
    nt_max = max(int(c[1]) for c in candidates)
    basis, ok_ref = smoothing_basis(mesh, (nz_max, nt_max))
    ok = ok_ref & np.isfinite(mesh.r)
    n = int(ok.sum())
    y = mesh.r[ok] - np.mean(mesh.r[ok])
    B = basis[ok]
    gram, bty = B.T @ B, B.T @ y
    best, best_score = None, np.inf
    wanted = {(int(c[0]), int(c[1])) for c in candidates}
    for nt in sorted({int(c[1]) for c in candidates}):
        cols = (np.arange(nz_max + 1)[:, None] + (nz_max + 1) * np.arange(2 * nt + 1)[None]).ravel()
        try:
            chol = np.linalg.cholesky(gram[np.ix_(cols, cols)])
        except np.linalg.LinAlgError:
            return reference_radius_degree(mesh, candidates)
        proj = solve_triangular(chol, bty[cols], lower=True)
        rss = np.maximum(float(y @ y) - np.cumsum(proj**2), 0.0)
        for nz in range(nz_max + 1):
            p = (nz + 1) * (2 * nt + 1)
            if (nz, nt) in wanted and p <= MAX_BASIS_FRACTION * n:
                score = float(rss[p - 1] / (n * (1.0 - p / n) ** 2))
                if score < best_score:
                    best, best_score = (nz, nt), score
    return best if best is not None else reference_radius_degree(mesh, candidates)


#: The smooth reference radius of recently seen meshes (``_reference_radius``): the data's mesh comes again in the
#: other wall form's preparation, the final fit's and every re-preparation of moved loaded steps.
_REFERENCE_CACHE: dict = {}
_REFERENCE_CACHE_SIZE = 4


#: Results of recent computations on a dense cloud's markers (``cached_fit``).
_FIT_CACHE: dict = {}
_FIT_CACHE_SIZE = 2  # an entry holds two (n_steps, n_markers, 3) arrays: 60 MB at 50,000 points x 25 steps


#: Quadrature states of recent dense clouds (``cached_state``): the gap noise of each wall form re-measures the
#: same replicates (8 each), the final fit re-prepares the chosen setting's markers.
_STATE_CACHE: dict = {}
_STATE_CACHE_SIZE = 10


def _digest(a) -> str:
    a = np.ascontiguousarray(a)
    return hashlib.sha1(a.view(np.uint8)).hexdigest() + str(a.shape) + a.dtype.str


def cached_state(mesh: SurfaceMesh, aligned: np.ndarray, quadrature: int, smoothing, reject_outliers: bool,
                 weights, survey: tuple, once: bool = False, reference_degree: tuple[int, int] | None = None):
    """``dense_state(mesh, aligned, quadrature, smoothing, reject_outliers, weights, survey)``, reused when the same
    markers, mesh coordinates, survey and options come again (a content key: a replicate's mesh is a new object).
    The state returned is shared: not to be modified. ``once``: markers never seen again (a bootstrap replicate, a
    moved set of the efficient weighting: ``estimate_noise=False``): neither looked up nor kept (the key's digests
    of the markers cost ~20 ms at 50,000 points x 25 steps). ``reference_degree``: as ``dense_state``'s."""
    if once:
        return dense_state(mesh, aligned, quadrature, smoothing, reject_outliers, weights, survey, reference_degree)
    axes, outliers, noise = survey
    frame = [mesh.axis.origin, mesh.axis.basis, np.array([mesh.z_bottom, mesh.z_top])]
    arrays = [aligned, mesh.r, mesh.theta, mesh.z, mesh.used, np.stack([a.origin for a in axes]),
              np.stack([a.basis for a in axes]), outliers, noise] + frame
    key = ("dense state", quadrature, repr(smoothing), bool(reject_outliers), mesh.n_markers, repr(reference_degree),
           None if weights is None else _digest(np.asarray(weights, dtype=float))) + tuple(_digest(a) for a in arrays)
    hit = _STATE_CACHE.get(key)
    if hit is not None:
        log.info("%s", hit[1].describe())
        return hit
    out = dense_state(mesh, aligned, quadrature, smoothing, reject_outliers, weights, survey, reference_degree)
    if out is not None:
        if len(_STATE_CACHE) >= _STATE_CACHE_SIZE:
            _STATE_CACHE.pop(next(iter(_STATE_CACHE)))
        _STATE_CACHE[key] = out
    return out


def cached_fit(label: tuple, mesh: SurfaceMesh, arrays: tuple, compute):
    """``compute()`` (a tuple of arrays, returned read-only), reused when ``label``, the mesh object and the
    contents of ``arrays`` come again (digests: a dense cloud's markers are tens of MB; e.g. the fitted positions
    that the gap noise of each wall form, the efficient weighting and its intervals all re-simulate about)."""
    key = (label, id(mesh)) + tuple(_digest(a) for a in arrays)
    hit = _FIT_CACHE.get(key)
    if hit is not None and hit[0] is mesh:
        return hit[1]
    out = tuple(compute())
    for a in out:
        a.flags.writeable = False
    if len(_FIT_CACHE) >= _FIT_CACHE_SIZE:
        _FIT_CACHE.pop(next(iter(_FIT_CACHE)))
    _FIT_CACHE[key] = (mesh, out)
    return out


def _reference_radius(mesh: SurfaceMesh, degree: tuple[int, int] | None = None):
    """(degree, coefficients (n_basis,)) of the smooth reference radius (``smoothing.smooth_reference_radius``'s
    fit, its basis chosen by GCV, or ``degree`` if given); reused for the same mesh object (the entry holds it: its
    ``id`` stays its own)."""
    hit = _REFERENCE_CACHE.get(id(mesh))
    if hit is not None and hit[0] is mesh and (degree is None or hit[1][0] == tuple(degree)):
        return hit[1]
    if degree is not None:  # a moved reference on the data's basis: its mesh is seen once, not kept
        given = (int(degree[0]), int(degree[1]))
        return given, _coefficients(mesh, given, np.where(mesh.used, mesh.r, np.nan)[None], None)[0]
    degree = _reference_degree(mesh)
    coef = _coefficients(mesh, degree, np.where(mesh.used, mesh.r, np.nan)[None], None)[0]
    out = tuple(int(v) for v in degree), coef
    if len(_REFERENCE_CACHE) >= _REFERENCE_CACHE_SIZE:
        _REFERENCE_CACHE.pop(next(iter(_REFERENCE_CACHE)))
    _REFERENCE_CACHE[id(mesh)] = (mesh, out)
    return out


def marker_survey(mesh: SurfaceMesh, aligned: np.ndarray, smoothing, reject_outliers: bool, estimate_noise: bool,
                  reuse: DenseQuadrature | None = None, start: tuple | None = None) -> tuple:
    """What ``dense_state`` learns of the markers before smoothing: every step's axis (``reuse``'s for a
    replicate; fitted from ``start``, one ``Axis`` per step, if given), the mis-tracked markers (n_steps, n_markers)
    bool and the noise estimate (n_steps,) m (``outliers.marker_outliers``; none and NaN when nothing needs them,
    as for a replicate)."""
    if reuse is not None:
        axes = tuple(reuse.axes)
    else:  # as kinematics.step_cylindrical
        axes = tuple(refit_axes(aligned, np.all(np.isfinite(aligned), axis=-1) & mesh.used, mesh.axis,
                                start=None if start is None else list(start)))
    n_s, n_m = aligned.shape[:2]
    if (estimate_noise and reuse is None) or reject_outliers or isinstance(smoothing, str):
        outliers, noise = marker_outliers(mesh, *step_coordinates(aligned, axes))
    else:
        outliers, noise = np.zeros((n_s, n_m), bool), np.full(n_s, np.nan)
    return axes, outliers, noise


def _marker_fields(mesh, aligned, smoothing, reject_outliers, weights, survey):
    """The survey's axes, outliers (those set unobserved) and noise, the smoothing degrees and the cylindrical
    coordinates (n_steps, n_markers) of the markers."""
    axes, outliers, noise = survey
    outliers, (r, th, z) = masked_outliers(outliers, step_coordinates(aligned, axes), reject_outliers)
    degrees = resolve_smoothing(mesh, r, th, z, smoothing, noise, weights)
    return axes, outliers, noise, degrees, (r, th, z)


def dense_state(mesh: SurfaceMesh, aligned: np.ndarray, quadrature: int, smoothing, reject_outliers: bool,
                weights, survey: tuple, reference_degree: tuple[int, int] | None = None):
    """``kinematics.surface_state`` of a dense cloud, on the quadrature grid (module docstring).

    Parameters as ``surface_state`` (aligned (n_steps, n_markers, 3) m); ``survey``: ``marker_survey``'s axes,
    outliers and noise of these markers; ``reference_degree``: the smooth reference radius's basis (default: chosen
    by GCV, ``_reference_degree``). Returns ``(state, DenseQuadrature)`` with the state's
    triangles those of the grid, or None when the markers look exact (``smoothing="auto"`` keeps them unsmoothed).
    """
    bary, qw = QUADRATURE[quadrature]
    axes, outliers, noise, degrees, (r, th, z) = _marker_fields(mesh, aligned, smoothing, reject_outliers, weights,
                                                                survey)
    if degrees is None:
        return None
    degrees = per_component_degrees(degrees)
    ref_degree, ref_coef = _reference_radius(mesh, reference_degree)
    coefs = [_coefficients(mesh, deg, d, weights) for deg, d in zip(degrees, _displacements(mesh, r, th, z))]
    grid = quadrature_grid(mesh)
    geo = triangle_geometry(grid)
    tri = grid.triangles
    vt = grid.theta[tri] + geo.theta_offset  # (t, 3) unwrapped vertex angles
    vz = grid.z[tri]
    qt, qz = (vt @ bary.T).ravel(), (vz @ bary.T).ravel()  # quadrature points (t n_q,)
    ct, cz = vt.mean(1), vz.mean(1)  # centroids (t,): where the gradients are taken
    n_t, n_q, n_s = len(tri), len(qw), aligned.shape[0]

    def at(degree, coef, theta, zz):  # values (s, n) and Theta, Z derivatives of a fitted component
        B, Bt, Bz = _basis_at(mesh, degree, theta, zz)
        return coef @ B.T, coef @ Bt.T, coef @ Bz.T

    Rq = at(ref_degree, ref_coef[None], qt, qz)[0][0].reshape(n_t, n_q)
    _, Rt, Rz = at(ref_degree, ref_coef[None], ct, cz)
    R_nodes = at(ref_degree, ref_coef[None], grid.theta, grid.z)[0][0]
    grid = replace(grid, r=R_nodes)
    dq = [at(deg, c, qt, qz)[0].reshape(n_s, n_t, n_q) for deg, c in zip(degrees, coefs)]
    dc = [at(deg, c, ct, cz)[1:] for deg, c in zip(degrees, coefs)]
    dn = [at(deg, c, grid.theta, grid.z)[0] for deg, c in zip(degrees, coefs)]
    R_xi = np.stack([Rt[0], Rz[0]], -1)  # (t, 2)
    r_xi = R_xi[None] + np.stack(dc[0], -1)  # (s, t, 2)
    theta_xi = np.stack([1.0 + dc[1][0], dc[1][1]], -1)
    z_xi = np.stack([dc[2][0], 1.0 + dc[2][1]], -1)
    jac = theta_xi[..., 0] * z_xi[..., 1] - theta_xi[..., 1] * z_xi[..., 0]
    valid = np.isfinite(jac) & (jac > 0.05)
    if not valid.all():
        log.warning("excluded inverted/collapsed quadrature cells per step: %s", (~valid).sum(axis=1).tolist())
    quad = DenseQuadrature(grid=grid, n_points=int(np.count_nonzero(mesh.used)), axes=axes, outliers=outliers,
                           reference_degree=ref_degree)
    st = SurfaceState(R=Rq, R_xi=R_xi, r=Rq[None] + dq[0], r_xi=r_xi, theta=(qt.reshape(n_t, n_q))[None] + dq[1],
                      theta_xi=theta_xi, z_xi=z_xi, valid=valid, outliers=outliers, noise=noise,
                      r_markers=R_nodes[None] + dn[0], theta_markers=wrap_angle(grid.theta[None] + dn[1]),
                      z_markers=grid.z[None] + dn[2], axes=axes, bary=bary, qweight=qw, geometry=geo,
                      smoothing=degrees)
    log.info("%s", quad.describe())
    return st, quad
