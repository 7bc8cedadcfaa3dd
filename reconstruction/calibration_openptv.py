"""OpenPTV calibrations (``.ori`` + ``.addpar`` + media from ``ptv.par``) <-> vfmlab cameras with a window.

Pure text conversions; the caller reads and writes the files.

OpenPTV's model (liboptv ``imgcoord.c``, ``multimed.c``, ``trafo.c``, ``calibration.c``), lengths in mm:

- exterior: projection centre ``X0`` (world), angles (omega, phi, kappa) giving the matrix ``dm``;
  camera coordinates ``Xc = dm^T (X - X0)``, the camera looking along ``-z``;
- image plane: ``x = -cc Xc_x / Xc_z``, ``y = -cc Xc_y / Xc_z`` (y up), then ``+ (xh, yh)``, Brown
  distortion (k1, k2, k3 on r^2, r^4, r^6 in mm; p1, p2), affine (scale ``scx``, shear ``she``);
- pixels: ``u = x / pix_x + imx / 2``, ``v = imy / 2 - y / pix_y``: OpenPTV's pixel (0, 0) is the
  corner of the first pixel, OpenCV's its centre, hence ``u_opencv = u_openptv - 0.5``;
- media: ``n1`` (air), ``n2`` (glass, thickness ``d``), ``n3`` (water) as written in ``ptv.par``;
  the glass vector ``g`` points from the world origin (in the water) to the glass/water surface,
  normal to it. The refraction itself is Snell's law through flat layers, which
  :class:`~reconstruction.refraction.Window` solves exactly.

OpenCV equivalents (no shear): ``fx = scx cc / pix_x``, ``fy = cc / pix_y``, ``cx = imx/2 + xh/pix_x - 0.5``,
``cy = imy/2 - yh/pix_y - 0.5``, ``R = diag(1, -1, -1) dm^T``, k_i scaled by ``cc^(2i)``,
``(p1, p2)_opencv = (-p2 cc, p1 cc)``. Brown distortion is centred on the sensor centre in OpenPTV and
on the principal point in OpenCV: a calibration with both distortion and a principal point off
centre is refused rather than approximated.
"""

from __future__ import annotations

import cv2
import numpy as np

from reconstruction.calibration_errors import CalibrationFileError
from reconstruction.camera_checks import validate_camera
from reconstruction.cameras import Camera
from reconstruction.refraction import Window

__all__ = ["OpenPTVControl", "parse_ptv_par", "camera_from_openptv", "camera_to_openptv", "openptv_rotation"]

_FLIP = np.diag([1.0, -1.0, -1.0])


def _error(msg: str) -> Exception:
    return CalibrationFileError(msg)


class OpenPTVControl(dict):
    """What ``ptv.par`` says: ``n_cameras``, ``image_names``, ``calibration_images``, ``image_size``
    (px), ``pixel_size_mm`` (x, y), media ``n_air``, ``n_glass``, ``n_water``, ``glass_thickness_mm``."""


def parse_ptv_par(text: str) -> OpenPTVControl:
    """Parse OpenPTV's ``ptv.par`` text (one value per line)."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    try:
        n = int(lines[0])
        names = lines[1 : 1 + 2 * n]
        rest = lines[1 + 2 * n :]
        vals = [float(v.split()[0]) for v in rest[:12]]
        if len(vals) < 12 or len(names) < 2 * n:
            raise IndexError
    except (IndexError, ValueError):
        raise _error(
            "ptv.par: expected n_cameras, 2 image names per camera, then hp_flag, allcam_flag, tiff_flag, imx, imy, "
            f"pix_x, pix_y, chfield, n1, n2, n3, d (one per line); got {len(lines)} lines"
        ) from None
    out = OpenPTVControl(
        n_cameras=n, image_names=names[0::2], calibration_images=names[1::2],
        image_size=(int(vals[3]), int(vals[4])), pixel_size_mm=(vals[5], vals[6]),
        n_air=vals[8], n_glass=vals[9], n_water=vals[10], glass_thickness_mm=vals[11],
    )
    if not (out["pixel_size_mm"][0] > 0 and out["pixel_size_mm"][1] > 0 and min(out["image_size"]) > 0):
        raise _error(f"ptv.par: pixel size (mm) and image size (px) must be > 0; got {out['pixel_size_mm']}, {out['image_size']}")
    return out


def openptv_rotation(omega: float, phi: float, kappa: float) -> np.ndarray:
    """OpenPTV's ``dm`` (liboptv ``rotation_matrix``), shape (3, 3)."""
    co, so, cp, sp, ck, sk = np.cos(omega), np.sin(omega), np.cos(phi), np.sin(phi), np.cos(kappa), np.sin(kappa)
    return np.array([
        [cp * ck, -cp * sk, sp],
        [co * sk + so * sp * ck, co * ck - so * sp * sk, -so * cp],
        [so * sk - co * sp * ck, so * ck + co * sp * sk, co * cp],
    ])


def _numbers(text: str, where: str, count: int) -> np.ndarray:
    try:
        vals = np.array([float(v) for v in text.split()])
    except ValueError as exc:
        raise _error(f"{where}: {exc}") from None
    if vals.size < count:
        raise _error(f"{where}: expected at least {count} numbers; got {vals.size}")
    return vals


