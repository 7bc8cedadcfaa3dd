"""Calibration files as text: aniposelib-compatible TOML, OpenCV FileStorage YAML, session arrays.

Pure conversions between :class:`~reconstruction.cameras.Camera` lists and strings / arrays;
reading and writing the files themselves is left to the caller (CLI).

Units: cameras hold translations in metres. Files carry a ``units`` key (``[metadata] units`` in
TOML, a top-level ``units`` in YAML). aniposelib writes no unit (its translations are in the
unit of the board's square size, usually mm): when a file has no ``units`` key the ``units``
argument decides, default ``"mm"``.

TOML layout (aniposelib ``CameraGroup.dump``)::

    [cam_0]
    name = "cam0"
    size = [2448, 2048]                     # width, height
    matrix = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
    distortions = [k1, k2, p1, p2, k3]
    rotation = [rx, ry, rz]                 # Rodrigues, world -> camera
    translation = [tx, ty, tz]              # in `units`
    [metadata]
    units = "mm"
"""

from __future__ import annotations

import tomllib

import cv2
import numpy as np
import tomli_w

from .calibration_errors import CalibrationFileError
from .camera_checks import check_number_values, validate_camera
from .calibration_openptv import OpenPTVControl, camera_from_openptv, camera_to_openptv, parse_ptv_par
from .cameras import Camera
from .refraction import Window

__all__ = [
    "CalibrationFileError",
    "UNIT_SCALE",
    "cameras_to_toml",
    "cameras_from_toml",
    "cameras_to_yaml",
    "cameras_from_yaml",
    "cameras_to_arrays",
    "cameras_from_arrays",
    "OpenPTVControl",
    "parse_ptv_par",
    "camera_from_openptv",
    "camera_to_openptv",
]

UNIT_SCALE = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6, "µm": 1e-6}
_UNIT_ALIASES = {"meter": "m", "meters": "m", "metre": "m", "metres": "m", "millimeter": "mm", "millimeters": "mm",
                 "millimetre": "mm", "millimetres": "mm", "centimeter": "cm", "centimeters": "cm", "micron": "um"}


def _scale(units: str, where: str) -> float:
    u = str(units).strip().lower()
    u = _UNIT_ALIASES.get(u, u)
    if u not in UNIT_SCALE:
        raise CalibrationFileError(f"{where}: units must be one of {sorted(UNIT_SCALE)}; got {units!r}")
    return UNIT_SCALE[u]


def _cam_from_parts(name, size, K, dist, rvec, tvec, scale, where) -> Camera:
    try:
        K = np.asarray(K, float).reshape(3, 3)
        dist = np.asarray(dist, float).ravel()
        rvec = np.asarray(rvec, float)
        if rvec.shape == (3, 3):
            rvec = _rotation_vector(rvec, where)
        rvec = rvec.ravel()
        tvec = np.asarray(tvec, float).ravel()
        size = tuple(int(v) for v in np.asarray(size).ravel())
    except (ValueError, TypeError) as exc:
        raise CalibrationFileError(f"{where}: {exc}") from None
    if rvec.size != 3 or tvec.size != 3 or len(size) != 2:
        raise CalibrationFileError(f"{where}: rotation/translation need 3 values and size 2; got {rvec.size}, {tvec.size}, {len(size)}")
    if dist.size > 5 and np.any(dist[5:] != 0):
        raise CalibrationFileError(f"{where}: only the 5-coefficient OpenCV model (k1, k2, p1, p2, k3) is supported; got {dist.size}")
    if K.size and not np.all(np.isfinite(K)):
        raise CalibrationFileError(f"{where}: matrix must be finite numbers; got {K.tolist()}")
    return validate_camera(Camera(str(name), K, dist[:5], rvec, tvec * scale, size), where)


def _rotation_vector(R: np.ndarray, where: str) -> np.ndarray:
    """The Rodrigues vector of a rotation matrix; a CalibrationFileError when ``R`` is no rotation."""
    if not np.all(np.isfinite(R)) or not np.allclose(R.T @ R, np.eye(3), atol=1e-3) or np.linalg.det(R) < 0:
        raise CalibrationFileError(f"{where}: rotation matrix must be a rotation (orthonormal, det +1); got {R.tolist()}")
    return cv2.Rodrigues(R)[0]


# ---------------------------------------------------------------------------------------------- TOML


