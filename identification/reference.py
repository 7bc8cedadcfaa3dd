"""The reference configuration treated as measured: each marker's material coordinates estimated from every step.

The paper (and ``prepare``) takes the reference step's marker positions as the material coordinates: their noise
enters every displacement and the reference metric of every triangle, so it is shared by all steps and does not
average out (at 0.17 mm, a third of the axial field's gap noise and a bias of the axial gap, ``docs/validation/
efficiency.md``). Here every marker's material coordinates (Theta_i, Z_i) are unknowns, as in the Cramér-Rao bound
of ``information``: each step's position of a marker is a smooth map of them plus noise,

    r_m,i = R_m(Theta_i, Z_i),  theta_m,i = Theta_i + u_m(Theta_i, Z_i),  z_m,i = Z_i + w_m(Theta_i, Z_i),

with R_m, u_m, w_m on the smoothing basis (Legendre(Z) x Fourier(Theta)) and the reference map the identity in
(theta, z) (the gauge). Alternating least squares: the maps given the coordinates (linear), then each marker's two
coordinates given the maps (a 2 x 2 Gauss-Newton step per marker, vectorised). The reference step's positions are
then replaced by the smooth reference surface at the estimated coordinates; the other steps are left as measured.
Units m, rad; frames as ``kinematics.step_cylindrical``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .kinematics import align_steps, step_cylindrical
from .mesh import SurfaceMesh, wrap_angle
from .smoothing import per_component_degrees, smoothing_basis, smoothing_basis_derivative

__all__ = ["refine_reference", "REFERENCE_RADIUS_DEGREE"]

#: Basis of the reference surface's radius (axial degree, harmonics), as ``resimulation.fitted_positions``.
REFERENCE_RADIUS_DEGREE = (4, 2)


def _fit(B: np.ndarray, y: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Least-squares coefficients (S, n_b) of y (S, N) on B (N, n_b) over the observed markers of each step."""
    coef = np.zeros((y.shape[0], B.shape[1]))
    for s in range(y.shape[0]):
        use = ok[s]
        coef[s] = np.linalg.lstsq(B[use], y[s, use], rcond=None)[0]
    return coef


def refine_reference(positions: np.ndarray, mesh: SurfaceMesh, degrees, *, n_iterations: int = 2) -> np.ndarray:
    """``positions`` (n_steps, n_markers, 3), m, with the reference step (0) replaced by its estimate from all steps.

    ``mesh``: the mesh of the measured reference; ``degrees``: the smoothing basis of the displacement (three
    (nz, nt) pairs, r, theta, z, as ``VFMData.smoothing``). Markers outside the mesh keep their measured reference.
    """
    x = np.asarray(positions, dtype=float)
    aligned, _, _ = align_steps(x, x[0])
    r, th, z, axes = step_cylindrical(mesh, aligned)  # (S, N) about each step's own axis
    ok = np.isfinite(r) & np.isfinite(th) & np.isfinite(z) & mesh.used[None]
    degs = per_component_degrees(degrees)
    # the measured reference in its own step frame (the frame the positions are rebuilt in)
    T_meas, Z_meas = np.where(ok[0], th[0], 0.0), np.where(ok[0], z[0], 0.0)
    T, Z = T_meas.copy(), Z_meas.copy()
    r0 = np.where(ok, r, 0.0)
    for _ in range(int(n_iterations)):
        m2 = replace(mesh, theta=T, z=Z)
        # the maps given the coordinates
        maps = []  # per component: (values (S, N), d/dTheta (S, N), d/dZ (S, N))
        for c, deg in enumerate(degs):
            if c == 0:
                y = r0
            elif c == 1:
                y = np.where(ok, wrap_angle(th - T[None]), 0.0)
            else:
                y = np.where(ok, z - Z[None], 0.0)
            B, dBt, dBz = (smoothing_basis(m2, deg)[0], smoothing_basis_derivative(m2, deg, 0),
                           smoothing_basis_derivative(m2, deg, 1))
            coef = _fit(B, y, ok)
            vals, dt, dz = coef @ B.T, coef @ dBt.T, coef @ dBz.T
            if c == 0:  # the reference surface: its own (richer) basis
                deg0 = (max(deg[0], REFERENCE_RADIUS_DEGREE[0]), max(deg[1], REFERENCE_RADIUS_DEGREE[1]))
                B0 = smoothing_basis(m2, deg0)[0]
                c0 = _fit(B0, y[:1], ok[:1])[0]
                last = (deg0, c0)
                vals[0] = B0 @ c0
                dt[0] = smoothing_basis_derivative(m2, deg0, 0) @ c0
                dz[0] = smoothing_basis_derivative(m2, deg0, 1) @ c0
            else:  # the gauge: the reference map is the identity in (theta, z)
                vals[0], dt[0], dz[0] = 0.0, 0.0, 0.0
            maps.append((vals, dt, dz))
        (R, Rt, Rz), (u, ut, uz), (w, wt, wz) = maps
        # each marker's coordinates given the maps: residuals (S, N, 3) in m and their Jacobian (S, N, 3, 2)
        rad = np.where(ok, r, 1.0)
        e = np.stack([r0 - R, rad * np.where(ok, wrap_angle(th - T[None] - u), 0.0), np.where(ok, z - Z[None] - w, 0.0)],
                     -1)
        J = -np.stack([np.stack([Rt, Rz], -1), rad[..., None] * np.stack([1.0 + ut, uz], -1),
                       np.stack([wt, 1.0 + wz], -1)], -2)
        J = J * ok[..., None, None]
        e = e * ok[..., None]
        JtJ = np.einsum("snci,sncj->nij", J, J)
        Jte = np.einsum("snci,snc->ni", J, e)
        good = mesh.used & (np.linalg.det(JtJ) > 0)
        step = np.zeros((len(T), 2))
        step[good] = -np.linalg.solve(JtJ[good], Jte[good][..., None])[..., 0]
        T, Z = T + step[:, 0], Z + step[:, 1]
        # the gauge, imposed: the coordinates' smooth part (on the displacement's basis) is the measured reference's
        # (the alternation alone creeps there at a rate of ~1/n_steps per iteration)
        for c, (coord, measured) in enumerate(((T, T_meas), (Z, Z_meas))):
            B, ok_ref = smoothing_basis(mesh, degs[c + 1])
            use = ok[0] & ok_ref
            dev = np.where(use, coord - measured, 0.0)
            coef = np.linalg.lstsq(B[use], dev[use], rcond=None)[0]
            coord -= np.where(use, B @ coef, 0.0)
    R0 = smoothing_basis(replace(mesh, theta=T, z=Z), last[0])[0] @ last[1]
    local = np.stack([R0 * np.cos(T), R0 * np.sin(T), Z], -1)
    ref = local @ axes[0].basis + axes[0].origin
    out = x.copy()
    out[0] = np.where(mesh.used[:, None], ref, x[0])
    return out
