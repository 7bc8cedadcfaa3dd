"""Wall geometry of ``vfm.prepare``: the virtual fields through the wall, its layers, and the external work.

The membrane form lumps the wall on the marker surface; the thick form integrates it through its thickness
in layers whose radius follows from incompressibility (``_layer``; see the ``vfm`` module docstring). The
external work is the pressure's on the loaded surface and the end force's (``end_force``). Units SI (m, Pa,
N, J); shapes in the docstrings.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix

from .errors import DegenerateDataError
from .kinematics import _grad, reference_frame
from .mesh import SurfaceMesh, unique_sorted, wrap_angle
from .virtual_fields import VirtualFields

__all__ = ["end_force"]


def _loop_area(edges: np.ndarray, r2: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Area enclosed by a boundary loop projected on the cross-section, ``1/2 \u222e r^2 d theta``.

    ``r2`` and ``theta`` have shape (n_steps, n_markers); r^2 is interpolated as for r linear in theta.
    """
    a, b = edges[:, 0], edges[:, 1]
    dth = wrap_angle(theta[:, b] - theta[:, a])
    ra, rb = np.sqrt(r2[:, a]), np.sqrt(r2[:, b])
    return np.abs(0.5 * np.nansum(dth * (ra * ra + ra * rb + rb * rb) / 3.0, axis=1))


def end_force(axial_force: np.ndarray, pressure: np.ndarray, loop_area: np.ndarray, clamp_area: float | None):
    """Axial force carried by the wall across the top measured boundary (N).

    Between the last row of markers and the clamp the tube is not measured; its axial equilibrium
    gives ``N = F + p (A_loop - A_clamp)`` with A_loop the cross-section area enclosed by the
    pressurised surface along the measured boundary and A_clamp the one at the clamp (the
    projected area on which the pressure pushes the unmeasured taper). ``clamp_area=None``
    (free ends: uniform tube up to the load cell) gives ``N = F``.
    """
    if clamp_area is None:
        return np.asarray(axial_force, dtype=float)
    return axial_force + pressure * (loop_area - clamp_area)


def _external_work(wg, surface, mesh: SurfaceMesh, st, fields: VirtualFields, p, f, wall: str, ends: str, e0: float,
                   clamp_radius):
    """External virtual work per field and step (J): the pressure's on the loaded surface (the markers' for
    the membrane form, the lumen for the thick one) and the end force's; with the end force N (n_steps,)
    that the fields' load end carries and the pressure's share on the unmeasured strip (``strip_force``, N)."""
    loaded = surface if wall == "membrane" else _layer(wg, 0.0)
    pressure_work = p[None] * _pressure_work_per_pascal(wg, loaded)
    loop_area = _top_loop_area(mesh, st, wg.jac, wall, e0)
    n_end = end_force(f, p, loop_area, _clamp_area(mesh, ends, wall, e0, clamp_radius))
    strip_force = end_force(f, p, loop_area, _clamp_area(mesh, "clamped", wall, e0, clamp_radius)) - f
    end_work = fields.load_end[:, None] * n_end[None]
    return pressure_work, end_work, n_end, strip_force


@dataclass(frozen=True)
class _WallGeometry:
    """Parameter-independent arrays shared by the layers of the wall (internal to ``prepare``).

    Shapes: f fields, s steps, t triangles, q quadrature points; trailing 2 = xi = (Theta, Z).
    """

    e0: float
    valid: np.ndarray    # (s, t)
    jac: np.ndarray      # (s, t) d(theta, z) / d(Theta, Z), 1 where invalid
    R: np.ndarray        # (1, t, q) reference radius at the markers
    R_xi: np.ndarray     # (1, t, 1, 2)
    r: np.ndarray        # (s, t, q) current radius at the markers
    r_xi: np.ndarray     # (s, t, 1, 2)
    th_xi: np.ndarray    # (s, t, 1, 2)
    z_xi: np.ndarray     # (s, t, 1, 2)
    area_q: np.ndarray   # (1, t, q) parametric area x quadrature weight
    u_q: np.ndarray      # (f, t, q, 3) virtual field at the quadrature points (r, theta, z components)
    u_xi: np.ndarray     # (f, t, 3, 2) its xi-gradient
    d_theta: np.ndarray  # (f, s, t) d u_theta / d theta (current)
    d_z: np.ndarray      # (f, s, t) d u_z / d z (current)


