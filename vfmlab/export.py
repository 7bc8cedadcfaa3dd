"""Export the deformed marker mesh and its fields, one file per step, in formats ParaView, PyVista and meshio read.

- ``vtu`` (default): VTK XML unstructured grids (:mod:`vfmlab.vtkxml`), one ``<prefix>_NNN.vtu`` per step. Points
  are the marker positions of the step (m; unmeasured markers at their reference position); cells are the mesh
  triangles whose three markers were measured in that step. Cell data, named by quantity, component and unit:
  ``E_theta``, ``E_z``, ``E_theta_z`` (Green-Lagrange, reference circumferential/axial frame, dimensionless),
  ``<model>_sigma_theta_Pa``, ``<model>_sigma_z_Pa`` (Cauchy stress of each identified model; ``<model>`` is
  the model name, with the wall model appended when it is not the membrane, e.g. ``fung_thick``),
  ``area_m2`` (deformed triangle area, trimesh), ``triangle`` (index in the full mesh). Point data: ``marker_id``,
  ``visible`` (0/1), ``displacement_m`` (3 components), ``normal`` (unit vertex normal, trimesh; NaN off the cells). Field data (one
  value per file): ``pressure_Pa``, ``force_N``, ``stretch``, ``clock_s`` (seconds since the first exported step),
  ``step``, ``session_row``, ``block``. Collections (``.pvd``, ParaView and PyVista play them as time series):
  ``<prefix>_block<B>.pvd`` per loading block (one axial stretch) with time = pressure in Pa, and
  ``<prefix>_clock.pvd`` with every step at time = clock seconds.
- ``vtk``: legacy ASCII VTK polydata, written here by hand, for old readers (meshio cannot read it). Cell data
  ``E11``, ``E22``, ``E12``, ``<result>_s11``, ``<result>_s22`` (Pa), ``triangle``; point data ``marker_id``,
  ``visible``, vector ``displacement`` (m). A ``<prefix>.vtk.series`` file (ParaView's JSON file-series format,
  time = step index) groups the steps.
- profiles (``export_profile``, a stored "regional" result): ``<prefix>_profile.csv`` (one row per band or
  profile point: axial position Z in m, world x/y/z in m, each regional parameter, its standard error and 95 %
  interval in Pa, whether the band differs; units in the header names and a leading ``#`` comment) and
  ``<prefix>_profile.vtk``, a legacy VTK polyline along the specimen axis through the band centres (world frame, m)
  with the same values as point data, to show beside the surface in ParaView.
- ``ply``: binary PLY through trimesh: the same geometry with face colours from the hoop strain (ParaView shows
  the colours) and the ``vtu`` cell fields as extra float face properties (ParaView's PLY reader ignores them;
  trimesh, plyfile, Open3D and MeshLab read them). Use ``vtu`` to see the fields in ParaView.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vfmlab.fields import SurfaceFields
from vfmlab.vtkxml import write_pvd, write_vtu

log = logging.getLogger(__name__)

__all__ = ["FORMATS", "StepTimes", "export_fields", "export_profile", "field_names", "write_vtk_polydata"]

FORMATS = ("vtu", "vtk", "ply")


def _cell_fields(fields: SurfaceFields, step: int) -> dict[str, np.ndarray]:
    out = {name: fields.kin[name][step] for name in ("E11", "E22", "E12")}
    for result, st in fields.stress.items():
        out[f"{result}_s11"] = st["s11"][step]
        out[f"{result}_s22"] = st["s22"][step]
    return out


def _fmt_rows(a: np.ndarray, fmt: str) -> str:
    a = np.atleast_2d(a) if a.ndim > 1 else a[:, None]
    return "\n".join(" ".join(fmt % v for v in row) for row in a)


def write_vtk_polydata(path: Path, points: np.ndarray, triangles: np.ndarray, *, title: str,
                       point_data: dict[str, np.ndarray], cell_data: dict[str, np.ndarray],
                       vectors: dict[str, np.ndarray] | None = None, line: bool = False) -> None:
    """Write a legacy ASCII VTK (4.2) polydata file.

    points (n, 3) float; triangles (m, 3) int; point_data {name: (n,) int or float};
    cell_data {name: (m,) float}; vectors {name: (n, 3) float} as point data. NaN is written as "nan".
    ``line``: instead of triangles, one polyline through all the points (``triangles`` ignored; one cell).
    """
    lines = ["# vtk DataFile Version 4.2", title.replace("\n", " ")[:250], "ASCII", "DATASET POLYDATA",
             f"POINTS {len(points)} double", _fmt_rows(np.asarray(points, float), "%.9g")]
    tri = np.asarray(triangles, int)
    if line:
        tri = np.arange(len(points))[None]
        lines += [f"LINES 1 {len(points) + 1}", " ".join(str(v) for v in [len(points), *range(len(points))])]
    else:
        lines.append(f"POLYGONS {len(tri)} {4 * len(tri)}")
        if len(tri):
            lines.append(_fmt_rows(np.column_stack([np.full(len(tri), 3), tri]), "%d"))
    lines.append(f"POINT_DATA {len(points)}")
    for name, values in point_data.items():
        values = np.asarray(values)
        integer = values.dtype.kind in "iub"
        lines += [f"SCALARS {name} {'int' if integer else 'double'} 1", "LOOKUP_TABLE default",
                  _fmt_rows(values.astype(int) if integer else values.astype(float), "%d" if integer else "%.9g")]
    for name, values in (vectors or {}).items():
        lines += [f"VECTORS {name} double", _fmt_rows(np.asarray(values, float), "%.9g")]
    if cell_data:
        lines.append(f"CELL_DATA {len(tri)}")
        for name, values in cell_data.items():
            lines += [f"SCALARS {name} double 1", "LOOKUP_TABLE default", _fmt_rows(np.asarray(values, float), "%.9g")]
    Path(path).write_text("\n".join(lines) + "\n", encoding="ascii")


def _step_geometry(fields: SurfaceFields, step: int):
    x = fields.positions[step]
    ref = fields.positions[0]
    visible = np.isfinite(x).all(axis=1)
    points = np.where(visible[:, None], x, np.nan_to_num(ref))
    keep = visible[fields.mesh.triangles].all(axis=1)
    return points, visible, keep, np.where(visible[:, None], x - ref, 0.0)


@dataclass(frozen=True)
class StepTimes:
    """When each exported step was taken: ``block`` (n_steps,) int, the loading block (one axial stretch) of the
    step; ``clock_s`` (n_steps,) float, seconds since the first exported step (monotonic clock)."""

    block: np.ndarray
    clock_s: np.ndarray


def _model_labels(fields: SurfaceFields) -> dict[str, str]:
    """Result name -> the label its fields carry: the model name, or ``<model>_<result>`` when two results
    share a model (e.g. membrane and thick wall)."""
    models = [str(st["model"]) for st in fields.stress.values()]
    return {result: (m if models.count(m) == 1 else f"{m}_{result}") for result, m in zip(fields.stress, models)}


def _vtu_cells(fields: SurfaceFields, step: int, labels: dict[str, str]) -> dict[str, np.ndarray]:
    out = {"E_theta": fields.kin["E11"][step], "E_z": fields.kin["E22"][step], "E_theta_z": fields.kin["E12"][step]}
    for result, st in fields.stress.items():
        out[f"{labels[result]}_sigma_theta_Pa"] = st["s11"][step]
        out[f"{labels[result]}_sigma_z_Pa"] = st["s22"][step]
    return out


def field_names(fields: SurfaceFields, fmt: str = "vtu") -> list[str]:
    """The cell fields an export in ``fmt`` writes (the stress fields name their model)."""
    if fmt == "vtk":
        return list(_cell_fields(fields, 0)) + ["triangle"]
    return list(_vtu_cells(fields, 0, _model_labels(fields))) + ["area_m2", "triangle"]


def _surface(points: np.ndarray, tri: np.ndarray):
    import trimesh

    return trimesh.Trimesh(vertices=points, faces=tri, process=False, validate=False)


def _write_vtu_step(path: Path, fields: SurfaceFields, k: int, times: StepTimes, labels: dict[str, str]) -> None:
    points, visible, keep, disp = _step_geometry(fields, k)
    tri = fields.mesh.triangles[keep]
    surface = _surface(points, tri)
    cells = {name: v[keep] for name, v in _vtu_cells(fields, k, labels).items()}
    cells["area_m2"] = surface.area_faces
    cells["triangle"] = np.flatnonzero(keep).astype(np.int32)
    normals = np.full_like(points, np.nan)  # a marker in no measured triangle has no normal
    used = np.unique(tri)
    if len(tri):
        normals[used] = surface.vertex_normals[used]
    write_vtu(path, points, tri,
              point_data={"marker_id": np.asarray(fields.marker_id, np.int32), "visible": visible.astype(np.uint8),
                          "displacement_m": disp, "normal": normals},
              cell_data=cells,
              field_data={"pressure_Pa": fields.pressure[k], "force_N": fields.force[k], "stretch": fields.stretch[k],
                          "clock_s": times.clock_s[k], "step": np.int32(k), "session_row": np.int32(fields.steps[k]),
                          "block": np.int32(times.block[k])})


def _write_vtu_series(fields: SurfaceFields, out: Path, prefix: str, times: StepTimes, specimen: str) -> list[Path]:
    labels = _model_labels(fields)
    written = []
    for k in range(len(fields.positions)):
        path = out / f"{prefix}_{k:03d}.vtu"
        _write_vtu_step(path, fields, k, times, labels)
        written.append(path)
    what = f"vfmlab {specimen}: marker mesh per step; SI units (m, Pa)"
    for b in np.unique(times.block):
        rows = np.flatnonzero(times.block == b)
        if len(np.unique(fields.pressure[rows])) < len(rows):
            log.warning("block %d has steps at the same pressure: ParaView shows one of them in %s_block%d.pvd "
                        "(every step is in %s_clock.pvd)", b, prefix, b, prefix)
        written.append(write_pvd(out / f"{prefix}_block{int(b)}.pvd", [written[i] for i in rows],
                                 fields.pressure[rows],
                                 comment=f"{what}; block {int(b)} (stretch {fields.stretch[rows[0]]:.6g}); "
                                         "time = pressure in Pa"))
    written.append(write_pvd(out / f"{prefix}_clock.pvd", written[:len(fields.positions)], times.clock_s,
                             comment=f"{what}; every step; time = clock seconds since the first step"))
    return written


def export_fields(fields: SurfaceFields, out_dir: str | Path, *, fmt: str = "vtu", prefix: str = "surface",
                  specimen: str = "", times: StepTimes | None = None) -> list[Path]:
    """Write one file per step (``<prefix>_NNN.<fmt>``) into ``out_dir``; returns the paths written.

    ``vtu``: the ``.pvd`` collections follow the step files (module docstring); ``times`` default: one block,
    clock = step index. ``vtk``: a ``<prefix>.vtk.series`` index is written too (last in the returned list).
    """
    if fmt not in FORMATS:
        raise ValueError(f"fmt must be one of {FORMATS}; got {fmt!r}")
    out = Path(out_dir)
    out.mkdir(exist_ok=True)  # the CLI checked that its parent exists
    n_steps = len(fields.positions)
    if times is None:
        times = StepTimes(np.zeros(n_steps, int), np.arange(n_steps, dtype=float))
    if np.shape(times.block) != (n_steps,) or np.shape(times.clock_s) != (n_steps,):
        raise ValueError(f"times.block and times.clock_s must have shape ({n_steps},); "
                         f"got {np.shape(times.block)} and {np.shape(times.clock_s)}")
    if fmt == "vtu":
        written = _write_vtu_series(fields, out, prefix, times, specimen)
        log.info("exported %d steps as vtu to %s", n_steps, out)
        return written
    labels = _model_labels(fields)
    written = []
    for k in range(n_steps):
        points, visible, keep, disp = _step_geometry(fields, k)
        tri = fields.mesh.triangles[keep]
        path = out / f"{prefix}_{k:03d}.{fmt}"
        if fmt == "vtk":
            cells = {name: v[keep] for name, v in _cell_fields(fields, k).items()}
            cells["triangle"] = np.flatnonzero(keep).astype(float)
            title = (f"vfmlab {specimen} step {k} (session row {int(fields.steps[k])}): pressure "
                     f"{fields.pressure[k]:.6g} Pa, force {fields.force[k]:.6g} N, stretch {fields.stretch[k]:.6g}; "
                     "SI units (m, Pa)")
            write_vtk_polydata(path, points, tri, title=title,
                               point_data={"marker_id": np.asarray(fields.marker_id, int),
                                           "visible": visible.astype(int)},
                               cell_data=cells, vectors={"displacement": disp})
        else:
            cells = {name: v[keep] for name, v in _vtu_cells(fields, k, labels).items()}
            cells["triangle"] = np.flatnonzero(keep).astype(float)
            _write_ply(path, points, tri, cells, np.asarray(fields.marker_id, np.int32), visible)
        written.append(path)
    if fmt == "vtk":
        series = out / f"{prefix}.vtk.series"
        series.write_text(json.dumps({"file-series-version": "1.0",
                                      "files": [{"name": p.name, "time": k} for k, p in enumerate(written)]},
                                     indent=1), encoding="utf-8")
        written.append(series)
    log.info("exported %d steps as %s to %s", n_steps, fmt, out)
    return written


def _write_ply(path: Path, points, tri, cells, marker_id, visible) -> None:
    import trimesh
    from matplotlib import colormaps
    from matplotlib.colors import Normalize

    mesh = _surface(points, tri)
    e11 = cells["E_theta"]
    finite = e11[np.isfinite(e11)]
    norm = Normalize(*(np.percentile(finite, [1, 99]) if finite.size else (0.0, 1.0)))
    mesh.visual.face_colors = (colormaps["viridis"](norm(np.nan_to_num(e11))) * 255).astype(np.uint8)
    for name, values in cells.items():
        mesh.face_attributes[name] = np.asarray(values, np.float32)
    mesh.vertex_attributes["marker_id"] = marker_id
    mesh.vertex_attributes["visible"] = visible.astype(np.int32)
    path.write_bytes(trimesh.exchange.ply.export_ply(mesh, encoding="binary", include_attributes=True))


def _profile_columns(result) -> dict[str, np.ndarray]:
    """Columns of a stored "regional" result's profile, named with their units (SI)."""
    a, units = result["arrays"], result.get("units", {})
    cols = {"Z_m": np.asarray(a["band_centres"], float), "Z_from_m": np.asarray(a["band_edges"], float)[:-1],
            "Z_to_m": np.asarray(a["band_edges"], float)[1:]}
    world = np.asarray(a["band_centres_world"], float) if "band_centres_world" in a else None
    if world is not None:
        cols.update({"x_m": world[:, 0], "y_m": world[:, 1], "z_m": world[:, 2]})
    for n in [str(v) for v in np.atleast_1d(a["regional_names"])]:
        u = units.get(n, "1")
        for key, label in ((n, n), (f"{n}_stderr", f"{n}_stderr"), (f"{n}_interval_low", f"{n}_low95"),
                           (f"{n}_interval_high", f"{n}_high95")):
            if key in a:
                cols[f"{label}_{u}"] = np.asarray(a[key], float)
    cols["differs"] = np.asarray(a["differs"], int)
    return cols


