"""Surface fields for reports and export: mesh, per-triangle strains and stresses, Laplace-law estimates.

This is the adapter between the stored results and the figures/exports. It prefers the identification
package's public functions (``identification.build_mesh``, ``identification.models.cauchy_stress``)
when they are installed, so the maps show exactly what the identification used, and falls back to a
small self-contained version of each otherwise (recorded in ``SurfaceFields.sources``).

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
from scipy.spatial import Delaunay

log = logging.getLogger(__name__)

__all__ = ["SurfaceMesh2", "SurfaceFields", "surface_mesh", "triangle_kinematics", "model_stress",
           "laplace_stress", "midspan_radius", "compute_fields", "stress_strain_curves"]


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
    raw : object
        The ``identification.SurfaceMesh`` when that package built it, else None.
    """

    triangles: np.ndarray
    s: np.ndarray
    z: np.ndarray
    radius: float
    source: str
    raw: Any = None


def _identification_build_mesh():
    try:
        from identification import build_mesh  # type: ignore[attr-defined]
    except ImportError:
        try:
            from identification.mesh import build_mesh  # type: ignore[no-redef]
        except ImportError:
            return None
    return build_mesh


def _fallback_mesh(reference: np.ndarray, min_quality: float = 0.3) -> SurfaceMesh2:
    """Delaunay triangulation of the unrolled reference surface about the world z axis, closed at the seam."""
    finite = np.all(np.isfinite(reference), axis=1)
    idx = np.flatnonzero(finite)
    if len(idx) < 12:
        raise FieldsError(f"meshing needs at least 12 markers visible in the reference step; got {len(idx)}")
    pts = reference[idx]
    centre = np.nanmean(pts[:, :2], axis=0)
    theta = np.arctan2(pts[:, 1] - centre[1], pts[:, 0] - centre[0])
    radius = float(np.mean(np.hypot(pts[:, 0] - centre[0], pts[:, 1] - centre[1])))
    s = radius * theta
    period = 2 * np.pi * radius
    pts2 = np.concatenate([np.column_stack([s + k * period, pts[:, 2]]) for k in (-1, 0, 1)])
    simp = Delaunay(pts2).simplices
    cs = pts2[simp, 0].mean(axis=1)
    simp = simp[(cs >= -np.pi * radius) & (cs < np.pi * radius)]
    a, b, c = pts2[simp[:, 0]], pts2[simp[:, 1]], pts2[simp[:, 2]]
    ab, ac, bc = b - a, c - a, c - b
    area = 0.5 * (ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0])
    quality = 4 * np.sqrt(3) * np.abs(area) / ((ab**2).sum(1) + (ac**2).sum(1) + (bc**2).sum(1))
    simp = np.where((area < 0)[:, None], simp[:, [0, 2, 1]], simp)[quality >= min_quality]
    tri = idx[simp % len(idx)]
    s_all = np.full(len(reference), np.nan)
    z_all = np.full(len(reference), np.nan)
    s_all[idx], z_all[idx] = s, pts[:, 2]
    return SurfaceMesh2(tri, s_all, z_all, radius, "vfmlab.fields fallback (world z axis)")


def surface_mesh(reference: np.ndarray) -> SurfaceMesh2:
    """Triangulate the reference markers ``(n_markers, 3)`` m (NaN rows ignored)."""
    reference = np.asarray(reference, dtype=float)
    if reference.ndim != 2 or reference.shape[1] != 3:
        raise FieldsError(f"reference positions must have shape (n_markers, 3); got {reference.shape}")
    build = _identification_build_mesh()
    if build is None:
        return _fallback_mesh(reference)
    mesh = build(reference)
    s = mesh.axis.radius * mesh.theta
    return SurfaceMesh2(np.asarray(mesh.triangles), np.where(mesh.used, s, np.nan),
                        np.where(mesh.used, mesh.z, np.nan), float(mesh.axis.radius), "identification.build_mesh", mesh)