def _wall_geometry(fields: VirtualFields, mesh: SurfaceMesh, st, e0: float) -> _WallGeometry:
    """Virtual-field values and gradients, and the current-coordinate derivatives of the extension."""
    geo = st.geometry
    uv = fields.values[:, mesh.triangles]  # (n_fields, n_tri, 3 vertices, 3 comps)
    u_q = np.einsum("ftvc,qv->ftqc", uv, st.bary)
    u_xi = np.moveaxis(_grad(np.moveaxis(uv, -1, -3), geo.dinv), -3, -2)  # (f, t, comp, 2)
    th_xi, z_xi = st.theta_xi, st.z_xi  # (s, t, 2)
    jac = th_xi[..., 0] * z_xi[..., 1] - th_xi[..., 1] * z_xi[..., 0]  # (s, t)
    if st.valid.sum() < 0.5 * st.valid.size:
        raise DegenerateDataError("more than half of the triangles are unobserved or inverted (check marker "
                                  "identities and noise)")
    jac = np.where(st.valid, jac, 1.0)
    d_theta = (z_xi[None, ..., 1] * u_xi[:, None, :, 1, 0] - z_xi[None, ..., 0] * u_xi[:, None, :, 1, 1]) / jac
    d_z = (-th_xi[None, ..., 1] * u_xi[:, None, :, 2, 0] + th_xi[None, ..., 0] * u_xi[:, None, :, 2, 1]) / jac
    return _WallGeometry(
        e0=e0, valid=st.valid, jac=jac, R=st.R[None], R_xi=st.R_xi[None, :, None, :], r=st.r,
        r_xi=st.r_xi[:, :, None, :], th_xi=th_xi[:, :, None, :], z_xi=z_xi[:, :, None, :],
        area_q=geo.param_area[None, :, None] * st.qweight[None, None, :], u_q=u_q, u_xi=u_xi, d_theta=d_theta,
        d_z=d_z)


