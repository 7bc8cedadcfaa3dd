"""Rendered calibration-board images: a board in many poses inside the camera ring.

Each camera pixel is traced back through the exact inverse of the lens distortion to a ray,
intersected with the board plane and the printed pattern sampled there (``cv2.remap``); the
sensor model of :mod:`rig_sim.sensor` is then applied.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from reconstruction import BoardSpec, Camera, rotation_matrix

from .refraction import project_refracted, rays_in_water
from .render import undistort_grid
from .sensor import SensorModel, expose, illumination_field

__all__ = ["BoardViews", "board_image", "board_poses", "render_board_views"]


@dataclass
class BoardViews:
    """Synchronised calibration views and their ground truth.

    Attributes
    ----------
    images : dict camera name -> list of ndarray (H, W), one per view
    rvecs, tvecs : ndarray, shape (n_views, 3)
        Board -> world pose: ``X_world = R(rvec) @ X_board + tvec`` (m).
    seen : ndarray, shape (n_cams, n_views), bool
        The board faces the camera and all its points lie inside the image.
    points : ndarray, shape (n_cams, n_views, n_points, 2)
        True pixel positions of the board points (NaN where ``seen`` is False).
    """

    images: dict
    rvecs: np.ndarray
    tvecs: np.ndarray
    seen: np.ndarray
    points: np.ndarray


def board_image(spec: BoardSpec, px_per_m: float, margin: float = 1.0) -> tuple[np.ndarray, float]:
    """The printed board as a float32 image in [0, 1], with a white margin of ``margin`` squares.

    Returns
    -------
    image : ndarray, shape (h, w), float32
    offset : float
        Board-frame coordinate (m) of the image's top-left pixel edge (negative: the margin).
    """
    wm, hm = spec.extent
    sq_px = int(round(spec.square_size * px_per_m))
    px_per_m = sq_px / spec.square_size
    w = int(round(wm * px_per_m))
    h = int(round(hm * px_per_m))
    if spec.kind == "charuco":
        core = spec.charuco_board().generateImage((w, h), marginSize=0, borderBits=1)
    else:
        core = np.full((h, w), 255, np.uint8)
        obj = spec.object_points()[:, :2] * px_per_m - 0.5
        if spec.kind == "chessboard":
            for i in range(spec.rows + 1):
                for j in range(spec.columns + 1):
                    if (i + j) % 2 == 0:
                        core[i * sq_px : (i + 1) * sq_px, j * sq_px : (j + 1) * sq_px] = 0
        else:
            rad = 0.25 * sq_px
            V, U = np.mgrid[0:h, 0:w]
            for x, y in obj:
                core[(U - x) ** 2 + (V - y) ** 2 <= rad * rad] = 0
    m = int(round(margin * sq_px))
    img = np.full((h + 2 * m, w + 2 * m), 1.0, np.float32)
    img[m : m + h, m : m + w] = core.astype(np.float32) / 255.0
    return img, -m / px_per_m


def _board_texture(spec: BoardSpec, px_per_m: float) -> tuple[np.ndarray, float, float]:
    """``board_image`` at about ``px_per_m`` (a whole number of pixels per square), and the px/m used.

    OpenCV's ``generateImage`` rejects a few square sizes (its marker ROI rounds past the image: 145 px for the
    default ChArUco board, hit by camera rings whose seed puts the ring's magnification there); the next size up
    samples the board as finely and is used instead.
    """
    sq_px = max(1, int(round(spec.square_size * px_per_m)))
    for extra in range(4):
        try:
            used = (sq_px + extra) / spec.square_size
            tex, off = board_image(spec, used)
            return tex, off, used
        except cv2.error as exc:
            error = exc
    raise error


def _board_coords_refracted(rays, Rc: np.ndarray, tc: np.ndarray, band: int = 256):
    """Board-plane coordinates (m) hit by refracted rays ``(origins, directions)``, each ``(H, W, 3)`` camera frame."""
    o_all, d_all = rays
    bx = np.empty(o_all.shape[:2])
    by = np.empty(o_all.shape[:2])
    n = Rc[:, 2]
    for r0 in range(0, o_all.shape[0], band):
        o = o_all[r0 : r0 + band].astype(np.float64)
        d = d_all[r0 : r0 + band].astype(np.float64)
        t = ((tc - o) @ n) / (d @ n)
        P = o + t[..., None] * d - tc
        bx[r0 : r0 + band] = P @ Rc[:, 0]
        by[r0 : r0 + band] = P @ Rc[:, 1]
    return bx, by


def board_poses(
    cameras: list[Camera], spec: BoardSpec, n_views: int, *, max_tilt: float = np.deg2rad(25), offset: float = 7e-3, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Random board poses near the ring centre, each facing a random direction in the ring plane.

    Returns
    -------
    rvecs, tvecs : ndarray, shape (n_views, 3)
        Board -> world poses.
    """
    rng = np.random.default_rng(seed)
    w, h = spec.extent
    centres = np.array([c.center for c in cameras])
    rvecs, tvecs = [], []
    for k in range(n_views):
        # face one camera (cycled), or the gap between two, so neighbouring cameras share views
        az0 = np.arctan2(centres[k % len(cameras), 1], centres[k % len(cameras), 0])
        az = az0 + (np.pi / len(cameras)) * rng.choice([-1, 0, 1]) + rng.normal(0, 0.1)
        n = np.array([np.cos(az), np.sin(az), 0.0])
        # board x along world z (the long image side), with in-plane and out-of-plane tilts
        ex = np.array([0.0, 0.0, 1.0])
        ey = np.cross(-n, ex)
        R = np.stack([ex, ey, -n], 1)  # columns: board x, y, z (z away from the cameras it faces)
        tilt = rng.normal(0, max_tilt / 2, 3).clip(-max_tilt, max_tilt)
        tilt[2] = rng.uniform(-np.pi / 8, np.pi / 8)  # in-plane
        R = R @ rotation_matrix(tilt)
        c = rng.uniform(-offset, offset, 3)
        t = c - R @ np.array([w / 2, h / 2, 0.0])
        rvecs.append(cv2.Rodrigues(R)[0].ravel())
        tvecs.append(t)
    return np.array(rvecs), np.array(tvecs)