def export_profile(result, out_dir: str | Path, *, prefix: str = "surface", specimen: str = "") -> list[Path]:
    """Write a stored "regional" result (``Session.result`` dict) as ``<prefix>_profile.csv`` and
    ``<prefix>_profile.vtk`` (module docstring) into ``out_dir``; returns the two paths."""
    out = Path(out_dir)
    out.mkdir(exist_ok=True)
    cols = _profile_columns(result)
    attrs = result.get("attrs", {})
    what = (f"vfmlab {specimen} {result.get('name', 'regional')}: {attrs.get('model', '')} profile along the axis "
            f"({attrs.get('profile_kind', 'bands')}, errors {attrs.get('uncertainty', 'gauss-newton')}, 95 % "
            "intervals); Z = reference axial coordinate from the mean marker position; SI units (m, Pa)")
    csv = out / f"{prefix}_profile.csv"
    body = np.column_stack([np.asarray(v, float) for v in cols.values()])
    lines = [f"# {what}", ",".join(cols)] + [",".join(f"{v:.9g}" for v in row) for row in body]
    csv.write_text("\n".join(lines) + "\n", encoding="utf-8")
    vtk = out / f"{prefix}_profile.vtk"
    points = np.column_stack([cols["x_m"], cols["y_m"], cols["z_m"]]) if "x_m" in cols else \
        np.column_stack([np.zeros_like(cols["Z_m"]), np.zeros_like(cols["Z_m"]), cols["Z_m"]])
    data = {k: v for k, v in cols.items() if k not in ("x_m", "y_m", "z_m")}
    write_vtk_polydata(vtk, points, np.zeros((0, 3), int), title=what, point_data=data, cell_data={}, line=True)
    return [csv, vtk]