def _layer(g: _WallGeometry, sv: float):
    """Kinematics and virtual gradients of the layer at reference depth fraction sv (1 = markers).

    Returns C (s, t, q, 3) and dE* (f, s, t, q, 3) as their (11, 22, 12) components, dA0 (s, t, q),
    n da (s, t, q, 3) and the virtual displacement there (f, s, t, q, 3).
    """
    depth = (1.0 - sv) * g.e0
    R, R_xi, r, r_xi, thx, zx = g.R, g.R_xi, g.r, g.r_xi, g.th_xi, g.z_xi
    J = g.jac[..., None]  # (s, t, 1)
    kappa = depth * (2.0 * R - depth)  # R^2 - R_s^2
    r2 = r * r - kappa / J
    if np.any(r2[g.valid] <= 0):
        raise DegenerateDataError("the wall thickness exceeds the measured radius (check thickness units: m)")
    r_s = np.sqrt(np.where(r2 > 0, r2, 1.0))
    r_s_xi = (r[..., None] * r_xi - depth * R_xi / J[..., None]) / r_s[..., None]
    ginv, area_factor = reference_frame(np.broadcast_to(R_xi, R.shape + (2,)), R - depth)  # (1, t, q, ...)
    # the current xi-tangents t_j = (r_s,xi_j, r_s theta,xi_j, z,xi_j) in cylindrical components, (s, t, q) each
    tan = [[r_s_xi[..., j], r_s * thx[..., j], np.broadcast_to(zx[..., j], r_s.shape)] for j in (0, 1)]
    g00, g01, g11 = ginv[..., 0, 0], ginv[..., 0, 1], ginv[..., 1, 1]  # ginv is upper triangular
    # divergence-free extension of the fields to this layer
    ur_o = g.u_q[..., 0][:, None]  # (f, 1, t, q)
    ur_o_xi = g.u_xi[:, None, :, None, 0, :]  # (f, 1, t, 1, 2)
    Dz, Dt = g.d_z[..., None], g.d_theta[..., None]  # (f, s, t, 1)
    if depth == 0.0:  # the marker surface: the extension is the field itself
        ur = np.broadcast_to(ur_o, Dz.shape[:2] + ur_o.shape[2:])
        ur_xi = np.broadcast_to(ur_o_xi, ur.shape + (2,))
    else:
        ur = (r * ur_o + 0.5 * kappa / J * Dz - (r_s - r) * Dt) / r_s
        ur_xi = (r_xi * ur_o[..., None] + r[..., None] * ur_o_xi + depth * R_xi / J[..., None] * Dz[..., None]
                 - (r_s_xi - r_xi) * Dt[..., None] - r_s_xi * ur[..., None]) / r_s[..., None]
    ut, ut_xi = g.u_q[..., 1][:, None], g.u_xi[:, None, :, None, 1, :]
    uz, uz_xi = g.u_q[..., 2][:, None], g.u_xi[:, None, :, None, 2, :]
    du = (ur_xi - ut[..., None] * thx, ut_xi + ur[..., None] * thx, uz_xi)  # (f, s, t, q, 2) per (r, theta, z)
    # G_ij = t_i . du_j (the xi-tangents t_i = columns of Fxi), then dE = sym(ginv^T G ginv), in components
    G = [[_dot3(tan[i], [du[c][..., j] for c in range(3)]) for j in (0, 1)] for i in (0, 1)]
    dE = _congruent_components(g00, g01, g11, G[0][0], 0.5 * (G[0][1] + G[1][0]), G[1][1])
    M = [[_dot3(tan[i], tan[j]) for j in (0, 1)] for i in (0, 1)]
    C = _congruent_components(g00, g01, g11, M[0][0], M[0][1], M[1][1])  # C = F^T F with F = Fxi ginv
    normal_da = _cross_components(tan[0], tan[1]) * g.area_q[..., None]  # (s, t, q, 3)
    u_here = np.stack([ur, np.broadcast_to(ut, ur.shape), np.broadcast_to(uz, ur.shape)], -1)
    return C, dE, area_factor * g.area_q, normal_da, u_here


def _cross_components(a, b) -> np.ndarray:
    """``kinematics._cross`` of two vectors given as their three component arrays (no stacked copies): (..., 3)."""
    return np.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]], -1)


def _dot3(a, b):
    """``a[0] b[0] + a[1] b[1] + a[2] b[2]`` of three components each (what ``sum`` of the products gives,
    without its first pass adding 0)."""
    out = a[0] * b[0] + a[1] * b[1]
    last = a[2] * b[2]
    if out.shape != np.broadcast_shapes(out.shape, last.shape):
        return out + last
    out += last
    return out


def _congruent_components(g00, g01, g11, s00, s01, s11) -> np.ndarray:
    """(11, 22, 12) components of ``ginv^T S ginv`` for a symmetric S and an upper-triangular ginv: (..., 3)."""
    return np.stack(np.broadcast_arrays(g00 * g00 * s00, g01 * g01 * s00 + 2.0 * g01 * g11 * s01 + g11 * g11 * s11,
                                        g00 * (g01 * s00 + g11 * s01)), -1)


