"""DuoDIC / MultiDIC results from MATLAB ``.mat`` files: 3-D points (``DIC3Dstereo.mat``, ``DIC3DPPresults.mat``)
and the 2-D point pairs each camera tracked (``DIC2DpairResults.mat``).

MATLAB saves these as v7.3 (HDF5, read with h5py) or, for smaller results, v5 (read with ``scipy.io.loadmat``);
:func:`read_mat_struct` detects which from the file's header. Conventions of the source, converted here:

- MATLAB arrays are column-major: an ``N x 3`` matrix of points is stored ``3 x N`` in HDF5 and transposed back;
- pixels are 1-based in MATLAB (the centre of the top-left pixel is (1, 1)): 1 is subtracted to give OpenCV's
  pixels (``docs/decisions/0002-frames-and-shapes.md``);
- triangle indices (``Faces``) are 1-based: 1 is subtracted;
- DuoDIC's/MultiDIC's 3-D points are in camera 1's frame (MultiDIC: the frame of its reference camera pair),
  in the calibration's world unit (mm for DuoDIC's sample data): ``unit`` says which, the points come back in metres.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .result import DICImportError, DICPoints, length_scale

__all__ = ["StereoPixelTracks", "read_duodic_points", "read_duodic_2d_pairs", "read_mat_struct"]

log = logging.getLogger(__name__)

_HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"


def _is_hdf5(path: Path) -> bool:
    with open(path, "rb") as fh:
        head = fh.read(520)
    if len(head) < 128 or not head.startswith(b"MATLAB"):
        raise DICImportError(f"{path}: not a MATLAB .mat file (no 'MATLAB' header)")
    return head[512:520] == _HDF5_MAGIC


def _h5_value(f, obj):
    """A MATLAB value from an h5py object: struct -> dict, cell -> list, numeric -> array in MATLAB's orientation."""
    import h5py

    if isinstance(obj, h5py.Group):
        return {k: _h5_value(f, obj[k]) for k in obj}
    cls = obj.attrs.get("MATLAB_class", b"")
    cls = cls.decode() if isinstance(cls, bytes) else str(cls)
    if cls == "cell":
        # h5py holds the transpose of MATLAB's shape, so its C order is MATLAB's column-major order
        return [_h5_value(f, f[ref]) for ref in np.asarray(obj[()]).ravel()]
    if cls == "char":
        return "".join(map(chr, np.asarray(obj[()]).ravel()))
    if obj.attrs.get("MATLAB_empty", 0):
        return np.zeros((0, 0))
    return np.asarray(obj[()]).T


def _v5_value(obj):
    """A MATLAB value from ``scipy.io.loadmat(struct_as_record=False, squeeze_me=False)``."""
    from scipy.io.matlab import mat_struct

    if isinstance(obj, mat_struct):
        return {k: _v5_value(getattr(obj, k)) for k in obj._fieldnames}
    if isinstance(obj, np.ndarray) and obj.dtype == object:
        if obj.size == 1 and isinstance(obj.flat[0], mat_struct):
            return _v5_value(obj.flat[0])
        return [_v5_value(v) for v in obj.T.ravel()]
    if isinstance(obj, np.ndarray) and obj.dtype.kind == "U":
        return "".join(obj.ravel())
    return obj


def read_mat_struct(path, name: str | None = None) -> dict:
    """The top-level MATLAB variable ``name`` (default: the only or first one) of a ``.mat`` file, as nested dicts
    (structs), lists (cells, column-major order) and arrays (MATLAB's own orientation, e.g. ``N x 3``).

    v7.3 files are read with h5py, v5 files with scipy.io; DICImportError naming the file otherwise.
    """
    path = Path(path)
    if not path.is_file():
        raise DICImportError(f"{path}: no such file")
    if _is_hdf5(path):
        import h5py

        with h5py.File(path, "r") as f:
            names = [k for k in f if not k.startswith("#")]
            key = _pick(names, name, path)
            return _h5_value(f, f[key])
    import scipy.io

    try:
        data = scipy.io.loadmat(path, struct_as_record=False, squeeze_me=False)
    except (ValueError, NotImplementedError, TypeError) as exc:
        raise DICImportError(f"{path}: scipy.io cannot read this MATLAB file ({exc})") from None
    names = [k for k in data if not k.startswith("__")]
    return _v5_value(data[_pick(names, name, path)])


def _pick(names: list[str], name: str | None, path: Path) -> str:
    if name is not None:
        if name not in names:
            raise DICImportError(f"{path}: no variable {name!r}; the file has {names}")
        return name
    if not names:
        raise DICImportError(f"{path}: no MATLAB variable in the file")
    return names[0]


def _field(struct: dict, key: str, path: Path, what: str):
    if not isinstance(struct, dict) or key not in struct:
        have = sorted(struct) if isinstance(struct, dict) else type(struct).__name__
        raise DICImportError(f"{path}: {what} has no field {key!r} (has {have})")
    return struct[key]


