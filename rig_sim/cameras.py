"""A ring of virtual cameras around the bath, looking at the specimen.

World frame of the rig: z along the specimen axis, origin at mid-length on the axis (metres).
Each camera's image x axis runs along the specimen axis so the long specimen fills the wide side
of the sensor.
"""

from __future__ import annotations

import cv2
import numpy as np

from reconstruction import Camera

__all__ = ["camera_ring", "look_at", "specimen_triangulation_error"]


def look_at(center: np.ndarray, target: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World -> camera rotation and translation for a camera at ``center`` looking at ``target``.

    Parameters
    ----------
    center, target : ndarray, shape (3,)
        Optical centre and a point on the optical axis, metres (world frame).
    up : ndarray, shape (3,)
        World direction that should map to the image's +x axis (approximately).

    Returns
    -------
    R : ndarray, shape (3, 3)
    t : ndarray, shape (3,)
        So that ``Xc = R @ X + t``.
    """
    center = np.asarray(center, float)
    z = np.asarray(target, float) - center
    z /= np.linalg.norm(z)
    x = np.asarray(up, float) - np.dot(up, z) * z
    norm = np.linalg.norm(x)
    if norm < 1e-9:
        raise ValueError("look_at: 'up' must not be parallel to the viewing direction")
    x /= norm
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ center


def camera_ring(
    n: int = 6,
    *,
    distance: float = 0.150,
    image_size: tuple[int, int] = (2448, 2048),
    pixel_pitch: float = 3.45e-6,
    focal_length: float = 0.025,
    distortion: tuple[float, ...] = (-0.08, 0.12, 2e-4, -1.5e-4, 0.0),
    elevation: float = 0.0,
    jitter: float = 1.0,
    seed: int = 0,
    name_format: str = "cam{}",
) -> list[Camera]:
    """N cameras evenly spaced around the specimen axis, looking at the specimen centre.

    Parameters
    ----------
    n : int
        Number of cameras.
    distance : float
        Distance of each optical centre from the specimen axis, m.
    image_size : (width, height)
        Pixels. The focal length in pixels is ``focal_length / pixel_pitch`` scaled by
        ``width / 2448`` so reduced-resolution rings keep the same field of view.
    pixel_pitch, focal_length : float
        m. Defaults (3.45 µm, 25 mm at 150 mm) image the 35 mm x 20 mm specimen onto about
        1400 x 800 px of a 2448 x 2048 sensor (~48 px/mm).
    distortion : sequence of up to 5 floats
        OpenCV (k1, k2, p1, p2, k3); each camera gets a seeded ±20 % variation.
    elevation : float
        Ring elevation angle (rad): cameras at ``z = distance * tan(elevation)`` looking at the origin.
    jitter : float
        Scale of seeded per-camera imperfections (0 = ideal ring): pose ±1 mm / ±1°, focal ±1 %,
        principal point ±15 px (at full resolution), distortion ±20 %.
    seed : int
        Seed of the imperfections.

    Returns
    -------
    list of Camera
    """
    if n < 1:
        raise ValueError(f"camera_ring: n must be >= 1; got {n}")
    width, height = int(image_size[0]), int(image_size[1])
    rng = np.random.default_rng(seed)
    scale = width / 2448.0
    f0 = focal_length / pixel_pitch * scale
    dist0 = np.zeros(5)
    dist0[: len(distortion)] = distortion
    cams = []
    for i in range(n):
        phi = 2 * np.pi * i / n
        center = np.array([distance * np.cos(phi), distance * np.sin(phi), distance * np.tan(elevation)])
        center = center + jitter * rng.normal(0, 1e-3, 3)
        target = jitter * rng.normal(0, 1e-3, 3)
        R, _ = look_at(center, target, np.array([0.0, 0.0, 1.0]))
        roll = jitter * rng.normal(0, np.deg2rad(1.0))
        c, s = np.cos(roll), np.sin(roll)
        R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]) @ R
        t = -R @ center
        f = f0 * (1 + jitter * rng.normal(0, 0.01))
        fy = f * (1 + jitter * rng.normal(0, 0.001))
        cx = (width - 1) / 2 + jitter * rng.normal(0, 15) * scale
        cy = (height - 1) / 2 + jitter * rng.normal(0, 15) * scale
        K = np.array([[f, 0, cx], [0, fy, cy], [0, 0, 1.0]])
        dist = dist0 * (1 + jitter * rng.normal(0, 0.2, 5))
        rvec = cv2.Rodrigues(R)[0].ravel()
        cams.append(Camera(name_format.format(i), K, dist, rvec, t, (width, height)))
    return cams


def specimen_triangulation_error(true_cameras: list[Camera], estimated_cameras: list[Camera], *,
                                 radius: float = 0.0102, half_length: float = 0.0175, n_points: int = 1000,
                                 min_facing: float = 0.2, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """What a calibration error does where it matters: on the specimen surface.

    Random points on a cylinder (z = specimen axis) are projected exactly through the *true*
    cameras (only where the wall faces the camera: cosine of the view to the radial direction >=
    ``min_facing``) and triangulated with the *estimated* ones.

    Returns
    -------
    errors : ndarray, shape (n_seen,), m
        3-D distance to the truth of every point seen by >= 2 cameras.
    seen : ndarray of bool, shape (n_points,)
    """
    from reconstruction import triangulate

    rng = np.random.default_rng(seed)
    theta, z = rng.uniform(-np.pi, np.pi, n_points), rng.uniform(-half_length, half_length, n_points)
    points = np.stack([radius * np.cos(theta), radius * np.sin(theta), z], -1)
    pixels = np.stack([c.project(points) for c in true_cameras])
    radial = points * [1, 1, 0] / radius
    for i, cam in enumerate(true_cameras):
        view = cam.center - points
        facing = np.einsum("ij,ij->i", view, radial) / np.linalg.norm(view, axis=1)
        pixels[i, facing < min_facing] = np.nan
    tri = triangulate(pixels, estimated_cameras)
    seen = tri.n_views >= 2
    return np.linalg.norm(tri.points[seen] - points[seen], axis=1), seen
