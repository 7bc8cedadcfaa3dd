"""How much does ignoring the flat window's refraction cost? A geometric simulation.

Cameras in air look into the bath through tilted flat windows. The board is observed through
the windows (exact refraction, optional pixel noise) and the cameras are calibrated with the
plain pinhole + distortion model, which absorbs most of the refraction; points on the specimen
surface, also imaged through the windows, are then triangulated with that calibration and
compared with the truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from reconstruction import BoardSpec, Camera, calibrate_cameras, rotation_matrix, triangulate

from .board import board_poses
from .cameras import camera_ring
from .refraction import project_refracted, tilted_window

__all__ = ["RefractionError", "refraction_error"]


@dataclass
class RefractionError:
    """3-D error of points triangulated with a refraction-blind calibration.

    Attributes
    ----------
    tilt : float
        Window tilt, rad.
    rms, max : float
        3-D error over the specimen points seen by >= 2 cameras, m.
    calibration_rms : float
        RMS reprojection error of the (refraction-blind) calibration, px.
    n_points : int
    """

    tilt: float
    rms: float
    max: float
    calibration_rms: float
    n_points: int


def _rigid_fit(src, dst):
    cs, cd = src.mean(0), dst.mean(0)
    U, _, Vt = np.linalg.svd((src - cs).T @ (dst - cd))
    R = Vt.T @ np.diag([1, 1, np.sign(np.linalg.det(Vt.T @ U.T))]) @ U.T
    return R, cd - R @ cs


def refraction_error(
    tilt: float,
    *,
    n_cams: int = 4,
    n_views: int = 30,
    image_size: tuple[int, int] = (1224, 1024),
    focal_length: float = 0.018,
    window_distance: float = 0.08,
    glass: float = 3e-3,
    azimuth: float = 0.0,
    noise_px: float = 0.0,
    spec: BoardSpec = BoardSpec(),
    seed: int = 0,
) -> RefractionError:
    """Calibrate through windows tilted by ``tilt`` (rad) ignoring refraction; measure the 3-D error.

    The specimen surface (radius 10.2 mm, 35 mm long) is sampled at 2000 points; a camera sees a
    point when the wall faces it (cosine > 0.2) and it falls inside the image.
    """
    rng = np.random.default_rng(seed)
    cams = camera_ring(n_cams, image_size=image_size, focal_length=focal_length, seed=1)
    wins = [tilted_window(tilt, azimuth=azimuth, distance=window_distance, thickness=glass) for _ in cams]
    obj = spec.object_points()
    rv, tv = board_poses(cams, spec, n_views, seed=seed)
    uv = np.full((n_cams, n_views, len(obj), 2), np.nan)
    for v in range(n_views):
        R = rotation_matrix(rv[v])
        X = obj @ R.T + tv[v]
        for c, (cam, win) in enumerate(zip(cams, wins)):
            facing = (cam.center - X.mean(0)) @ (-R[:, 2])
            if facing <= 0.3 * np.linalg.norm(cam.center - X.mean(0)):
                continue
            p = project_refracted(cam, win, X)
            w, h = cam.image_size
            inside = np.isfinite(p).all(1) & (p[:, 0] > 0) & (p[:, 1] > 0) & (p[:, 0] < w - 1) & (p[:, 1] < h - 1)
            p = p + noise_px * rng.standard_normal(p.shape)
            uv[c, v, inside] = p[inside]
    res = calibrate_cameras(uv, obj, [c.image_size for c in cams], [c.name for c in cams], outlier_sigma=1e9)
    ok = np.isfinite(res.board_rvecs).all(-1)
    est_pts = np.concatenate([obj @ rotation_matrix(r).T + t for r, t in zip(res.board_rvecs[ok], res.board_tvecs[ok])])
    true_pts = np.concatenate([obj @ rotation_matrix(r).T + t for r, t in zip(rv[ok], tv[ok])])
    Ra, ta = _rigid_fit(est_pts, true_pts)
    import cv2

    est = []
    for c in res.cameras:
        Rn = c.R @ Ra.T
        est.append(Camera(c.name, c.K, c.dist, cv2.Rodrigues(Rn)[0].ravel(), c.tvec - Rn @ ta, c.image_size))
    th, z = rng.uniform(-np.pi, np.pi, 2000), rng.uniform(-0.0175, 0.0175, 2000)
    P = np.stack([0.0102 * np.cos(th), 0.0102 * np.sin(th), z], -1)
    px = np.full((n_cams, len(P), 2), np.nan)
    for c, (cam, win) in enumerate(zip(cams, wins)):
        view = cam.center - P
        facing = np.einsum("ij,ij->i", view, P * [1, 1, 0]) / np.linalg.norm(view, axis=1) / 0.0102
        p = project_refracted(cam, win, P)
        w, h = cam.image_size
        inside = (facing > 0.2) & np.isfinite(p).all(1) & (p[:, 0] > 0) & (p[:, 1] > 0) & (p[:, 0] < w - 1) & (p[:, 1] < h - 1)
        px[c, inside] = p[inside]
    tri = triangulate(px, est)
    sel = tri.n_views >= 2
    e = np.linalg.norm(tri.points[sel] - P[sel], axis=1)
    return RefractionError(float(tilt), float(np.sqrt(np.mean(e**2))), float(e.max()), float(res.rms_total), int(sel.sum()))
