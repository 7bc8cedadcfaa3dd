"""Surface fields for reports and export: mesh, per-triangle strains and stresses, Laplace-law estimates.

This is the adapter between the stored results and the figures/exports. It uses the identification
package's public functions (``identification.build_mesh``, ``identification.membrane_kinematics``,
``identification.cauchy_stress``, ``identification.laplace_curves``), so the maps show exactly what the
identification used (recorded in ``SurfaceFields.sources``). ``identification`` ships in the same
distribution as vfmlab (pyproject.toml), so there is no fallback for its absence.

Frames: world frame of the rig (m), z along the specimen axis. Per triangle, the local frame is
(1 = circumferential, 2 = axial) in the reference configuration; strains are Green-Lagrange
components E11, E22, E12 in that frame, stresses are Cauchy components in the matching current
(circumferential, axial) directions. Shapes: ``(n_steps, n_triangles)`` per component.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

log = logging.getLogger(__name__)

__all__ = ["SurfaceMesh2", "SurfaceFields", "surface_mesh", "surface_kinematics", "model_stress", "compute_fields",
           "stress_strain_curves"]


class FieldsError(ValueError):
    """The marker data cannot be meshed or the fields cannot be computed."""


@dataclass(frozen=True)
class SurfaceMesh2:
    """A triangulation of the reference markers with unrolled reference coordinates.

    Attributes
    ----------
    triangles : ndarray, shape (n_triangles, 3) int
        Marker indices (columns of ``positions``).
    s, z : ndarray, shape (n_markers,) m
        Unrolled reference coordinates: arc length R*theta and axial position (NaN if unused).
    radius : float, m
        Mean reference radius of the markers.
    source : str
        Which implementation built it.
    raw : identification.SurfaceMesh
        The mesh ``identification.build_mesh`` built.
    """

    triangles: np.ndarray
    s: np.ndarray
    z: np.ndarray
    radius: float
    source: str
    raw: Any


def surface_mesh(reference: np.ndarray) -> SurfaceMesh2:
    """Triangulate the reference markers ``(n_markers, 3)`` m (NaN rows ignored)."""
    reference = np.asarray(reference, dtype=float)
    if reference.ndim != 2 or reference.shape[1] != 3:
        raise FieldsError(f"reference positions must have shape (n_markers, 3); got {reference.shape}")
    from identification import build_mesh

    mesh = build_mesh(reference)
    s = mesh.axis.radius * mesh.theta
    return SurfaceMesh2(np.asarray(mesh.triangles), np.where(mesh.used, s, np.nan),
                        np.where(mesh.used, mesh.z, np.nan), float(mesh.axis.radius), "identification.build_mesh", mesh)


def surface_kinematics(mesh: SurfaceMesh2, positions: np.ndarray) -> tuple[dict[str, np.ndarray], str]:
    """Per-triangle strains on ``mesh``: ``identification.membrane_kinematics`` (cylindrical interpolation,
    rigid motion removed).

    Returns a dict with ``F`` (n_steps, n_tri, 3, 2) in current cylindrical components (r, theta, z),
    Green-Lagrange strains ``E11, E22, E12`` and stretches ``lam1, lam2`` (n_steps, n_tri) in the local
    (circumferential, axial) frame, ``centroid`` (n_steps, n_tri, 3) m and ``frame`` = "cylindrical"; and a
    description of the source.
    """
    from identification import membrane_kinematics

    with np.errstate(invalid="ignore", divide="ignore"):  # unobserved triangles are NaN by design
        k = membrane_kinematics(mesh.raw, positions)
    C = k.C
    return ({"F": k.F, "E11": k.E[..., 0, 0], "E22": k.E[..., 1, 1], "E12": k.E[..., 0, 1],
             "lam1": np.sqrt(C[..., 0, 0]), "lam2": np.sqrt(C[..., 1, 1]), "centroid": k.centroid,
             "frame": "cylindrical"},
            "identification.membrane_kinematics (cylindrical interpolation, as used by the identification)")


def model_stress(model: str, parameters: Mapping[str, float], kin: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Cauchy stresses (Pa) s11 (circumferential), s22 (axial), each (n_steps, n_tri), from the model.

    Uses ``identification.cauchy_stress`` on ``F`` of :func:`surface_kinematics` (cylindrical components).
    """
    from identification import cauchy_stress

    F = kin["F"]
    ok = np.all(np.isfinite(F), axis=(-1, -2))
    sig = np.full(F.shape[:-2] + (3, 3), np.nan)
    if ok.any():
        sig[ok] = cauchy_stress(model, F[ok], dict(parameters))
    return {"s11": sig[..., 1, 1], "s22": sig[..., 2, 2]}  # F maps to (r, theta, z) components


