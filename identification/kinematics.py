"""Membrane kinematics per triangle, interpolated in cylindrical coordinates.

Each triangle of the ``SurfaceMesh`` is parametrised by the reference cylindrical coordinates
xi = (Theta, Z) of its markers; r, theta, z of the current configuration (and any vector field
given by its cylindrical components) are interpolated linearly in xi. The surface is therefore a
piece of a cylinder-like surface, not a flat chord triangle: flat triangles over-estimate the hoop
virtual work by ~2 % at 300 markers (see ``docs/validation/identification.md``).

Local frame of a triangle (reference configuration): e1 along the circumferential tangent, e2 the
in-plane axial direction orthogonal to it (Gram-Schmidt). Frames and units: ``docs/decisions``;
positions in m, world frame; cylindrical components in the order (radial, circumferential, axial).

Every step is first brought onto the reference by the best rigid motion (Kabsch), so that the
results are objective: a rigid rotation of the deformed markers changes nothing.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from .errors import DegenerateDataError
from .mesh import SurfaceMesh, wrap_angle
from .outliers import marker_outliers
from .smoothing import (AUTO_DEGREES, resolve_smoothing, select_smoothing, smooth_cylindrical, smooth_reference_radius,
                        smoothing_basis)
from .step_axes import refit_axes

__all__ = ["AUTO_DEGREES", "Kinematics", "align_steps", "membrane_kinematics", "QUADRATURE", "select_smoothing",
           "smooth_cylindrical", "smoothing_basis"]

log = logging.getLogger(__name__)

# Barycentric quadrature rules on a triangle: (points (n_q, 3), weights (n_q,), summing to 1).
QUADRATURE = {
    1: (np.full((1, 3), 1.0 / 3.0), np.ones(1)),
    3: (np.array([[2 / 3, 1 / 6, 1 / 6], [1 / 6, 2 / 3, 1 / 6], [1 / 6, 1 / 6, 2 / 3]]), np.full(3, 1.0 / 3.0)),
}


def align_steps(positions: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rigidly align every step onto the reference configuration (Kabsch, finite markers only).

    Parameters
    ----------
    positions : ndarray, shape (n_steps, n_markers, 3)
        m, NaN = not observed.
    reference : ndarray, shape (n_markers, 3)

    Returns
    -------
    aligned : ndarray, shape (n_steps, n_markers, 3)
        ``R_m x + t_m`` for each step m.
    rotation : ndarray, shape (n_steps, 3, 3)
    translation : ndarray, shape (n_steps, 3)
    """
    x = np.asarray(positions, dtype=float)
    ref = np.asarray(reference, dtype=float)
    ok = np.all(np.isfinite(x), axis=-1) & np.all(np.isfinite(ref), axis=-1)[None]  # (n_steps, n_markers)
    w = ok.astype(float)
    count = np.maximum(w.sum(1), 1.0)[:, None]
    xz = np.where(ok[..., None], x, 0.0)
    rz = np.where(ok[..., None], ref[None], 0.0)
    cx = xz.sum(1) / count
    cr = rz.sum(1) / count
    H = np.swapaxes(w[..., None] * (xz - cx[:, None]), 1, 2) @ (rz - cr[:, None])  # (s, 3, 3)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, -1, -2) @ np.swapaxes(U, -1, -2)))
    D = np.zeros_like(H)
    D[:, 0, 0] = 1.0
    D[:, 1, 1] = 1.0
    D[:, 2, 2] = d
    R = np.swapaxes(Vt, -1, -2) @ D @ np.swapaxes(U, -1, -2)
    t = cr - (R @ cx[..., None])[..., 0]
    aligned = x @ np.swapaxes(R, 1, 2) + t[:, None]
    return aligned, R, t


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], -1)


@dataclass(frozen=True)
class TriangleGeometry:
    """Static reference quantities per triangle (internal to the stage).

    Attributes
    ----------
    dinv : ndarray, shape (n_tri, 2, 2)
        Inverse of the (Theta, Z) edge matrix: ``grad_xi f = [f1 - f0, f2 - f0] @ dinv``.
    param_area : ndarray, shape (n_tri,)
        Area of the triangle in the (Theta, Z) plane (rad m).
    theta_offset : ndarray, shape (n_tri, 3)
        Per-vertex multiple of 2 pi that unwraps the reference angles across the seam.
    """

    dinv: np.ndarray
    param_area: np.ndarray
    theta_offset: np.ndarray


