"""Export the deformed marker mesh and its fields, one file per step, in formats ParaView reads.

- ``vtk``: legacy ASCII VTK polydata, written here by hand (no dependency). Points are the marker
  positions of the step (m); cells are the mesh triangles whose three markers were measured in that
  step. Cell data: ``E11``, ``E22``, ``E12`` (Green-Lagrange, reference circumferential/axial frame),
  ``<result>_s11``, ``<result>_s22`` (Cauchy stress of each identified model, Pa), ``triangle``
  (index in the full mesh). Point data: ``marker_id``, ``visible`` (0/1; unmeasured markers are
  written at their reference position), vector ``displacement`` (m). A ``<prefix>.vtk.series``
  file (ParaView's JSON file-series format, time = step index) groups the steps; ParaView also
  groups ``<prefix>_NNN.vtk`` files as a series by their names.
- profiles (``export_profile``, a stored "regional" result): ``<prefix>_profile.csv`` (one row per band or
  profile point: axial position Z in m, world x/y/z in m, each regional parameter, its standard error and 95 %
  interval in Pa, whether the band differs; units in the header names and a leading ``#`` comment) and
  ``<prefix>_profile.vtk``, a legacy VTK polyline along the specimen axis through the band centres (world frame, m)
  with the same values as point data, to show beside the surface in ParaView.
- ``ply``: binary PLY through trimesh: the same geometry with face colours from E11 and the scalar
  fields as extra float face properties (ParaView shows the colours; the scalars are read by
  trimesh, plyfile, Open3D, MeshLab).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from vfmlab.fields import SurfaceFields

log = logging.getLogger(__name__)

__all__ = ["FORMATS", "export_fields", "export_profile", "write_vtk_polydata"]

FORMATS = ("vtk", "ply")


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


def export_fields(fields: SurfaceFields, out_dir: str | Path, *, fmt: str = "vtk", prefix: str = "surface",
                  specimen: str = "") -> list[Path]:
    """Write one file per step (``<prefix>_NNN.<fmt>``) into ``out_dir``; returns the paths written.

    For ``vtk`` a ``<prefix>.vtk.series`` index is written too (last in the returned list).
    """
    if fmt not in FORMATS:
        raise ValueError(f"fmt must be one of {FORMATS}; got {fmt!r}")
    out = Path(out_dir)
    out.mkdir(exist_ok=True)  # the CLI checked that its parent exists
    written = []
    n_steps = len(fields.positions)
    for k in range(n_steps):
        points, visible, keep, disp = _step_geometry(fields, k)
        tri = fields.mesh.triangles[keep]
        cells = {name: v[keep] for name, v in _cell_fields(fields, k).items()}
        cells["triangle"] = np.flatnonzero(keep).astype(float)
        path = out / f"{prefix}_{k:03d}.{fmt}"
        title = (f"vfmlab {specimen} step {k} (session row {int(fields.steps[k])}): pressure {fields.pressure[k]:.6g} Pa, "
                 f"force {fields.force[k]:.6g} N, stretch {fields.stretch[k]:.6g}; SI units (m, Pa)")
        if fmt == "vtk":
            write_vtk_polydata(path, points, tri, title=title,
                               point_data={"marker_id": np.asarray(fields.marker_id, int),
                                           "visible": visible.astype(int)},
                               cell_data=cells, vectors={"displacement": disp})
        else:
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

    mesh = trimesh.Trimesh(vertices=points, faces=tri, process=False, validate=False)
    e11 = cells["E11"]
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