def camera_from_openptv(name: str, ori_text: str, addpar_text: str | None, control: OpenPTVControl) -> Camera:
    """One vfmlab :class:`Camera` (SI, OpenCV pixels) with its :class:`Window` from OpenPTV texts.

    ``ori_text``: X0 (3), angles (3), dm (9, ignored: recomputed from the angles as OpenPTV does),
    xh yh, cc, glass vector (3), all mm / rad. ``addpar_text``: k1 k2 k3 p1 p2 scx she (None = none).
    """
    ori = _numbers(ori_text, f"{name} .ori", 18)
    add = _numbers(addpar_text, f"{name} .addpar", 7) if addpar_text is not None else np.array([0, 0, 0, 0, 0, 1.0, 0])
    X0, angles, (xh, yh), cc, g = ori[0:3], ori[3:6], ori[15:17], ori[17], ori[18:21] if ori.size >= 21 else np.zeros(3)
    k1, k2, k3, p1, p2, scx, she = add[:7]
    if not cc > 0:
        raise _error(f"{name} .ori: focal distance cc must be > 0 mm; got {cc}")
    if np.any(add[:5] != 0) and (xh != 0 or yh != 0):
        raise _error(f"{name}: OpenPTV distortion is centred on the sensor, OpenCV's on the principal point; "
                     f"a calibration with both distortion and (xh, yh) = ({xh}, {yh}) mm is not supported")
    px, py = control["pixel_size_mm"]
    imx, imy = control["image_size"]
    K = np.array([
        [scx * cc / px, np.sin(she) * cc / px, imx / 2 + (scx * xh - np.sin(she) * yh) / px - 0.5],
        [0.0, np.cos(she) * cc / py, imy / 2 - np.cos(she) * yh / py - 0.5],
        [0.0, 0.0, 1.0],
    ])
    dist = np.array([k1 * cc**2, k2 * cc**4, -p2 * cc, p1 * cc, k3 * cc**6])
    R = _FLIP @ openptv_rotation(*angles).T
    X0_m = X0 * 1e-3
    rvec = cv2.Rodrigues(R)[0].ravel()
    window = _window_from_glass(name, g, control)
    meta = {"source": "openptv", "pixel_size_mm": (px, py), "shear_rad": float(she)}
    return validate_camera(Camera(name, K, dist, rvec, -R @ X0_m, (imx, imy), meta=meta, window=window),
                           principal_point=False)


def _window_from_glass(name: str, g: np.ndarray, control: OpenPTVControl) -> Window | None:
    indices = (control["n_air"], control["n_glass"], control["n_water"])
    if np.linalg.norm(g) == 0 or all(n == 1.0 for n in indices):
        return None
    d = control["glass_thickness_mm"] * 1e-3
    gm = np.asarray(g, float) * 1e-3
    gn = float(np.linalg.norm(gm))
    normal = -gm / gn  # into the bath: OpenPTV's world origin is in the water, beyond the glass
    return Window(normal, -(gn + d), (d,), (control["n_glass"],), control["n_water"], control["n_air"])


def camera_to_openptv(camera: Camera, *, pixel_size_mm: tuple[float, float] | None = None) -> tuple[str, str, dict]:
    """OpenPTV ``.ori`` and ``.addpar`` texts of ``camera`` and its media (for ``ptv.par``).

    Returns ``(ori_text, addpar_text, media)`` with ``media = {n_air, n_glass, n_water, glass_thickness_mm}``
    (all 1 / 0 without a window). Needs a one-layer window whose bath side contains the world origin
    (OpenPTV's convention) and no skew beyond OpenPTV's shear.
    """
    px, py = pixel_size_mm or camera.meta.get("pixel_size_mm", (None, None))
    if px is None:
        raise _error(f"camera_to_openptv({camera.name!r}): pixel_size_mm is needed (the sensor's pixel pitch, mm)")
    K = camera.K
    she = float(np.arctan2(K[0, 1] * py / px, K[1, 1]))
    cc = K[1, 1] * py / np.cos(she)
    scx = K[0, 0] * px / cc
    imx, imy = camera.image_size
    yh = (imy / 2 - 0.5 - K[1, 2]) * py / np.cos(she)
    xh = ((K[0, 2] + 0.5 - imx / 2) * px + np.sin(she) * yh) / scx
    k1c, k2c, p1c, p2c, k3c = camera.dist
    add = [k1c / cc**2, k2c / cc**4, k3c / cc**6, p2c / cc, -p1c / cc, scx, she]
    dm = (_FLIP @ camera.R).T
    phi = np.arcsin(np.clip(dm[0, 2], -1, 1))
    omega = np.arctan2(-dm[1, 2], dm[2, 2])
    kappa = np.arctan2(-dm[0, 1], dm[0, 0])
    X0 = camera.center * 1e3
    g, media = _glass_from_window(camera)
    fmt = lambda v: " ".join(f"{x: .12f}" for x in v)  # noqa: E731
    ori = "\n".join([fmt(X0), fmt([omega, phi, kappa]), "", *(fmt(row) for row in dm), "", fmt([xh, yh]),
                     fmt([cc]), "", fmt(g)]) + "\n"
    return ori, " ".join(f"{v:.10g}" for v in add) + "\n", media


def _glass_from_window(camera: Camera) -> tuple[np.ndarray, dict]:
    w = camera.window
    if w is None:
        return np.zeros(3), {"n_air": 1.0, "n_glass": 1.0, "n_water": 1.0, "glass_thickness_mm": 0.0}
    if len(w.thicknesses) != 1:
        raise _error(f"camera_to_openptv({camera.name!r}): OpenPTV files hold one glass layer; the window has {len(w.thicknesses)}")
    gn = -w.offset - w.thicknesses[0]
    if not gn > 0:
        raise _error(f"camera_to_openptv({camera.name!r}): OpenPTV needs the world origin in the bath, beyond the window; "
                     f"the bath side of this window starts {-gn:.4g} m beyond the origin")
    return -w.normal * gn * 1e3, {"n_air": w.n_air, "n_glass": w.indices[0], "n_water": w.n_bath,
                                  "glass_thickness_mm": w.thicknesses[0] * 1e3}