def _internal_work_terms(g: _WallGeometry, wall: str, n_layers: int):
    """C components (s, n_points, 3) and work densities (f, s, n_points, 3) over the wall's layers.

    Also returns the marker-surface layer (for the membrane's external work).
    """
    if wall == "membrane":
        s_nodes, s_weights = np.array([1.0]), np.array([1.0])
    else:
        gl, wl = np.polynomial.legendre.leggauss(int(n_layers))
        s_nodes, s_weights = 0.5 * (gl + 1.0), 0.5 * wl
    valid = g.valid[:, :, None]  # (s, t, 1)
    n_fields, n_steps = g.d_z.shape[:2]
    cs, dens, surface = [], [], None
    for sv, sw in zip(s_nodes, s_weights):
        layer = _layer(g, sv)
        C, dE, dA0 = layer[:3]  # C (s, t, q, 3) and dE (f, s, t, q, 3) as (11, 22, 12) components
        if sv == 1.0:
            surface = layer
        dV0 = np.where(valid, dA0 * g.e0 * sw, 0.0)  # (s, t, q)
        C = np.where(valid[..., None], C, _IDENTITY)
        cs.append(C.reshape(n_steps, -1, 3))
        dE = np.where(valid[None, ..., None], dE, 0.0)  # excluded triangles may hold NaN geometry
        dE *= _SHEAR_TWICE  # in place: the same products as (dE * _SHEAR_TWICE) * dV0
        dE *= dV0[None, ..., None]
        dens.append(dE.reshape(n_fields, n_steps, -1, 3))
    return np.concatenate(cs, axis=1), np.concatenate(dens, axis=2), surface


#: (11, 22, 12) components of the identity, and the factors of the work density (dE11, dE22, 2 dE12)
_IDENTITY = np.array([1.0, 1.0, 0.0])

_SHEAR_TWICE = np.array([1.0, 1.0, 2.0])


def _pressure_work_per_pascal(g: _WallGeometry, layer) -> np.ndarray:
    """Virtual work of a unit pressure on the loaded surface ``layer``, shape (n_fields, n_steps)."""
    _, _, _, normal_da, u_here = layer
    with np.errstate(invalid="ignore"):
        pw = np.einsum("stqc,fstqc->fst", normal_da, u_here)
    return np.where(g.valid[None], np.nan_to_num(pw), 0.0).sum(-1)


def _top_loop_area(mesh: SurfaceMesh, st, jac: np.ndarray, wall: str, e0: float) -> np.ndarray:
    """Cross-section area (m^2) enclosed by the pressurised surface along the top boundary, per step."""
    r2 = st.r_markers**2
    if wall == "thick":
        # per-marker J (mean over its triangles) for the lumen radius along the loop
        tri = mesh.triangles
        incidence = csr_matrix((np.ones(tri.size), (tri.ravel(), np.arange(tri.size))),
                               shape=(mesh.n_markers, tri.size))
        per_vertex = np.repeat(np.where(st.valid, jac, 0.0), 3, axis=1)  # (s, 3 t), vertices in tri.ravel() order
        jm = (incidence @ per_vertex.T).T
        cnt = (incidence @ np.repeat(st.valid.astype(float), 3, axis=1).T).T
        jm = jm / np.maximum(cnt, 1.0)
        kappa_m = e0 * (2.0 * mesh.r - e0)
        r2 = r2 - kappa_m[None] / np.where(jm > 0, jm, np.nan)
    top = unique_sorted(mesh.top_edges)
    r2_top = r2[:, top]
    fillv = np.nanmean(np.where(np.isfinite(r2_top), r2_top, np.nan), axis=1, keepdims=True)
    r2 = r2.copy()
    r2[:, top] = np.where(np.isfinite(r2_top), r2_top, fillv)
    th_all = st.theta_markers
    th_use = np.where(np.isfinite(th_all), th_all, np.broadcast_to(mesh.theta, th_all.shape))
    return _loop_area(mesh.top_edges, r2, th_use)


def _clamp_area(mesh: SurfaceMesh, ends: str, wall: str, e0: float, clamp_radius: float | None) -> float | None:
    """Area (m^2) on which the pressure pushes at the load-cell clamp; None for free ends."""
    if ends != "clamped":
        return None
    rc = float(np.mean(mesh.r[unique_sorted(mesh.top_edges)])) if clamp_radius is None else float(clamp_radius)
    if clamp_radius is None and wall == "thick":
        rc -= e0
    return np.pi * rc * rc
