"""A rig whose cameras look through one flat tank wall (glass | water) at a board at several depths and tilts:
exact refracted projections (synthetic checks) and rig_sim renderings (tests/test_calib_window_ba.py,
benchmarks/bench_window_ba.py). World frame = camera 0's (the calibration's gauge)."""

from __future__ import annotations

import cv2
import numpy as np

from reconstruction.cameras import Camera, rotation_matrix
from reconstruction.refraction import Window


def look_at(name: str, centre, target, f: float = 2000.0, size: tuple[int, int] = (1224, 1024)) -> Camera:
    """A camera at ``centre`` (m) looking at ``target``, image y down, k1 -0.05, k2 0.05."""
    centre, target = np.asarray(centre, float), np.asarray(target, float)
    z = (target - centre) / np.linalg.norm(target - centre)
    x = np.cross([0, 1.0, 0], z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    K = np.array([[f, 0, size[0] / 2 + 6.5], [0, 1.001 * f, size[1] / 2 - 5.5], [0, 0, 1]])
    return Camera(name, K, np.array([-0.05, 0.05, 0, 0, 0]), cv2.Rodrigues(R)[0].ravel(), -R @ centre, size)


def wall_rig(*, per_camera: bool = False, size: tuple[int, int] = (1224, 1024), f: float = 2000.0) -> list[Camera]:
    """Three cameras (camera 0 at the origin) looking at (0, 0, 200) mm through a 6 mm glass wall (n 1.52) 90 mm
    away, tilted 2 deg, into water (n 1.333). ``per_camera``: each camera its own window instead (planes 0/5/10 mm
    apart, normals 0/1.1/2.3 deg apart)."""
    target = np.array([0, 0, 0.2])
    centres = [np.zeros(3), np.array([0.07, 0, 0.01]), np.array([-0.05, 0.05, 0])]
    cams = [look_at(f"cam{i}", c, target, f, size) for i, c in enumerate(centres)]
    n = np.array([0.03, -0.02, 1.0]) / np.linalg.norm([0.03, -0.02, 1.0])
    wins = [Window(n + [0.02 * i * per_camera, 0, 0], 0.09 + 0.005 * i * per_camera, (0.006,), (1.52,), 1.333)
            for i in range(len(cams))]
    return [Camera(c.name, c.K, c.dist, c.rvec, c.tvec, c.image_size, window=w) for c, w in zip(cams, wins)]


def board_views(n_views: int, *, centre_xy=(0.0, 0.0), depths=(0.17, 0.2, 0.23), tilt_deg: float = 30.0,
                extent=(0.035, 0.025), seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Board -> world poses ``(n_views, 3)`` x2: the board's centre at ``depths`` (cycled, m) within 10 mm of the
    axis, tilted up to ``tilt_deg`` about x and y and turned up to 17 deg in its plane; its z away from the cameras."""
    rng = np.random.default_rng(seed)
    rv, tv = [], []
    half = np.array([extent[0] / 2, extent[1] / 2, 0.0])
    for v in range(n_views):
        tilt = np.deg2rad(tilt_deg) * rng.uniform(-1, 1, 2)
        R = rotation_matrix(np.array([tilt[0], tilt[1], rng.uniform(-0.3, 0.3)]))
        c = np.array([centre_xy[0] + rng.uniform(-0.01, 0.01), centre_xy[1] + rng.uniform(-0.01, 0.01),
                      depths[v % len(depths)]])
        rv.append(cv2.Rodrigues(R)[0].ravel())
        tv.append(c - R @ half)
    return np.array(rv), np.array(tv)


def exact_views(cams: list[Camera], obj: np.ndarray, rv: np.ndarray, tv: np.ndarray, noise_px: float = 0.0,
                seed: int = 0) -> np.ndarray:
    """Pixels ``(n_cams, n_views, n_points, 2)`` of the board points through each camera's window (NaN outside)."""
    rng = np.random.default_rng(seed)
    uv = np.full((len(cams), len(rv), len(obj), 2), np.nan)
    for v in range(len(rv)):
        X = obj @ rotation_matrix(rv[v]).T + tv[v]
        for c, cam in enumerate(cams):
            p = cam.project(X)
            w, h = cam.image_size
            ok = np.isfinite(p).all(1) & (p > 0).all(1) & (p[:, 0] < w - 1) & (p[:, 1] < h - 1)
            uv[c, v, ok] = p[ok] + noise_px * rng.standard_normal((int(ok.sum()), 2))
    return uv


def flat_windows(cams: list[Camera]) -> list:
    """rig_sim's per-camera FlatWindow (camera frame) of each camera's world-frame window."""
    from rig_sim.refraction import FlatWindow

    out = []
    for c in cams:
        w = c.window
        out.append(FlatWindow(c.R @ w.normal, w.distance_from(c.center), w.thicknesses[0], w.n_air, w.indices[0], w.n_bath))
    return out


def wrong_window(w: Window, shift_m: float = 2e-3, turn_deg: float = 2.0) -> Window:
    """``w`` moved ``shift_m`` along its normal and turned ``turn_deg``."""
    a = np.cross(w.normal, [0.0, 0.0, 1.0])
    a = a / np.linalg.norm(a) if np.linalg.norm(a) > 1e-6 else np.cross(w.normal, [1.0, 0.0, 0.0])
    t = np.deg2rad(turn_deg)
    return Window(np.cos(t) * w.normal + np.sin(t) * a / np.linalg.norm(a), w.offset + shift_m, w.thicknesses,
                  w.indices, w.n_bath, w.n_air)


def specimen_points(n: int = 2000, seed: int = 0) -> np.ndarray:
    """Points ``(n, 3)`` on the camera-facing half of a tube (radius 10 mm, 30 mm long, axis along y at z = 200 mm)."""
    rng = np.random.default_rng(seed)
    th = rng.uniform(-np.pi / 2, np.pi / 2, n)
    return np.stack([0.010 * np.sin(th), rng.uniform(-0.015, 0.015, n), 0.2 - 0.010 * np.cos(th)], -1)


def render_views(cams: list[Camera], spec, rv: np.ndarray, tv: np.ndarray, seed: int = 0):
    """rig_sim's rendering (``render_board_views``) of the board poses through each camera's window. The renderer
    scales its board texture by the cameras' distance from the world origin, so it renders in a frame centred on
    the target (z = 200 mm); the pixels are the same."""
    from rig_sim.board import render_board_views

    shift = np.array([0.0, 0.0, 0.2])
    moved = [Camera(c.name, c.K, c.dist, c.rvec, c.tvec + c.R @ shift, c.image_size) for c in cams]
    return render_board_views(moved, spec, rv, tv - shift, windows=flat_windows(cams), seed=seed)
