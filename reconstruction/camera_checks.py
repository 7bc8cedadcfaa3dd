"""Cameras that can exist: one check (:func:`validate_camera`) applied by every reader of a calibration
(aniposelib TOML, OpenCV YAML, an OpenPTV folder, a session's stored calibration) before a camera is used.

Pure: the camera in, nothing or a :class:`CameraError` out that names the camera, the field, what was expected
and what was found. A file that passes the syntax but describes no possible camera (K = 0, a negative focal
length, a principal point far outside the image, a non-finite rotation) is refused here, not discovered after
25 minutes of reconstruction that silently lost that camera's markers.
"""

from __future__ import annotations

import numpy as np

from reconstruction.calibration_errors import CameraError
from reconstruction.cameras import Camera

__all__ = ["CameraError", "MAX_IMAGE_SIDE_PX", "MAX_DISTANCE_M", "check_number_values", "fraction_in_view",
           "validate_camera"]

#: Largest image side a camera may have, px (no sensor comes near: 150 MP is 14,204 px wide).
MAX_IMAGE_SIDE_PX = 40_000
#: Farthest a camera may stand from the world origin, m (a translation in µm read as metres lands far beyond it).
MAX_DISTANCE_M = 1000.0
#: How far outside the image the principal point may lie, as a fraction of the image side.
PRINCIPAL_POINT_MARGIN = 0.5


def validate_camera(camera: Camera, where: str = "", *, principal_point: bool = True) -> Camera:
    """``camera`` when it can be a real camera, else a :class:`CameraError` naming the camera and the field.

    Checked: image size (both > 0 and at most :data:`MAX_IMAGE_SIDE_PX`, or both 0 = not given); K finite,
    focal lengths fx, fy > 0 with fy/fx in [1/4, 4], last row (0, 0, 1); the principal point within half an
    image of the image; distortion, rotation and translation finite; the camera within :data:`MAX_DISTANCE_M`
    of the world origin. ``where`` (e.g. ``"[cam_1]"``) is added to the message. ``principal_point=False``
    skips the principal-point test: a camera refined on a calibration body behind a window (OpenPTV, whose
    sensor offset absorbs the window) may well have its principal point several images away.
    """
    def fail(field: str, message: str) -> None:
        raise CameraError(f"camera {camera.name!r}{' ' + where if where else ''}: {field} {message}",
                          camera=camera.name, field=field)

    w, h = camera.image_size
    if (w, h) != (0, 0) and not (0 < w <= MAX_IMAGE_SIDE_PX and 0 < h <= MAX_IMAGE_SIDE_PX):
        fail("size", f"must be two image sides in 1..{MAX_IMAGE_SIDE_PX} px; got {w} x {h}")
    K = camera.K
    if not np.all(np.isfinite(K)):
        fail("matrix", f"must be finite numbers; got {K.tolist()}")
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if not (fx > 0 and fy > 0):
        fail("matrix", f"focal lengths fx, fy must be positive (px); got fx = {fx:g}, fy = {fy:g}")
    if not 0.25 <= fy / fx <= 4:
        fail("matrix", f"fy/fx must be within 0.25..4 (pixels are near square); got {fy / fx:.3g}")
    if not np.allclose(K[2], [0.0, 0.0, 1.0], atol=1e-9) or abs(K[1, 0]) > 1e-9:
        fail("matrix", f"must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]]; got {K.tolist()}")
    if w > 0 and principal_point:
        m = PRINCIPAL_POINT_MARGIN
        if not (-m * w <= cx <= (1 + m) * w and -m * h <= cy <= (1 + m) * h):
            fail("matrix", f"principal point ({cx:g}, {cy:g}) px is far outside the {w} x {h} px image "
                           f"(allowed: within half an image of it)")
    for field, values in (("distortions", camera.dist), ("rotation", camera.rvec), ("translation", camera.tvec)):
        if not np.all(np.isfinite(values)):
            fail(field, f"must be finite numbers; got {values.tolist()}")
    distance = float(np.linalg.norm(camera.center))
    if distance > MAX_DISTANCE_M:
        fail("translation", f"puts the camera {distance:.3g} m from the origin (at most {MAX_DISTANCE_M:g} m): "
                            "a length unit mixed up (µm read as m)?")
    return camera


def check_number_values(value, field: str, where: str) -> None:
    """A :class:`CameraError` unless ``value`` is a number or (nested) list of numbers as a file gives them:
    booleans (``true``) and text (``"1.5"``) are refused, though Python and NumPy would convert them."""
    items = value if isinstance(value, (list, tuple)) else [value]
    for item in items:
        if isinstance(item, (list, tuple)):
            check_number_values(item, field, where)
        elif isinstance(item, bool) or not isinstance(item, (int, float, np.integer, np.floating)):
            raise CameraError(f"{where}: {field} must hold numbers; got {item!r} ({type(item).__name__})",
                              camera=where, field=field)


def fraction_in_view(camera: Camera, points: np.ndarray) -> float:
    """Fraction of the finite world ``points`` (n, 3), m, that ``camera`` projects inside its image (NaN when
    there are none or the image size is not known). Occlusion is ignored: a camera that looks at the specimen
    projects nearly all its markers into the image, one whose calibration is wrong almost none. The pinhole
    projection is used (no distortion, no window): OpenCV's distortion polynomial folds points far outside
    the field of view back into the image."""
    pts = np.asarray(points, float).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    w, h = camera.image_size
    if pts.shape[0] == 0 or w == 0:
        return float("nan")
    xc = camera.to_camera(pts)
    front = xc[:, 2] > 0
    px = (xc[:, :2] / np.where(front, xc[:, 2], 1.0)[:, None]) @ camera.K[:2, :2].T + camera.K[:2, 2]
    inside = front & (px[:, 0] >= -0.5) & (px[:, 0] <= w - 0.5) \
        & (px[:, 1] >= -0.5) & (px[:, 1] <= h - 0.5)
    return float(inside.mean())