def cameras_to_toml(cameras: list[Camera], *, units: str = "mm", metadata: dict | None = None) -> str:
    """aniposelib ``calibration.toml`` text for ``cameras`` with translations in ``units``."""
    s = _scale(units, "cameras_to_toml")
    lines = []
    for i, c in enumerate(cameras):
        lines += [
            f"[cam_{i}]",
            f"name = {tomli_w.dumps({'v': c.name})[4:].strip()}",
            f"size = [{int(c.image_size[0])}, {int(c.image_size[1])}]",
            "matrix = [" + ", ".join(_floats(row) for row in c.K) + "]",
            f"distortions = {_floats(c.dist)}",
            f"rotation = {_floats(c.rvec)}",
            f"translation = {_floats(c.tvec / s)}",
            "",
        ]
    meta = dict(metadata or {})
    meta["units"] = units
    return "\n".join(lines) + tomli_w.dumps({"metadata": _jsonable(meta)})


def _floats(values) -> str:
    return "[" + ", ".join(repr(float(v)) for v in values) + "]"


def cameras_from_toml(text: str, *, units: str | None = None) -> tuple[list[Camera], dict]:
    """Parse aniposelib ``calibration.toml`` text.

    Parameters
    ----------
    text : str
    units : str, optional
        Length unit of the translations when the file's ``[metadata]`` has no ``units`` key
        (default ``"mm"``, aniposelib's usual board unit). A ``units`` key in the file wins.

    Returns
    -------
    cameras : list of Camera
        Translations in metres, ordered by the ``cam_N`` index.
    metadata : dict
    """
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CalibrationFileError(f"calibration TOML: {exc}") from None
    meta = dict(doc.get("metadata", {}))
    scale = _scale(meta.get("units", units or "mm"), "calibration TOML [metadata] units")
    keys = [k for k in doc if k != "metadata" and isinstance(doc[k], dict)]
    if not keys:
        raise CalibrationFileError("calibration TOML: no [cam_N] sections")

    def order(k):
        tail = k.rsplit("_", 1)[-1]
        return (0, int(tail), k) if tail.isdigit() else (1, 0, k)

    cams = []
    for k in sorted(keys, key=order):
        d = doc[k]
        if d.get("fisheye", False):
            raise CalibrationFileError(f"calibration TOML [{k}]: fisheye cameras are not supported")
        missing = [f for f in ("matrix", "rotation", "translation", "size") if f not in d]
        dist = d.get("distortions", d.get("distortion"))
        if missing or dist is None:
            raise CalibrationFileError(f"calibration TOML [{k}]: missing {missing + ([] if dist is not None else ['distortions'])}")
        for field, value in (("size", d["size"]), ("matrix", d["matrix"]), ("distortions", dist),
                             ("rotation", d["rotation"]), ("translation", d["translation"])):
            check_number_values(value, field, f"calibration TOML [{k}]")
        cams.append(_cam_from_parts(d.get("name", k), d["size"], d["matrix"], dist, d["rotation"], d["translation"], scale, f"[{k}]"))
    return cams, meta


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items() if v is not None}
    if isinstance(obj, (list, tuple, np.ndarray)):
        return [_jsonable(v) for v in np.asarray(obj).tolist()] if isinstance(obj, np.ndarray) else [_jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


# ---------------------------------------------------------------------------------------------- YAML


def cameras_to_yaml(cameras: list[Camera], *, units: str = "mm", metadata: dict | None = None) -> str:
    """OpenCV FileStorage YAML text: top-level ``units``, ``n_cameras``, and ``cam_N`` maps with
    ``name, image_width, image_height, camera_matrix, distortion_coefficients, rvec, tvec, R``."""
    s = _scale(units, "cameras_to_yaml")
    fs = cv2.FileStorage("", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY | cv2.FILE_STORAGE_FORMAT_YAML)
    fs.write("units", units)
    fs.write("n_cameras", len(cameras))
    for key, value in (metadata or {}).items():
        if isinstance(value, (int, float, str)) and key not in ("units", "n_cameras") and not key.startswith("cam_"):
            fs.write(str(key), value)
    for i, c in enumerate(cameras):
        fs.startWriteStruct(f"cam_{i}", cv2.FileNode_MAP)
        fs.write("name", c.name)
        fs.write("image_width", int(c.image_size[0]))
        fs.write("image_height", int(c.image_size[1]))
        fs.write("camera_matrix", c.K)
        fs.write("distortion_coefficients", c.dist.reshape(1, 5))
        fs.write("rvec", c.rvec.reshape(3, 1))
        fs.write("tvec", (c.tvec / s).reshape(3, 1))
        fs.write("R", c.R)
        fs.endWriteStruct()
    return fs.releaseAndGetString()


def cameras_from_yaml(text: str, *, units: str | None = None) -> tuple[list[Camera], dict]:
    """Parse OpenCV FileStorage YAML/XML/JSON text.

    Understands the layout written by :func:`cameras_to_yaml`, a single camera at top level
    (``camera_matrix``, ``distortion_coefficients``, ``image_width``, ``image_height``, optional
    ``rvec``/``R`` and ``tvec``; ROS style ``{rows, cols, data}`` maps are accepted), and
    ``cv2.stereoCalibrate`` output (``M1, D1, M2, D2, R, T``, optional ``image_width/height``).
    Translations are in the file's top-level ``units`` when present, else ``units`` (default mm).
    """
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except cv2.error as exc:
        raise CalibrationFileError(f"calibration YAML: cannot parse ({exc.err})") from None
    if not fs.isOpened():
        raise CalibrationFileError("calibration YAML: cannot parse")
    keys = list(fs.root().keys())
    meta = _yaml_scalars(fs, keys)
    file_units = meta.get("units")
    scale = _scale(file_units if file_units is not None else (units or "mm"), "calibration YAML units")
    cams = _yaml_cameras(fs, keys, scale)
    fs.release()
    return cams, meta


def _yaml_scalars(fs, keys: list[str]) -> dict:
    """The top-level strings and numbers of a FileStorage (``units``, ``n_cameras``, ...)."""
    meta = {}
    for k in keys:
        node = fs.getNode(k)
        if node.isString():
            meta[k] = node.string()
        elif node.isReal() or node.isInt():
            meta[k] = node.real()
    return meta


def _yaml_mat(node, where: str):
    """A FileStorage matrix (or ROS ``{rows, cols, data}`` map) as an array; None when absent."""
    if node.empty():
        return None
    if node.isMap() and not node.getNode("data").empty() and node.mat() is None:
        data = node.getNode("data")
        vals = [data.at(i).real() for i in range(data.size())]
        rows = int(node.getNode("rows").real())
        return np.asarray(vals, float).reshape(rows, -1)
    m = node.mat()
    if m is None:
        raise CalibrationFileError(f"calibration YAML: {where} is not a matrix")
    return np.asarray(m, float)


def _yaml_size(node, where: str):
    """``[width, height]`` px from ``image_width``/``image_height`` or ``image_size``."""
    w, h = node.getNode("image_width"), node.getNode("image_height")
    if w.empty() or h.empty():
        sz = node.getNode("image_size")
        if not sz.empty():
            m = _yaml_mat(sz, where + " image_size")
            return m.ravel()[:2]
        raise CalibrationFileError(f"calibration YAML: {where} needs image_width and image_height")
    return [w.real(), h.real()]


def _yaml_pose(node, where: str) -> tuple[np.ndarray, np.ndarray]:
    """``rvec`` (or ``R``) and ``tvec`` of a camera map; zeros when absent."""
    r = _yaml_mat(node.getNode("rvec"), f"{where}rvec")
    if r is None:
        r = _yaml_mat(node.getNode("R"), f"{where}R")
    t = _yaml_mat(node.getNode("tvec"), f"{where}tvec")
    return (r if r is not None else np.zeros(3)), (t if t is not None else np.zeros(3))


def _yaml_cameras(fs, keys: list[str], scale: float) -> list[Camera]:
    """The cameras of one of the three layouts: ``cam_N`` maps, stereo ``M1 D1 M2 D2 R T``, one top-level camera."""
    root = fs.root()
    cams = []
    cam_keys = sorted((k for k in keys if k.startswith("cam_")), key=lambda k: int(k[4:]) if k[4:].isdigit() else 1 << 30)
    if cam_keys:
        for k in cam_keys:
            n = fs.getNode(k)
            name = n.getNode("name").string() if not n.getNode("name").empty() else k
            K = _yaml_mat(n.getNode("camera_matrix"), f"{k}.camera_matrix")
            if K is None:
                raise CalibrationFileError(f"calibration YAML: {k} has no camera_matrix")
            dist = _yaml_mat(n.getNode("distortion_coefficients"), f"{k}.distortion_coefficients")
            r, t = _yaml_pose(n, f"{k}.")
            cams.append(_cam_from_parts(name, _yaml_size(n, k), K, dist if dist is not None else np.zeros(5), r, t, scale, k))
    elif not fs.getNode("M1").empty():
        size = _yaml_size(root, "stereo file") if not fs.getNode("image_width").empty() else [0, 0]
        cams.append(_cam_from_parts("cam0", size, _yaml_mat(fs.getNode("M1"), "M1"), _yaml_mat(fs.getNode("D1"), "D1"),
                                    np.zeros(3), np.zeros(3), scale, "M1"))
        cams.append(_cam_from_parts("cam1", size, _yaml_mat(fs.getNode("M2"), "M2"), _yaml_mat(fs.getNode("D2"), "D2"),
                                    _yaml_mat(fs.getNode("R"), "R"), _yaml_mat(fs.getNode("T"), "T"), scale, "M2"))
    elif not fs.getNode("camera_matrix").empty():
        name = fs.getNode("camera_name").string() if not fs.getNode("camera_name").empty() else "cam0"
        r, t = _yaml_pose(root, "")
        dist = _yaml_mat(fs.getNode("distortion_coefficients"), "distortion_coefficients")
        cams.append(_cam_from_parts(name, _yaml_size(root, "top level"), _yaml_mat(fs.getNode("camera_matrix"), "camera_matrix"),
                                    dist if dist is not None else np.zeros(5), r, t, scale, "top level"))
    else:
        raise CalibrationFileError("calibration YAML: found neither cam_N maps, M1/M2 stereo matrices nor a camera_matrix")
    return cams


# ---------------------------------------------------------------------------------------------- session arrays


def cameras_to_arrays(cameras: list[Camera], rms: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Arrays of the session's ``calibration`` result (SI): camera_names, K, dist, rvec, tvec, image_size, rms."""
    out = {
        "camera_names": np.array([c.name for c in cameras], dtype=object),
        "K": np.stack([c.K for c in cameras]),
        "dist": np.stack([c.dist for c in cameras]),
        "rvec": np.stack([c.rvec for c in cameras]),
        "tvec": np.stack([c.tvec for c in cameras]),
        "image_size": np.array([c.image_size for c in cameras], dtype=np.int64),
    }
    out["rms"] = np.full(len(cameras), np.nan) if rms is None else np.asarray(rms, float).reshape(len(cameras))
    if any(c.window is not None for c in cameras):
        out.update(_window_arrays(cameras))
    return out


def _window_arrays(cameras: list[Camera]) -> dict[str, np.ndarray]:
    """``window_*`` arrays (NaN rows for cameras without a window): normal (n, 3), offset (n,) m,
    thickness (n, m) m, index (n, m), n_bath (n,), n_air (n,)."""
    m = max(len(c.window.thicknesses) for c in cameras if c.window is not None)
    n = len(cameras)
    out = {"window_normal": np.full((n, 3), np.nan), "window_offset": np.full(n, np.nan),
           "window_thickness": np.full((n, m), np.nan), "window_index": np.full((n, m), np.nan),
           "window_n_bath": np.full(n, np.nan), "window_n_air": np.full(n, np.nan)}
    for i, c in enumerate(cameras):
        w = c.window
        if w is None:
            continue
        k = len(w.thicknesses)
        out["window_normal"][i], out["window_offset"][i] = w.normal, w.offset
        out["window_thickness"][i, :k], out["window_index"][i, :k] = w.thicknesses, w.indices
        out["window_n_bath"][i], out["window_n_air"][i] = w.n_bath, w.n_air
    return out


def _window_from_arrays(arrays: dict, i: int) -> Window | None:
    if "window_normal" not in arrays or not np.all(np.isfinite(np.asarray(arrays["window_normal"])[i])):
        return None
    t = np.asarray(arrays["window_thickness"])[i]
    k = np.isfinite(t)
    return Window(np.asarray(arrays["window_normal"])[i], float(np.asarray(arrays["window_offset"])[i]), tuple(t[k]),
                  tuple(np.asarray(arrays["window_index"])[i][k]), float(np.asarray(arrays["window_n_bath"])[i]),
                  float(np.asarray(arrays["window_n_air"])[i]))


def cameras_from_arrays(arrays: dict) -> list[Camera]:
    """Inverse of :func:`cameras_to_arrays` (accepts bytes names as h5py returns them)."""
    try:
        names = [n.decode() if isinstance(n, bytes) else str(n) for n in np.asarray(arrays["camera_names"]).tolist()]
        K, dist, rvec, tvec, size = (np.asarray(arrays[k]) for k in ("K", "dist", "rvec", "tvec", "image_size"))
    except KeyError as exc:
        raise CalibrationFileError(f"calibration arrays: missing {exc.args[0]!r}") from None
    return [validate_camera(Camera(names[i], K[i], dist[i], rvec[i], tvec[i], tuple(size[i]),
                                   window=_window_from_arrays(arrays, i)), principal_point=False)
            for i in range(len(names))]
