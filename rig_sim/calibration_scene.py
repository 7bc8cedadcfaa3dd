"""Rendered ChArUco views in a small camera ring, for the calibration tests and benchmarks (moved from
tests/_calib_sim.py)."""

from __future__ import annotations

import functools

import cv2
import numpy as np

from reconstruction.cameras import Camera, rotation_matrix
from reconstruction.targets import BoardSpec, detect_boards
from rig_sim.board import board_poses, render_board_views
from rig_sim.cameras import camera_ring

SPEC = BoardSpec()


@functools.lru_cache(maxsize=1)
def rendered_charuco(n_cams: int = 4, n_views: int = 24, size: tuple[int, int] = (1224, 1024)):
    """(true cameras, BoardViews, detections) for a seeded ring; cached across tests."""
    cams = camera_ring(n_cams, image_size=size, seed=1)
    rv, tv = board_poses(cams, SPEC, n_views, seed=0)
    views = render_board_views(cams, SPEC, rv, tv, seed=0)
    det = detect_boards(views.images, SPEC)
    return cams, views, det


def rigid_fit(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R, t minimising |R src + t - dst| (Kabsch), points ``(n, 3)``."""
    cs, cd = src.mean(0), dst.mean(0)
    U, _, Vt = np.linalg.svd((src - cs).T @ (dst - cd))
    D = np.diag([1, 1, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, cd - R @ cs


def board_corners_world(rvecs, tvecs, spec=SPEC):
    obj = spec.object_points()
    ok = np.isfinite(rvecs).all(-1)
    return np.concatenate([obj @ rotation_matrix(r).T + t for r, t in zip(rvecs[ok], tvecs[ok])]), ok


def align_cameras(est: list[Camera], R: np.ndarray, t: np.ndarray) -> list[Camera]:
    """Cameras whose world frame is mapped by X_new = R X_old + t."""
    out = []
    for c in est:
        Rn = c.R @ R.T
        tn = c.tvec - Rn @ t
        out.append(Camera(c.name, c.K, c.dist, cv2.Rodrigues(Rn)[0].ravel(), tn, c.image_size))
    return out
