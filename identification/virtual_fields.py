"""Virtual displacement fields as data.

A virtual field is given by its cylindrical components (radial, circumferential, axial) at every
marker of the reference configuration (it is attached to material points), interpolated like the
positions. To keep unknown forces out of the balance it must vanish on the bottom (far) end of the
measured surface and be a uniform axial translation ``load_end`` on the top (load-cell) end, where
the measured axial force does the work ``load_end * F``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import IdentificationError
from .mesh import SurfaceMesh

__all__ = ["VirtualFields", "paper_fields", "check_fields"]


@dataclass(frozen=True)
class VirtualFields:
    """A set of virtual displacement fields.

    Attributes
    ----------
    names : tuple of str
    values : ndarray, shape (n_fields, n_markers, 3)
        Cylindrical components (radial, circumferential, axial), dimensionless (a virtual
        displacement of 1 times the real forces gives work in J).
    load_end : ndarray, shape (n_fields,)
        Uniform axial virtual displacement of the top (load-cell end) boundary.
    """

    names: tuple[str, ...]
    values: np.ndarray
    load_end: np.ndarray

    def __post_init__(self) -> None:
        values = np.asarray(self.values, dtype=float)
        if values.ndim != 3 or values.shape[2] != 3 or values.shape[0] != len(self.names):
            raise ValueError(f"values must have shape (n_fields={len(self.names)}, n_markers, 3); got {values.shape}")
        load = np.asarray(self.load_end, dtype=float)
        if load.shape != (len(self.names),):
            raise ValueError(f"load_end must have shape ({len(self.names)},); got {load.shape}")
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "load_end", load)

    @property
    def n_fields(self) -> int:
        return len(self.names)


def paper_fields(mesh: SurfaceMesh) -> VirtualFields:
    """The two virtual fields of Avril et al. (2010), eq. 7, on the measured surface.

    ``u*1 = sin(pi zeta) e_r`` (radial expansion, zero at both ends) and ``u*2 = zeta e_z``
    (axial), with ``zeta = clip((Z - z_bottom) / (z_top - z_bottom), 0, 1)`` in the reference
    axial coordinate. ``z_bottom`` / ``z_top`` are the innermost boundary markers, so the fields
    are exactly 0 and 1 along the whole jagged measured boundary, 1 at the load-cell end.
    """
    zeta = np.clip((mesh.z - mesh.z_bottom) / (mesh.z_top - mesh.z_bottom), 0.0, 1.0)
    zeta = np.nan_to_num(zeta)
    values = np.zeros((2, mesh.n_markers, 3))
    values[0, :, 0] = np.sin(np.pi * zeta)
    values[1, :, 2] = zeta
    return VirtualFields(names=("radial", "axial"), values=values, load_end=np.array([0.0, 1.0]))


def check_fields(fields: VirtualFields, mesh: SurfaceMesh, tol: float = 1e-9) -> None:
    """Raise ``IdentificationError`` if a field does unknown work on the measured boundary."""
    if fields.values.shape[1] != mesh.n_markers:
        raise IdentificationError(
            f"virtual fields are given at {fields.values.shape[1]} markers; the mesh has {mesh.n_markers}")
    bottom = np.unique(mesh.bottom_edges)
    top = np.unique(mesh.top_edges)
    for k, name in enumerate(fields.names):
        v = fields.values[k]
        if np.abs(v[bottom]).max() > tol:
            raise IdentificationError(
                f"virtual field {name!r} must vanish on the bottom boundary markers; max |u*| there is "
                f"{np.abs(v[bottom]).max():.3g}")
        dev = np.abs(v[top] - np.array([0.0, 0.0, fields.load_end[k]])).max()
        if dev > tol:
            raise IdentificationError(
                f"virtual field {name!r} must be the uniform axial translation load_end={fields.load_end[k]} on "
                f"the top (load-cell) boundary markers; it deviates by {dev:.3g}")
