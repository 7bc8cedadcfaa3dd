"""Mean stress-strain curves against the Laplace law (Avril et al. 2010, appendices A and B).

Circumferential: E11 = ((R / R0)^2 - 1) / 2 with R the mean radius at mid-span (eq. 12), Laplace
hoop stress p R / e (eq. 13), e the mid-span thickness from incompressibility. Axial:
E22 = ((L / L0)^2 - 1) / 2 (eq. 14), stress F / (2 pi R e) (eq. 15).

Two model predictions per step: ``sigma11_path`` / ``sigma22_path``, the identified law's Cauchy stresses at
the measured strains of the step (E11 and E22 together: the loading path the specimen followed, which is what
the Laplace points measure), and ``sigma11_model`` / ``sigma22_model``, the paper's uniaxial-strain
definitions (E22 = 0, resp. E11 = 0), which on an inflation test at fixed stretch lie far below the axial
Laplace points.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from .kinematics import align_steps, step_cylindrical
from .mesh import SurfaceMesh
from .models import Model, get_model, pk2_stress

__all__ = ["StressStrainCurves", "laplace_curves"]


@dataclass(frozen=True)
class StressStrainCurves:
    """Per-step mean curves, shapes (n_steps,), stresses in Pa (Cauchy); ``*_path``: the model along the measured
    path, ``*_model``: the paper's uniaxial-strain model curves (see the module docstring)."""

    E11: np.ndarray
    sigma11_laplace: np.ndarray
    sigma11_model: np.ndarray
    E22: np.ndarray
    sigma22_laplace: np.ndarray
    sigma22_model: np.ndarray
    radius: np.ndarray
    thickness: np.ndarray
    sigma11_path: np.ndarray
    sigma22_path: np.ndarray


def laplace_curves(mesh: SurfaceMesh, positions: np.ndarray, pressure: np.ndarray, axial_force: np.ndarray, *,
                   thickness: float, model: str | Model, parameters: Mapping[str, float],
                   band: float = 0.2) -> StressStrainCurves:
    """Mean circumferential / axial curves (appendices A, B) and the model's prediction.

    Parameters
    ----------
    mesh : SurfaceMesh
    positions : ndarray, shape (n_steps, n_markers, 3)
    pressure, axial_force : ndarray, shape (n_steps,)
    thickness : float
        Reference wall thickness e0 (m).
    band : float
        Half-width of the mid-span band, as a fraction of the measured length.
    """
    model = get_model(model)
    ref = np.column_stack([mesh.r * np.cos(mesh.theta), mesh.r * np.sin(mesh.theta), mesh.z]) @ mesh.axis.basis
    aligned, _, _ = align_steps(np.asarray(positions, float), ref + mesh.axis.origin)
    r, _, z, _ = step_cylindrical(mesh, aligned)
    zmid = 0.5 * (mesh.z_bottom + mesh.z_top)
    half = band * (mesh.z_top - mesh.z_bottom)
    sel = mesh.used & (np.abs(mesh.z - zmid) <= half)
    R = np.nanmean(r[:, sel], axis=1)
    lam_t = R / R[0]
    # axial stretch between the end rows (innermost boundary levels)
    lo = mesh.used & (mesh.z <= mesh.z_bottom)
    hi = mesh.used & (mesh.z >= mesh.z_top)
    L = np.nanmean(z[:, hi], axis=1) - np.nanmean(z[:, lo], axis=1)
    lam_z = L / L[0]
    e = thickness / (lam_t * lam_z)
    E11 = 0.5 * (lam_t**2 - 1.0)
    E22 = 0.5 * (lam_z**2 - 1.0)
    sig11 = np.asarray(pressure, float) * R / e
    sig22 = np.asarray(axial_force, float) / (2.0 * np.pi * R * e)
    C1 = np.zeros((len(E11), 2, 2))
    C1[:, 0, 0] = 1.0 + 2.0 * E11
    C1[:, 1, 1] = 1.0
    C2 = np.zeros((len(E22), 2, 2))
    C2[:, 0, 0] = 1.0
    C2[:, 1, 1] = 1.0 + 2.0 * E22
    C = np.zeros((len(E11), 2, 2))  # the measured path: both strains of each step
    C[:, 0, 0] = 1.0 + 2.0 * E11
    C[:, 1, 1] = 1.0 + 2.0 * E22
    S1 = pk2_stress(model, C1, parameters)
    S2 = pk2_stress(model, C2, parameters)
    S = pk2_stress(model, C, parameters)
    return StressStrainCurves(E11=E11, sigma11_laplace=sig11, sigma11_model=C1[:, 0, 0] * S1[:, 0, 0], E22=E22,
                              sigma22_laplace=sig22, sigma22_model=C2[:, 1, 1] * S2[:, 1, 1], radius=R, thickness=e,
                              sigma11_path=C[:, 0, 0] * S[:, 0, 0], sigma22_path=C[:, 1, 1] * S[:, 1, 1])