@dataclass
class SurfaceFields:
    """Everything the report and the exporter draw on the surface.

    ``steps`` (n_steps,) rows of the step table; ``pressure``, ``force``, ``stretch`` (n_steps,)
    SI; ``positions`` (n_steps, n_markers, 3) m; ``mesh``; ``kin`` (see :func:`surface_kinematics`);
    ``stress`` {result name: {"model", "s11", "s22"}}; ``sources`` says which code computed what.
    """

    steps: np.ndarray
    pressure: np.ndarray
    force: np.ndarray
    stretch: np.ndarray
    positions: np.ndarray
    marker_id: np.ndarray
    mesh: SurfaceMesh2
    kin: dict[str, np.ndarray]
    stress: dict[str, dict[str, Any]] = field(default_factory=dict)
    sources: dict[str, str] = field(default_factory=dict)


def compute_fields(markers: Mapping[str, Any], step_table: Mapping[str, np.ndarray],
                   identifications: list[Mapping[str, Any]] = ()) -> SurfaceFields:
    """Fields from a "markers" result, the session's step table and "identification" results.

    The first step of the markers result is the reference configuration.
    """
    arrays = markers["arrays"]
    pos = np.asarray(arrays["positions"], dtype=float)
    if pos.ndim != 3 or pos.shape[2] != 3 or pos.shape[0] < 1:
        raise FieldsError(f"markers positions must have shape (n_steps, n_markers, 3); got {pos.shape}")
    if "visible" in arrays:
        pos = np.where(np.asarray(arrays["visible"], bool)[..., None], pos, np.nan)
    rows = np.asarray(arrays.get("step_index", np.arange(len(pos))), dtype=int)
    n_table = len(step_table["pressure"])
    if rows.shape != (len(pos),) or np.any(rows < 0) or np.any(rows >= n_table):
        raise FieldsError(f"markers step_index must hold {len(pos)} rows of the step table (0..{n_table - 1}); "
                          f"got {rows.tolist()}")
    mesh = surface_mesh(pos[0])
    kin, kin_source = surface_kinematics(mesh, pos)
    fields = SurfaceFields(
        steps=rows, pressure=np.asarray(step_table["pressure"], float)[rows],
        force=np.asarray(step_table["force"], float)[rows], stretch=np.asarray(step_table["stretch"], float)[rows],
        positions=pos, marker_id=np.asarray(arrays.get("marker_id", np.arange(pos.shape[1]))), mesh=mesh, kin=kin,
        sources={"mesh": mesh.source, "strain": kin_source})
    for ident in identifications:
        model = str(ident["attrs"].get("model", ""))
        names = [str(n) for n in ident["arrays"].get("parameter_names", [])]
        values = np.asarray(ident["arrays"].get("parameters", []), dtype=float)
        if not model or len(names) != len(values):
            continue
        try:
            stress = model_stress(model, dict(zip(names, values)), kin)
        except ValueError as exc:  # unknown model or parameter names
            log.warning("no stresses for %s: %s", ident["name"], exc)
            continue
        fields.stress[ident["name"]] = {"model": model, **stress}
        fields.sources["stress"] = "identification.models.cauchy_stress"
    return fields


def stress_strain_curves(fields: SurfaceFields, force: np.ndarray, thickness: float, load_cell_measures: str,
                         identifications: list[Mapping[str, Any]] = (), band: float = 0.2) -> dict[str, Any]:
    """Mean mid-span stress-strain curves and their Laplace-law estimates (paper appendices A, B).

    Uses ``identification.laplace_curves`` (the paper's definitions: mean mid-span radius, length
    between the end rows; each model evaluated along the measured path, at both measured strains of
    every step).

    ``force`` (n_steps,) N is the load-cell reading; a "total" reading is corrected to the wall force.
    Returns ``E11, E22, s11, s22, radius``, ``thickness`` (current, m), ``wall_force`` (N) (n_steps,) and
    ``models`` {label: {"s11", "s22"}}, and ``source``.
    """
    p = fields.pressure
    mesh = fields.mesh
    r_i = mesh.radius - thickness
    wall_force = force + p * np.pi * r_i**2 if load_cell_measures == "total" else np.asarray(force, float)
    from identification import laplace_curves

    models: dict[str, dict[str, np.ndarray]] = {}
    base = None
    for ident in identifications:
        a = ident["arrays"]
        names = [str(n) for n in a.get("parameter_names", [])]
        model = str(ident["attrs"].get("model", ""))
        try:
            c = laplace_curves(mesh.raw, fields.positions, p, wall_force, thickness=thickness, model=model,
                               parameters=dict(zip(names, np.asarray(a["parameters"], float))), band=band)
        except (ValueError, KeyError) as exc:
            log.warning("no model curve for %s: %s", ident.get("name"), exc)
            continue
        base = base or c
        models[f"{ident['name']} ({model})"] = {"s11": c.sigma11_path, "s22": c.sigma22_path, "result": ident["name"],
                                                 "model": model}
    if base is None:  # the Laplace estimates do not depend on the model
        base = laplace_curves(mesh.raw, fields.positions, p, wall_force, thickness=thickness, model="neohookean",
                              parameters={"mu": 1.0}, band=band)
    return {"E11": base.E11, "E22": base.E22, "s11": base.sigma11_laplace, "s22": base.sigma22_laplace,
            "radius": base.radius, "thickness": base.thickness, "wall_force": wall_force, "models": models,
            "source": "identification.laplace_curves (models evaluated at the measured E11 and E22 of each "
                      "step)"}