def triangle_kinematics(positions: np.ndarray, triangles: np.ndarray, reference_step: int = 0) -> dict[str, np.ndarray]:
    """In-plane deformation of each flat triangle relative to the reference step.

    Parameters
    ----------
    positions : ndarray, shape (n_steps, n_markers, 3), m
        Marker positions (NaN = not observed).
    triangles : ndarray, shape (n_triangles, 3) int
    reference_step : int

    Returns
    -------
    dict with
        ``F`` (n_steps, n_tri, 3, 2): deformation gradient from the local reference (circ., axial)
        frame to world components; ``E11, E22, E12`` (n_steps, n_tri): Green-Lagrange strains;
        ``lam1, lam2`` (n_steps, n_tri): stretches; ``e1, e2`` (n_steps, n_tri, 3): current unit
        circumferential / axial directions; ``centroid`` (n_steps, n_tri, 3) m.
    """
    x = np.asarray(positions, dtype=float)
    tri = np.asarray(triangles)
    X = x[reference_step]
    dX = np.stack([X[tri[:, 1]] - X[tri[:, 0]], X[tri[:, 2]] - X[tri[:, 0]]], axis=-1)  # (t, 3, 2)
    normal = np.cross(dX[..., 0], dX[..., 1])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    cen = X[tri].mean(axis=1)
    circ = np.stack([-cen[:, 1], cen[:, 0], np.zeros(len(cen))], axis=1)
    circ -= (circ * normal).sum(1, keepdims=True) * normal
    circ /= np.linalg.norm(circ, axis=1, keepdims=True)
    axial = np.cross(normal, circ)
    axial *= np.sign(axial[:, 2:3] + 1e-300)
    basis = np.stack([circ, axial], axis=1)  # (t, 2, 3)
    G = basis @ dX  # (t, 2, 2): local reference edge components
    Ginv = np.linalg.inv(G)
    dx = np.stack([x[:, tri[:, 1]] - x[:, tri[:, 0]], x[:, tri[:, 2]] - x[:, tri[:, 0]]], axis=-1)  # (s, t, 3, 2)
    F = dx @ Ginv[None]
    C = np.swapaxes(F, -1, -2) @ F
    lam1, lam2 = np.sqrt(C[..., 0, 0]), np.sqrt(C[..., 1, 1])
    e1 = F[..., 0] / lam1[..., None]
    e2 = F[..., 1] - (F[..., 1] * e1).sum(-1, keepdims=True) * e1
    e2 /= np.linalg.norm(e2, axis=-1, keepdims=True)
    return {"F": F, "E11": 0.5 * (C[..., 0, 0] - 1), "E22": 0.5 * (C[..., 1, 1] - 1), "E12": 0.5 * C[..., 0, 1],
            "lam1": lam1, "lam2": lam2, "e1": e1, "e2": e2, "centroid": x[:, tri].mean(axis=2)}


def surface_kinematics(mesh: SurfaceMesh2, positions: np.ndarray) -> tuple[dict[str, np.ndarray], str]:
    """Per-triangle strains on ``mesh``: ``identification.membrane_kinematics`` (cylindrical interpolation,
    rigid motion removed) when the identification package built the mesh, else :func:`triangle_kinematics`.

    Returns the dict of :func:`triangle_kinematics` (``F`` then in current cylindrical components
    (r, theta, z) and ``frame`` = "cylindrical") and a description of the source.
    """
    if mesh.raw is None:
        kin = triangle_kinematics(positions, mesh.triangles)
        kin["frame"] = "projected"
        return kin, "vfmlab.fields.triangle_kinematics (flat triangles)"
    from identification import membrane_kinematics

    with np.errstate(invalid="ignore", divide="ignore"):  # unobserved triangles are NaN by design
        k = membrane_kinematics(mesh.raw, positions)
    C = k.C
    return ({"F": k.F, "E11": k.E[..., 0, 0], "E22": k.E[..., 1, 1], "E12": k.E[..., 0, 1],
             "lam1": np.sqrt(C[..., 0, 0]), "lam2": np.sqrt(C[..., 1, 1]), "centroid": k.centroid,
             "frame": "cylindrical"},
            "identification.membrane_kinematics (cylindrical interpolation, as used by the identification)")


def model_stress(model: str, parameters: Mapping[str, float], kin: Mapping[str, np.ndarray]) -> dict[str, np.ndarray] | None:
    """Cauchy stresses (Pa) s11 (circumferential), s22 (axial), each (n_steps, n_tri), from the model.

    Uses ``identification.models.cauchy_stress``; returns None when it is unavailable.
    """
    try:
        from identification.models import cauchy_stress
    except ImportError:
        log.info("identification.models not available: no model stresses")
        return None
    F = kin["F"]
    ok = np.all(np.isfinite(F), axis=(-1, -2))
    sig = np.full(F.shape[:-2] + (3, 3), np.nan)
    if ok.any():
        sig[ok] = cauchy_stress(model, F[ok], dict(parameters))
    if kin.get("frame") == "cylindrical":  # F maps to (r, theta, z) components
        return {"s11": sig[..., 1, 1], "s22": sig[..., 2, 2]}
    e1, e2 = kin["e1"], kin["e2"]
    s11 = np.einsum("...i,...ij,...j->...", e1, sig, e1)
    s22 = np.einsum("...i,...ij,...j->...", e2, sig, e2)
    return {"s11": s11, "s22": s22}


def laplace_stress(pressure: np.ndarray, force: np.ndarray, radius: np.ndarray, lam1: np.ndarray, lam2: np.ndarray,
                   thickness: float, load_cell_measures: str = "wall") -> dict[str, np.ndarray]:
    """Mean-wall Cauchy stresses from global equilibrium of a thin incompressible tube.

    ``sigma_theta = p r / h`` and ``sigma_z = N / (2 pi r h)`` with the current thickness
    ``h = H / (lam1 lam2)`` and the wall force ``N = F`` ("wall") or ``F + p pi r^2`` ("total").
    All inputs (n_steps,) in SI; returns ``s11``, ``s22``, ``h`` (n_steps,).
    """
    p, f, r = (np.asarray(a, dtype=float) for a in (pressure, force, radius))
    h = thickness / (np.asarray(lam1) * np.asarray(lam2))
    wall_force = f + p * np.pi * r * r if load_cell_measures == "total" else f
    return {"s11": p * r / h, "s22": wall_force / (2 * np.pi * r * h), "h": h}