def triangle_geometry(mesh: SurfaceMesh) -> TriangleGeometry:
    tri = mesh.triangles
    th = mesh.theta[tri]
    unwrapped = th[:, :1] + np.concatenate([np.zeros((len(tri), 1)), wrap_angle(th[:, 1:] - th[:, :1])], axis=1)
    z = mesh.z[tri]
    D0 = np.stack([unwrapped[:, 1:] - unwrapped[:, :1], z[:, 1:] - z[:, :1]], axis=1)  # rows (Theta, Z), cols edges
    det = D0[:, 0, 0] * D0[:, 1, 1] - D0[:, 0, 1] * D0[:, 1, 0]
    if np.any(np.abs(det) <= 0):
        raise DegenerateDataError("a mesh triangle has zero area in the (theta, z) plane")
    # the 2 x 2 inverses by their adjugate (a quarter of np.linalg.inv's time on ~600 small matrices)
    dinv = np.stack([np.stack([D0[:, 1, 1], -D0[:, 0, 1]], -1), np.stack([-D0[:, 1, 0], D0[:, 0, 0]], -1)], -2)
    return TriangleGeometry(dinv=dinv / det[:, None, None], param_area=0.5 * np.abs(det), theta_offset=unwrapped - th)


def _grad(values: np.ndarray, dinv: np.ndarray) -> np.ndarray:
    """Vertex values ``(..., n_tri, 3)`` -> xi-gradient ``(..., n_tri, 2)``."""
    delta = values[..., 1:] - values[..., :1]
    # the two-term sum written out: ~3x faster than einsum's generic loop over the batch axes, same numbers
    return delta[..., :1] * dinv[:, 0] + delta[..., 1:] * dinv[:, 1]


@dataclass(frozen=True)
class SurfaceState:
    """Interpolated reference and current quantities at the quadrature points (internal).

    Shapes: ``(n_steps, n_tri, n_q)`` for values, with a trailing axis of 2 for xi-derivatives.
    """

    R: np.ndarray       # (n_tri, n_q) reference radius at the marker surface
    R_xi: np.ndarray    # (n_tri, 2)
    r: np.ndarray       # (n_steps, n_tri, n_q)
    r_xi: np.ndarray    # (n_steps, n_tri, 2)
    theta: np.ndarray   # (n_steps, n_tri, n_q) current angle
    theta_xi: np.ndarray
    z_xi: np.ndarray
    valid: np.ndarray   # (n_steps, n_tri) bool
    outliers: np.ndarray  # (n_steps, n_markers) bool, markers set unobserved by marker_outliers
    noise: np.ndarray     # (n_steps,) estimated marker noise (m)
    r_markers: np.ndarray      # (n_steps, n_markers) current cylindrical coordinates of the markers
    theta_markers: np.ndarray
    z_markers: np.ndarray
    axes: tuple
    bary: np.ndarray    # (n_q, 3)
    qweight: np.ndarray  # (n_q,)
    geometry: TriangleGeometry
    smoothing: tuple | None = None  # degrees used: three (nz, nt) pairs (r, theta, z), or None


def step_cylindrical(mesh: SurfaceMesh, aligned: np.ndarray, start: list | None = None):
    """Cylindrical coordinates of every step about its own fitted axis.

    The axis of each (rigidly aligned) step is refitted from its own markers, starting from the
    reference axis (or from ``start``, one ``Axis`` per step: the same minimum in fewer iterations when
    they are close to it), so that a non-rigid deformation that fools the rigid alignment (e.g. an axial
    stretch of an unevenly marked tube) does not tilt the axis.

    Returns ``r, theta, z`` of shape (n_steps, n_markers) and the list of step axes.
    """
    observed = np.all(np.isfinite(aligned), axis=-1) & mesh.used
    axes = refit_axes(aligned, observed, mesh.axis, start=start)
    return (*cylindrical_about(aligned, axes), axes)