_MAPS: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}  # the last ring's per-pixel maps (see _camera_maps)


def _camera_maps(cam: Camera, sensor: SensorModel, phase: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel undistorted normalised coordinates (h, w, 2) and illumination (h, w) of a camera.

    They do not change from view to view: kept for the cameras of the last ring (most of a view's
    cost when the views are rendered one at a time, as a simulated rig captures them)."""
    w, h = cam.image_size
    key = b"".join([np.asarray(cam.K, float).tobytes(), np.asarray(cam.dist, float).tobytes(),
                    np.array([w, h, phase], float).tobytes(), repr(sensor).encode()])
    if key not in _MAPS:
        if len(_MAPS) >= 6:
            _MAPS.clear()
        V, U = np.mgrid[0:h, 0:w].astype(np.float32)
        _MAPS[key] = (undistort_grid(cam, U, V).astype(np.float64), illumination_field(U, V, (w, h), sensor, phase=phase))
    return _MAPS[key]


def _refracted_pixel_rays(cam: Camera, win, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Refracted rays (origin, direction in the water) of every pixel, float32 (~1e-4 px at the board), by bands."""
    h, w = xy.shape[:2]
    o32 = np.empty((h, w, 3), np.float32)
    d32 = np.empty((h, w, 3), np.float32)
    for r0 in range(0, h, 256):
        o, d = rays_in_water(cam, win, xy[r0 : r0 + 256])
        o32[r0 : r0 + 256], d32[r0 : r0 + 256] = o, d
    return o32, d32


def _render_view(cam, win, xy, rays, texture, obj, rvec, tvec, bath_albedo, max_view_angle):
    """Radiance ``(h, w)`` of one board pose in one camera, and the board points' pixels ``(n, 2)`` when they are
    all well inside the image (else None)."""
    tex, off, px_per_m = texture
    w, h = cam.image_size
    Rb = rotation_matrix(rvec)
    Rc = cam.R @ Rb
    tc = cam.R @ tvec + cam.tvec
    normal_c = Rc[:, 2]
    facing = -normal_c @ (-tc) / np.linalg.norm(tc)  # board z points away from a camera seeing its face
    if not facing > np.cos(max_view_angle):
        return np.full((h, w), bath_albedo, np.float32), None
    if win is None:
        H = np.column_stack([Rc[:, 0], Rc[:, 1], tc])
        Hi = np.linalg.inv(H)
        X = Hi[0, 0] * xy[..., 0] + Hi[0, 1] * xy[..., 1] + Hi[0, 2]
        Y = Hi[1, 0] * xy[..., 0] + Hi[1, 1] * xy[..., 1] + Hi[1, 2]
        W = Hi[2, 0] * xy[..., 0] + Hi[2, 1] * xy[..., 1] + Hi[2, 2]
        bx, by = X / W, Y / W
    else:
        bx, by = _board_coords_refracted(rays, Rc, tc)
    mx = ((bx - off) * px_per_m - 0.5).astype(np.float32)
    my = ((by - off) * px_per_m - 0.5).astype(np.float32)
    sample = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0)
    on = sample >= 0
    # soften the sheet's outline so it is not a hard aliased edge
    shade = 0.85 + 0.15 * facing
    radiance = np.where(on, 0.06 + 0.84 * sample * shade, bath_albedo).astype(np.float32)
    Xw = obj @ Rb.T + tvec
    uv = cam.project(Xw) if win is None else project_refracted(cam, win, Xw)
    inside = np.isfinite(uv).all() and (uv[:, 0] > 2).all() and (uv[:, 1] > 2).all()
    inside = inside and (uv[:, 0] < w - 3).all() and (uv[:, 1] < h - 3).all()
    return radiance, (uv if inside else None)