def midspan_radius(positions: np.ndarray, band: float = 0.2) -> np.ndarray:
    """Radius (m) per step of the markers whose reference axial position is in the middle ``band`` of the span.

    The axis of each step is taken through the centroid of the visible markers, along world z.
    """
    x = np.asarray(positions, dtype=float)
    z0 = x[0, :, 2]
    lo, hi = np.nanmin(z0), np.nanmax(z0)
    mid = 0.5 * (lo + hi)
    sel = np.abs(z0 - mid) <= 0.5 * band * (hi - lo)
    centre = np.nanmean(x[:, :, :2], axis=1, keepdims=True)
    r = np.hypot(*(x[:, sel, :2] - centre).transpose(2, 0, 1))
    with np.errstate(all="ignore"):
        return np.nanmean(r, axis=1) if sel.any() else np.full(len(x), np.nan)


@dataclass
class SurfaceFields:
    """Everything the report and the exporter draw on the surface.

    ``steps`` (n_steps,) rows of the step table; ``pressure``, ``force``, ``stretch`` (n_steps,)
    SI; ``positions`` (n_steps, n_markers, 3) m; ``mesh``; ``kin`` (see :func:`triangle_kinematics`);
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
        if stress is not None:
            fields.stress[ident["name"]] = {"model": model, **stress}
            fields.sources["stress"] = "identification.models.cauchy_stress"
    return fields


def stress_strain_curves(fields: SurfaceFields, force: np.ndarray, thickness: float, load_cell_measures: str,
                         identifications: list[Mapping[str, Any]] = (), band: float = 0.2) -> dict[str, Any]:
    """Mean mid-span stress-strain curves and their Laplace-law estimates (paper appendices A, B).

    Uses ``identification.laplace_curves`` (the paper's definitions: mean mid-span radius, length
    between the end rows; each model evaluated along the measured path, at both measured strains of
    every step) when the identification package built the mesh; otherwise the per-triangle means of :func:`triangle_kinematics` over the
    mid-span band and :func:`laplace_stress`, with each model's median stress on those triangles.

    ``force`` (n_steps,) N is the load-cell reading; a "total" reading is corrected to the wall force.
    Returns ``E11, E22, s11, s22, radius`` (n_steps,) and ``models`` {label: {"s11", "s22"}}, and
    ``source``.
    """
    p = fields.pressure
    mesh = fields.mesh
    r_i = mesh.radius - thickness
    wall_force = force + p * np.pi * r_i**2 if load_cell_measures == "total" else np.asarray(force, float)
    if mesh.raw is not None:
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
            models[f"{ident['name']} ({model})"] = {"s11": c.sigma11_path, "s22": c.sigma22_path}
        if base is None:  # the Laplace estimates do not depend on the model
            base = laplace_curves(mesh.raw, fields.positions, p, wall_force, thickness=thickness, model="neohookean",
                                  parameters={"mu": 1.0}, band=band)
        return {"E11": base.E11, "E22": base.E22, "s11": base.sigma11_laplace, "s22": base.sigma22_laplace,
                "radius": base.radius, "models": models,
                "source": "identification.laplace_curves (models evaluated at the measured E11 and E22 of each "
                          "step)"}
    zc = np.nanmean(mesh.z[mesh.triangles], axis=1)
    lo, hi = np.nanmin(mesh.z), np.nanmax(mesh.z)
    sel = np.abs(zc - 0.5 * (lo + hi)) <= 0.5 * band * (hi - lo)
    with np.errstate(all="ignore"):
        lam1, lam2 = np.nanmean(fields.kin["lam1"][:, sel], axis=1), np.nanmean(fields.kin["lam2"][:, sel], axis=1)
        radius = midspan_radius(fields.positions, band)
        lap = laplace_stress(p, force, radius, lam1, lam2, thickness, load_cell_measures)
        models = {f"{name} ({st['model']})": {"s11": np.nanmedian(st["s11"][:, sel], axis=1),
                                              "s22": np.nanmedian(st["s22"][:, sel], axis=1)}
                  for name, st in fields.stress.items()}
        return {"E11": np.nanmean(fields.kin["E11"][:, sel], axis=1), "E22": np.nanmean(fields.kin["E22"][:, sel], axis=1),
                "s11": lap["s11"], "s22": lap["s22"], "radius": radius, "models": models,
                "source": "vfmlab.fields (mid-span triangle means; models: median stress on those triangles)"}