def cylindrical_about(aligned: np.ndarray, axes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``r, theta, z`` (n_steps, n_markers) of the positions ``aligned`` (n_steps, n_markers, 3) about each step's
    axis (``axes``, one ``Axis`` per step)."""
    origin = np.stack([a.origin for a in axes])  # (n_steps, 3)
    basis = np.stack([a.basis for a in axes])  # (n_steps, 3, 3)
    local = (aligned - origin[:, None]) @ np.swapaxes(basis, 1, 2)  # (n_steps, n_markers, 3)
    return np.hypot(local[..., 0], local[..., 1]), np.arctan2(local[..., 1], local[..., 0]), local[..., 2]


def masked_outliers(outliers: np.ndarray, coords: tuple, reject: bool) -> tuple[np.ndarray, tuple]:
    """The outliers (n_steps, n_markers) set unobserved (NaN) in the cylindrical coordinates ``coords`` (r, theta,
    z), each (n_steps, n_markers), when ``reject`` (logged per step); else no outlier and the coordinates as given."""
    if not reject:
        return np.zeros(coords[0].shape, bool), coords
    if outliers.any():
        log.warning("markers disagreeing with their neighbours (set unobserved) per step: %s",
                    outliers.sum(axis=1).tolist())
        coords = tuple(np.where(outliers, np.nan, a) for a in coords)
    return outliers, coords


def surface_state(mesh: SurfaceMesh, aligned: np.ndarray, quadrature: int = 1,
                  smoothing: tuple | str | None = None, reject_outliers: bool = True,
                  weights: np.ndarray | None = None, smooth_reference: bool = False,
                  reference_noise_correction: bool = False, estimate_noise: bool = True) -> SurfaceState:
    """Cylindrical interpolation of the aligned positions ``(n_steps, n_markers, 3)``.

    ``smoothing=(axial degree, circumferential harmonics)`` smooths the displacement field first
    (``smooth_cylindrical``); ``"auto"`` chooses the basis of each component from the data
    (``select_smoothing``) unless the markers look exact (estimated noise below ``EXACT_MARKERS``).
    ``weights`` (n_steps, n_markers): relative marker weights (1 / variance) of the smoothing fit.
    ``smooth_reference`` (with smoothing): the reference radius too is replaced by its smooth fit
    (``smooth_reference_radius``), so the noise of the reference markers' radius does not enter the
    reference metric (its slope noise biases the strains by ~sigma^2, see docs "Noise").
    ``reference_noise_correction`` (with smoothing): remove the errors-in-variables bias that the
    reference markers' own noise (estimated from the reference step) causes in the smoothed field.
    ``estimate_noise=False`` (with ``reject_outliers=False``, a given smoothing basis and no reference noise
    correction, as a bootstrap replicate): skip ``marker_outliers``, whose noise estimate (``noise``, NaN then) is
    then used by nothing. ``reject_outliers`` first sets mis-tracked markers (``marker_outliers``)
    to NaN in the steps where they disagree with their neighbours. Triangles that are inverted in a step (a noisy marker crossed an
    edge) are excluded from that step like unobserved ones.
    """
    if quadrature not in QUADRATURE:
        raise ValueError(f"quadrature must be one of {sorted(QUADRATURE)}; got {quadrature}")
    r, th, z, axes = step_cylindrical(mesh, aligned)  # (n_steps, n_markers)
    if estimate_noise or reject_outliers or isinstance(smoothing, str) or reference_noise_correction:
        outliers, noise = marker_outliers(mesh, r, th, z)
    else:
        outliers, noise = np.zeros(r.shape, bool), np.full(r.shape[0], np.nan)
    outliers, (r, th, z) = masked_outliers(outliers, (r, th, z), reject_outliers)
    smoothing = resolve_smoothing(mesh, r, th, z, smoothing, noise, weights)
    R_ref = mesh.r
    if smoothing is not None:
        # the reference step's own "noise" is 0 (d = X - X); the reference markers are measured like the others
        level = float(np.nanmedian(noise[1:])) if reference_noise_correction and noise.size > 1 else float("nan")
        ref_noise = level if reference_noise_correction and np.isfinite(level) else None
        r, th, z = smooth_cylindrical(mesh, r, th, z, smoothing, weights, reference_noise=ref_noise)
        if smooth_reference:
            R_ref = smooth_reference_radius(mesh)
            r = r + (R_ref - mesh.r)[None]  # same displacement, from the smooth reference surface
    return interpolated_state(mesh, (r, th, z), R_ref, quadrature,
                              dict(outliers=outliers, noise=noise, axes=tuple(axes), smoothing=smoothing))


def interpolated_state(mesh: SurfaceMesh, cylindrical: tuple, reference_radius: np.ndarray, quadrature: int,
                       about: dict) -> SurfaceState:
    """The ``SurfaceState`` of the (smoothed) current cylindrical coordinates ``cylindrical = (r, theta, z)``, each
    (n_steps, n_markers), on the reference radius ``reference_radius`` (n_markers,) m; ``about``: the state's
    ``outliers``, ``noise``, ``axes`` and ``smoothing`` (``surface_state``'s second half)."""
    bary, qw = QUADRATURE[quadrature]
    geo = triangle_geometry(mesh)
    tri = mesh.triangles
    r, th, z = cylindrical
    R_ref = reference_radius
    cyl = np.stack([r, th, z])[:, :, tri]  # (r, theta, z) at the vertices: (3, n_steps, n_tri, 3)
    valid = np.all(np.isfinite(cyl), axis=(0, -1))
    # unwrap the current angles of each triangle relative to its first vertex
    thv = cyl[1]
    cyl[1] = thv[..., :1] + np.concatenate([np.zeros_like(thv[..., :1]), wrap_angle(thv[..., 1:] - thv[..., :1])], -1)
    cyl = np.where(valid[..., None], cyl, 0.0)
    rv, thv, zv = cyl
    Rv = R_ref[tri]
    r_xi, theta_xi, z_xi = _grad(cyl, geo.dinv)
    jac = theta_xi[..., 0] * z_xi[..., 1] - theta_xi[..., 1] * z_xi[..., 0]
    inverted = valid & ~(jac > 0.05)  # area in (theta, z) shrunk 20-fold or flipped: a marker crossed an edge
    if inverted.any():
        log.warning("excluded inverted/collapsed triangles per step: %s", inverted.sum(axis=1).tolist())
        valid = valid & ~inverted
    return SurfaceState(
        R=Rv @ bary.T, R_xi=_grad(Rv, geo.dinv),
        r=rv @ bary.T, r_xi=r_xi,
        theta=thv @ bary.T, theta_xi=theta_xi, z_xi=z_xi,
        valid=valid, r_markers=r, theta_markers=th, z_markers=z, bary=bary, qweight=qw, geometry=geo, **about,
    )


def reference_frame(R_xi: np.ndarray, R_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gram-Schmidt local frame of the reference surface.

    Returns ``ginv (..., 2, 2)`` mapping xi-components to local (circumferential, axial) ones
    (``F = F_xi @ ginv``) and the area factor ``|T_Theta x T_Z|`` (m per rad) of shape ``(...)``.
    """
    R_t = R_xi[..., 0]
    R_z = R_xi[..., 1]
    a = np.sqrt(R_t**2 + R_s**2)
    b = R_t * R_z / a
    c = np.sqrt(R_z**2 + 1.0 - b**2)
    zero = np.zeros_like(a)
    ginv = np.stack([np.stack([1.0 / a, -b / (a * c)], -1), np.stack([zero, 1.0 / c], -1)], -2)
    return ginv, a * c


def tangents(r_s, r_s_xi, theta_xi, z_xi) -> np.ndarray:
    """Current tangent vectors ``F_xi`` (..., 3, 2) in the local cylindrical basis (r, theta, z)."""
    cols = [np.stack([r_s_xi[..., j], r_s * theta_xi[..., j], np.broadcast_to(z_xi[..., j], r_s.shape)], -1)
            for j in (0, 1)]
    return np.stack(cols, -1)


@dataclass(frozen=True)
class Kinematics:
    """Per-triangle membrane kinematics at the triangle centroids (marker surface).

    Attributes
    ----------
    F : ndarray, shape (n_steps, n_triangles, 3, 2)
        Deformation gradient from the local reference frame (circumferential, axial) to current
        cylindrical components (radial, circumferential, axial) at the centroid.
    C, E : ndarray, shape (n_steps, n_triangles, 2, 2)
        Right Cauchy-Green and Green-Lagrange tensors in the local frame.
    area_ratio : ndarray, shape (n_steps, n_triangles)
        a / A = sqrt(det C).
    thickness : ndarray, shape (n_steps, n_triangles)
        e0 / (a / A) from incompressibility (m); NaN if no reference thickness was given.
    normal : ndarray, shape (n_steps, n_triangles, 3)
        Outward unit normal, world frame.
    centroid : ndarray, shape (n_steps, n_triangles, 3)
        Interpolated centroid, world frame (m).
    reference_area : ndarray, shape (n_triangles,)
        m^2.
    valid : ndarray, shape (n_steps, n_triangles) bool
        False where a vertex was not observed (all other arrays are NaN there).
    """

    F: np.ndarray
    C: np.ndarray
    E: np.ndarray
    area_ratio: np.ndarray
    thickness: np.ndarray
    normal: np.ndarray
    centroid: np.ndarray
    reference_area: np.ndarray
    valid: np.ndarray


def membrane_kinematics(mesh: SurfaceMesh, positions: np.ndarray, *, thickness: float | None = None,
                        reference: np.ndarray | None = None) -> Kinematics:
    """Deformation of every triangle from the reference to each step.

    Parameters
    ----------
    mesh : SurfaceMesh
    positions : ndarray, shape (n_steps, n_markers, 3)
        Marker positions (m, world frame), NaN = not observed.
    thickness : float, optional
        Reference wall thickness e0 (m).
    reference : ndarray, shape (n_markers, 3), optional
        Reference positions (default: rebuilt from the mesh).
    """
    x = np.asarray(positions, dtype=float)
    if x.ndim != 3 or x.shape[1:] != (mesh.n_markers, 3):
        raise ValueError(f"positions must have shape (n_steps, {mesh.n_markers}, 3); got {x.shape}")
    if reference is None:
        local = np.column_stack([mesh.r * np.cos(mesh.theta), mesh.r * np.sin(mesh.theta), mesh.z])
        reference = local @ mesh.axis.basis + mesh.axis.origin
    aligned, rot, trans = align_steps(x, reference)
    st = surface_state(mesh, aligned, 1)
    ginv, area_factor = reference_frame(st.R_xi[:, None, :], st.R)  # (n_tri, 1, 2, 2)
    Fxi = tangents(st.r, st.r_xi[:, :, None, :], st.theta_xi[:, :, None, :], st.z_xi[:, :, None, :])
    F = (Fxi @ ginv)[:, :, 0]
    C = np.swapaxes(F, -1, -2) @ F
    nan = ~st.valid
    area_ratio = np.sqrt(np.linalg.det(C))
    n_cyl = _cross(Fxi[..., 0], Fxi[..., 1])[:, :, 0]
    n_cyl /= np.linalg.norm(n_cyl, axis=-1, keepdims=True)
    th = st.theta[:, :, 0]
    cos, sin = np.cos(th), np.sin(th)
    n_spec = np.stack([n_cyl[..., 0] * cos - n_cyl[..., 1] * sin, n_cyl[..., 0] * sin + n_cyl[..., 1] * cos,
                       n_cyl[..., 2]], -1)
    zv = np.where(st.valid[..., None], st.z_markers[:, mesh.triangles], np.nan)
    zc = zv.mean(-1)
    c_spec = np.stack([st.r[:, :, 0] * cos, st.r[:, :, 0] * sin, zc], -1)
    # back from each step's specimen frame to the world frame of that step
    basis = np.stack([a.basis for a in st.axes])
    origin = np.stack([a.origin for a in st.axes])
    n_aligned = np.einsum("stj,sji->sti", n_spec, basis)
    c_aligned = np.einsum("stj,sji->sti", c_spec, basis) + origin[:, None]
    normal = np.einsum("sji,stj->sti", rot, n_aligned)
    centroid = np.einsum("sji,stj->sti", rot, c_aligned - trans[:, None])
    e0 = np.nan if thickness is None else float(thickness)

    def mask(a):
        return np.where(nan.reshape(nan.shape + (1,) * (a.ndim - 2)), np.nan, a)

    E = 0.5 * (C - np.eye(2))
    return Kinematics(F=mask(F), C=mask(C), E=mask(E), area_ratio=mask(area_ratio), thickness=mask(e0 / area_ratio),
                      normal=mask(normal), centroid=mask(centroid),
                      reference_area=st.geometry.param_area * area_factor[:, 0], valid=st.valid)