def render_board_views(
    cameras: list[Camera],
    spec: BoardSpec,
    rvecs: np.ndarray,
    tvecs: np.ndarray,
    *,
    sensor: SensorModel = SensorModel(blur_sigma=0.7),
    bath_albedo: float = 0.12,
    max_view_angle: float = np.deg2rad(70),
    seed: int = 0,
    windows: list | None = None,
) -> BoardViews:
    """Render every board pose in every camera.

    Parameters
    ----------
    cameras : list of Camera
    spec : BoardSpec
    rvecs, tvecs : ndarray, shape (n_views, 3)
        Board -> world poses (see :func:`board_poses`).
    sensor : SensorModel
    bath_albedo : float
        Radiance of the background.
    max_view_angle : float
        The board is drawn only where its normal is within this angle (rad) of the line of sight.
    seed : int
    windows : list of FlatWindow or None, optional
        Per camera, a flat bath window to look through (the board is in the bath).

    Returns
    -------
    BoardViews
    """
    rvecs = np.atleast_2d(rvecs)
    tvecs = np.atleast_2d(tvecs)
    rng = np.random.default_rng(seed)
    obj = spec.object_points()
    n_cam, n_view = len(cameras), len(rvecs)
    # board texture sampled ~2.5x finer than the finest camera sampling, pre-filtered
    mag = max(c.K[0, 0] / np.linalg.norm(c.center) for c in cameras)  # px per m at the ring centre
    tex, off, px_per_m = _board_texture(spec, 2.5 * mag)
    tex = cv2.GaussianBlur(tex, (0, 0), 1.0)
    seen = np.zeros((n_cam, n_view), bool)
    points = np.full((n_cam, n_view, len(obj), 2), np.nan)
    images: dict[str, list[np.ndarray]] = {c.name: [] for c in cameras}
    windows = list(windows) if windows is not None else [None] * n_cam
    if len(windows) != n_cam:
        raise ValueError(f"render_board_views: windows needs one entry (FlatWindow or None) per camera ({n_cam}); got {len(windows)}")
    texture = (tex, off, px_per_m)
    for ci, cam in enumerate(cameras):
        win = windows[ci]
        xy, illum = _camera_maps(cam, sensor, ci)
        rays = _refracted_pixel_rays(cam, win, xy) if win is not None else None
        for k in range(n_view):
            radiance, uv = _render_view(cam, win, xy, rays, texture, obj, rvecs[k], tvecs[k], bath_albedo,
                                        max_view_angle)
            if uv is not None:
                seen[ci, k] = True
                points[ci, k] = uv
            images[cam.name].append(expose(radiance * illum, sensor, rng))
    return BoardViews(images, np.asarray(rvecs, float), np.asarray(tvecs, float), seen, points)