def _stack_rows(cells: list, width: int, path: Path, what: str) -> np.ndarray:
    """Cells of ``N x width`` (or empty) matrices -> (n_cells, N, width); empty cells become NaN."""
    arrays = [np.asarray(c, dtype=float) for c in cells]
    n = max((a.shape[0] for a in arrays if a.size), default=0)
    out = np.full((len(arrays), n, width), np.nan)
    for i, a in enumerate(arrays):
        if not a.size:
            continue
        if a.shape != (n, width):
            raise DICImportError(f"{path}: {what}{{{i + 1}}} has shape {a.shape}; expected ({n}, {width})")
        out[i] = a
    return out


def _triangles(struct: dict) -> np.ndarray | None:
    faces = struct.get("Faces")
    if faces is None or not np.size(faces):
        return None
    return np.asarray(faces, dtype=float).astype(np.int64) - 1


def read_duodic_points(path, unit: str = "mm") -> DICPoints:
    """3-D points of a DuoDIC ``DIC3Dstereo.mat`` (variable ``DIC3D``) or MultiDIC ``DIC3DPPresults.mat``
    (variable ``DIC3DPPresults``): the cell ``Points3D`` (one ``N x 3`` matrix per step, in the calibration's
    world unit ``unit``), ``corrComb`` (the combined correlation cost of the two cameras, lower is better) as
    ``quality``, and ``Faces`` (1-based) as ``triangles``.

    Returns
    -------
    DICPoints
        ``points`` (n_steps, n_points, 3) in m, camera 1's frame; NaN where DuoDIC/MultiDIC left a point out.
    """
    path = Path(path)
    s = read_mat_struct(path)
    if isinstance(s, dict) and "Points3D" not in s:
        inner = [v for v in s.values() if isinstance(v, dict) and "Points3D" in v]
        s = inner[0] if inner else s
    cells = _field(s, "Points3D", path, "the result struct")
    if not isinstance(cells, list) or not cells:
        raise DICImportError(f"{path}: Points3D must be a non-empty cell array (one N x 3 matrix per step)")
    pts = _stack_rows(cells, 3, path, "Points3D") * length_scale(unit, str(path))
    quality = None
    if isinstance(s.get("corrComb"), list) and len(s["corrComb"]) == len(cells):
        quality = _stack_rows([np.reshape(c, (-1, 1)) for c in s["corrComb"]], 1, path, "corrComb")[..., 0]
    log.debug("%s: %d steps x %d points", path, pts.shape[0], pts.shape[1])
    return DICPoints(points=pts, quality=quality, triangles=_triangles(s),
                     quality_name="corrComb (combined correlation cost of the two cameras, lower is better)",
                     source=str(path))


@dataclass(frozen=True)
class StereoPixelTracks:
    """The 2-D points each camera tracked (DuoDIC ``DIC2DpairResults``), ready for triangulation.

    Attributes
    ----------
    pixels : ndarray, shape (n_cameras, n_steps, n_points, 2)
        OpenCV pixels (0-based; MATLAB's 1 subtracted); NaN where a point was lost.
    correlation : ndarray, shape (n_cameras, n_steps, n_points)
        Ncorr's correlation cost per point (lower is better); NaN where lost.
    triangles : ndarray, shape (n_triangles, 3), int, or None
        0-based point indices of DuoDIC's mesh.
    cameras : tuple of int
        DuoDIC's camera numbers (``nCamRef``, ``nCamDef``), 1-based as DuoDIC counts them.
    image_paths : tuple of str
        The images DuoDIC correlated, camera by camera (n_cameras * n_steps).
    """

    pixels: np.ndarray
    correlation: np.ndarray
    triangles: np.ndarray | None
    cameras: tuple[int, ...]
    image_paths: tuple[str, ...]


def read_duodic_2d_pairs(path) -> StereoPixelTracks:
    """DuoDIC's ``DIC2DpairResults.mat``: the cell ``Points`` holds ``2 * n_images`` matrices ``N x 2`` (the
    reference camera's steps, then the other camera's), ``CorCoeffVec`` their correlation costs."""
    path = Path(path)
    s = read_mat_struct(path)
    pts = _field(s, "Points", path, "DIC2DpairResults")
    n_images = int(np.asarray(_field(s, "nImages", path, "DIC2DpairResults")).ravel()[0])
    if not isinstance(pts, list) or len(pts) != 2 * n_images:
        raise DICImportError(f"{path}: Points must be a cell of 2 x nImages = {2 * n_images} matrices; "
                             f"got {len(pts) if isinstance(pts, list) else type(pts).__name__}")
    xy = _stack_rows(pts, 2, path, "Points") - 1.0
    n = xy.shape[1]
    cc = s.get("CorCoeffVec")
    corr = (_stack_rows([np.reshape(c, (-1, 1)) for c in cc], 1, path, "CorCoeffVec")[..., 0]
            if isinstance(cc, list) and len(cc) == len(pts) else np.full(xy.shape[:2], np.nan))
    corr = np.where(np.isfinite(xy).all(-1), corr, np.nan)
    cams = tuple(int(np.asarray(s.get(k, i + 1)).ravel()[0]) for i, k in enumerate(("nCamRef", "nCamDef")))
    paths = s.get("ImPaths", [])
    return StereoPixelTracks(pixels=xy.reshape(2, n_images, n, 2), correlation=corr.reshape(2, n_images, n),
                             triangles=_triangles(s), cameras=cams,
                             image_paths=tuple(p if isinstance(p, str) else "" for p in paths))
