"""VTK XML files that ParaView, PyVista (VTK's own readers) and meshio all read: one ``.vtu`` per mesh and a
``.pvd`` collection that gives each file its time.

Written here with numpy and the standard library (no dependency): ``UnstructuredGrid`` of triangles, every array
inline as base64 binary (little-endian, ``UInt64`` size header encoded with the data, as VTK writes uncompressed
arrays), so NaN and full float64 precision survive. See the VTK file formats page (XML formats, "binary" data).
"""

from __future__ import annotations

import base64
import os
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from xml.sax.saxutils import escape, quoteattr

import numpy as np

__all__ = ["write_pvd", "write_vtu"]

_VTK_TYPES = {"f8": "Float64", "f4": "Float32", "i8": "Int64", "i4": "Int32", "u1": "UInt8", "i1": "Int8"}
_VTK_TRIANGLE = 5


def _array_xml(name: str, values: np.ndarray, indent: str) -> str:
    a = np.asarray(values)
    if a.dtype.kind == "b":
        a = a.astype("u1")
    elif a.dtype.kind in "iu":
        a = a.astype("<i8") if a.dtype.itemsize > 4 else a.astype("<i4")
    else:
        a = a.astype("<f8")
    a = np.ascontiguousarray(a.astype(a.dtype.newbyteorder("<")))
    n_comp = a.shape[1] if a.ndim == 2 else 1
    raw = np.array([a.nbytes], "<u8").tobytes() + a.tobytes()
    comp = f' NumberOfComponents="{n_comp}"' if n_comp > 1 else ""
    # NumberOfTuples: VTK needs it to size field data (arrays outside points and cells)
    return (f'{indent}<DataArray type="{_VTK_TYPES[a.dtype.str[1:]]}" Name={quoteattr(name)}{comp} '
            f'NumberOfTuples="{len(a)}" format="binary">{base64.b64encode(raw).decode("ascii")}</DataArray>')


def _atomic_write(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_vtu(path: str | os.PathLike, points: np.ndarray, triangles: np.ndarray, *,
              point_data: Mapping[str, np.ndarray] | None = None, cell_data: Mapping[str, np.ndarray] | None = None,
              field_data: Mapping[str, np.ndarray | float] | None = None) -> Path:
    """Write a triangle mesh as a VTK XML unstructured grid (``.vtu``).

    points (n, 3) float; triangles (m, 3) int indices into points; point_data {name: (n,) or (n, k)};
    cell_data {name: (m,) or (m, k)}; field_data {name: scalar or (j,)}: values that belong to the whole file
    (ParaView's "Field Data", meshio's ``field_data``). Booleans are written as UInt8, integers as Int32/Int64,
    the rest as Float64; NaN is kept.
    """
    pts = np.asarray(points, float).reshape(-1, 3)
    tri = np.asarray(triangles, np.int64).reshape(-1, 3)
    if tri.size and (tri.min() < 0 or tri.max() >= len(pts)):
        raise ValueError(f"triangles must index the {len(pts)} points (0..{len(pts) - 1}); "
                         f"got indices {tri.min()}..{tri.max()}")
    for what, data, n in (("point_data", point_data, len(pts)), ("cell_data", cell_data, len(tri))):
        for name, values in (data or {}).items():
            if np.shape(values)[:1] != (n,):
                raise ValueError(f"{what}[{name!r}] must have {n} rows; got shape {np.shape(values)}")
    i4, i5 = " " * 4, " " * 5
    lines = ['<?xml version="1.0"?>',
             '<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" header_type="UInt64">',
             "  <UnstructuredGrid>"]
    if field_data:
        lines.append("  <FieldData>")
        lines += [_array_xml(k, np.atleast_1d(v), i4) for k, v in field_data.items()]
        lines.append("  </FieldData>")
    lines += [f'  <Piece NumberOfPoints="{len(pts)}" NumberOfCells="{len(tri)}">',
              "   <Points>", _array_xml("Points", pts, i4), "   </Points>",
              "   <Cells>", _array_xml("connectivity", tri.ravel(), i4),
              _array_xml("offsets", 3 * np.arange(1, len(tri) + 1, dtype=np.int64), i4),
              _array_xml("types", np.full(len(tri), _VTK_TRIANGLE, np.uint8), i4), "   </Cells>"]
    for tag, data in (("PointData", point_data), ("CellData", cell_data)):
        lines.append(f"   <{tag}>")
        lines += [_array_xml(k, v, i5) for k, v in (data or {}).items()]
        lines.append(f"   </{tag}>")
    lines += ["  </Piece>", "  </UnstructuredGrid>", "</VTKFile>"]
    path = Path(path)
    _atomic_write(path, "\n".join(lines) + "\n")
    return path


def write_pvd(path: str | os.PathLike, files: Sequence[str | os.PathLike], times: Sequence[float], *,
              comment: str = "") -> Path:
    """Write a ParaView collection (``.pvd``): ``files[k]`` (in the .pvd's folder; its name is stored) at
    time ``times[k]``.

    ParaView and PyVista (``pyvista.PVDReader``) play it as a time series; ParaView orders the files by time.
    """
    if len(files) != len(times):
        raise ValueError(f"files and times must have the same length; got {len(files)} and {len(times)}")
    path = Path(path)
    lines = ['<?xml version="1.0"?>']
    if comment:
        lines.append(f"<!-- {escape(comment).replace('--', '- -')} -->")
    lines += ['<VTKFile type="Collection" version="1.0" byte_order="LittleEndian">', " <Collection>"]
    lines += [f'  <DataSet timestep="{float(t)!r}" group="" part="0" file={quoteattr(Path(f).name)}/>'
              for f, t in zip(files, times)]
    lines += [" </Collection>", "</VTKFile>"]
    _atomic_write(path, "\n".join(lines) + "\n")
    return path
