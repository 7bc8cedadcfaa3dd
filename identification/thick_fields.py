"""Virtual fields that vanish with their axial gradient on the measured boundary (for ``wall="thick"``).

The paper's fields (``virtual_fields.paper_fields``: ``sin(pi zeta) e_r`` and ``zeta e_z``) have a
non-zero axial gradient on the measured boundary. In the thick form the fields are extended through
the wall so as to be divergence-free (``_wall._layer``): where ``d u_z / d z`` or ``d u_r / d z`` is not 0,
the inner layers of the boundary cross-section move radially, so the transverse shear stress there
(unknown, and not small next to a clamp, where the wall bends) would do virtual work that the balance
leaves out; the layered kinematics (material lines through the wall stay radial) is also least right
in the taper next to a clamp, where these fields weigh most.

``flat_end_fields`` uses ``sin^2(pi zeta) e_r`` and ``(zeta - sin(2 pi zeta) / (2 pi)) e_z``: the same
boundary values (0 at the bottom, the uniform axial translation 1 at the load-cell end), with zero
axial gradient at both ends. On exact homogeneous data any admissible fields give the exact answer;
on the clamped finite-element tube (``rig_sim.fe_tube``, docs/validation/identification.md "FE ground truth")
they bring the Delfino RMS virtual-work gap from 1.27 % to 0.37 % and beta from -3.3 % to -0.9 %.
"""

from __future__ import annotations

import numpy as np

from .mesh import SurfaceMesh
from .virtual_fields import VirtualFields

__all__ = ["flat_end_fields"]


def flat_end_fields(mesh: SurfaceMesh) -> VirtualFields:
    """Radial and axial virtual fields with zero axial gradient on the measured boundary.

    ``u*1 = sin^2(pi zeta) e_r`` and ``u*2 = (zeta - sin(2 pi zeta) / (2 pi)) e_z`` with
    ``zeta = clip((Z - z_bottom) / (z_top - z_bottom), 0, 1)`` as in ``paper_fields`` (0 on the
    bottom boundary markers, 1 on the top, load-cell, ones). Values have shape (2, n_markers, 3).
    """
    zeta = np.nan_to_num(np.clip((mesh.z - mesh.z_bottom) / (mesh.z_top - mesh.z_bottom), 0.0, 1.0))
    values = np.zeros((2, mesh.n_markers, 3))
    values[0, :, 0] = np.sin(np.pi * zeta) ** 2
    values[1, :, 2] = zeta - np.sin(2.0 * np.pi * zeta) / (2.0 * np.pi)
    return VirtualFields(names=("radial", "axial"), values=values, load_end=np.array([0.0, 1.0]))
