"""Pinhole camera with OpenCV's lens distortion model, vectorised projection.

Frames (see ``docs/decisions/0002-frames-and-shapes.md``): world points are in the rig frame
(metres, z along the specimen axis); a camera maps a world point X to its own frame by
``Xc = R @ X + t`` (R from the Rodrigues vector ``rvec``), z forward; pixels are OpenCV's
(x right, y down, origin at the centre of the top-left pixel).

A camera may look into the bath through a flat window (``Camera.window``, see
``reconstruction/refraction.py``); then :meth:`Camera.project` and :meth:`Camera.rays` follow the
refracted rays exactly. Without a window nothing changes.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from reconstruction.refraction import Window, refracted_directions, window_rays

__all__ = ["Camera", "project_points", "rotation_matrix"]


def rotation_matrix(rvec: np.ndarray) -> np.ndarray:
    """Rodrigues vector(s) ``(..., 3)`` -> rotation matrices ``(..., 3, 3)``."""
    rvec = np.asarray(rvec, dtype=float)
    theta = np.linalg.norm(rvec, axis=-1)[..., None, None]
    safe = np.where(theta > 1e-300, theta, 1.0)
    k = rvec[..., None, :] / safe  # (..., 1, 3)
    kx, ky, kz = k[..., 0, 0], k[..., 0, 1], k[..., 0, 2]
    zero = np.zeros_like(kx)
    kmat = np.stack(
        [np.stack([zero, -kz, ky], -1), np.stack([kz, zero, -kx], -1), np.stack([-ky, kx, zero], -1)], -2
    )
    eye = np.broadcast_to(np.eye(3), kmat.shape)
    return eye + np.sin(theta) * kmat + (1.0 - np.cos(theta)) * (kmat @ kmat)


@dataclass(frozen=True)
class Camera:
    """One calibrated camera.

    Attributes
    ----------
    name : str
    K : ndarray, shape (3, 3)
        Intrinsic matrix, pixels.
    dist : ndarray, shape (5,)
        OpenCV distortion (k1, k2, p1, p2, k3), dimensionless.
    rvec, tvec : ndarray, shape (3,)
        World -> camera rotation (Rodrigues, rad) and translation (m).
    image_size : tuple (width, height)
        Pixels.
    window : Window or None
        Flat window between the camera and the bath (world frame); None = straight rays.
    """

    name: str
    K: np.ndarray
    dist: np.ndarray
    rvec: np.ndarray
    tvec: np.ndarray
    image_size: tuple[int, int]
    meta: dict = field(default_factory=dict, compare=False)
    window: Window | None = None

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=float)
        if K.shape != (3, 3):
            raise ValueError(f"Camera {self.name!r}: K must have shape (3, 3); got {K.shape}")
        dist = np.zeros(5)
        given = np.asarray(self.dist, dtype=float).ravel()
        if given.size > 5:
            raise ValueError(f"Camera {self.name!r}: dist must have at most 5 coefficients; got {given.size}")
        dist[: given.size] = given
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", dist)
        object.__setattr__(self, "rvec", np.asarray(self.rvec, dtype=float).reshape(3))
        object.__setattr__(self, "tvec", np.asarray(self.tvec, dtype=float).reshape(3))
        object.__setattr__(self, "image_size", (int(self.image_size[0]), int(self.image_size[1])))
        if self.window is not None and not isinstance(self.window, Window):
            raise ValueError(f"Camera {self.name!r}: window must be a reconstruction.refraction.Window or None; "
                             f"got {type(self.window).__name__}")

    def without_window(self) -> "Camera":
        """The same camera with straight rays (the window ignored)."""
        return replace(self, window=None)

    @property
    def R(self) -> np.ndarray:
        """World -> camera rotation matrix, shape (3, 3)."""
        return rotation_matrix(self.rvec)

    @property
    def center(self) -> np.ndarray:
        """Optical centre in the world frame, shape (3,), metres."""
        return -self.R.T @ self.tvec

    @property
    def P(self) -> np.ndarray:
        """3x4 projection matrix K [R | t] of the undistorted pinhole model."""
        return self.K @ np.hstack([self.R, self.tvec[:, None]])

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """World points ``(..., 3)`` -> camera-frame points ``(..., 3)``."""
        return np.asarray(points, dtype=float) @ self.R.T + self.tvec

    def project(self, points: np.ndarray) -> np.ndarray:
        """Project world points ``(..., 3)`` (m) to distorted pixels ``(..., 2)``.

        Points behind the camera (z <= 0) give NaN; with a window, so do points not beyond it.
        """
        if self.window is None:
            return project_points(self.K, self.dist, self.to_camera(points))
        d, beyond = refracted_directions(self.window, self.R, self.center, points)
        return np.where(beyond[..., None], project_points(self.K, self.dist, d), np.nan)

    def rays(self, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World-frame rays of distorted pixels ``(n, 2)``: origins ``(n, 3)`` (m) and unit directions ``(n, 3)``.

        Without a window the origin is the optical centre; with one, the point where the ray
        enters the bath and the direction is the one in the bath.
        """
        xy = self.undistort_pixels(pixels)
        d = np.concatenate([xy, np.ones((xy.shape[0], 1))], axis=1) @ self.R  # camera -> world
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        if self.window is None:
            return np.broadcast_to(self.center, d.shape).copy(), d
        return window_rays(self.window, self.center, d)

    def undistort_pixels(self, pixels: np.ndarray) -> np.ndarray:
        """Distorted pixels ``(n, 2)`` -> normalised undistorted image coordinates ``(n, 2)``.

        Uses explicit termination criteria: OpenCV's default stops at ~0.01 px.
        """
        pixels = np.asarray(pixels, dtype=float).reshape(-1, 1, 2)
        if pixels.shape[0] == 0:
            return np.zeros((0, 2))
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
        out = cv2.undistortPoints(pixels, self.K, self.dist, R=None, P=None, criteria=criteria)
        return out.reshape(-1, 2)


def project_points(K: np.ndarray, dist: np.ndarray, camera_points: np.ndarray) -> np.ndarray:
    """Camera-frame points ``(..., 3)`` -> distorted pixels ``(..., 2)`` (OpenCV model).

    ``dist`` is (k1, k2, p1, p2, k3). Points with z <= 0 give NaN.
    """
    pts = np.asarray(camera_points, dtype=float)
    z = pts[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.where(z > 0, pts[..., 0] / z, np.nan)
        y = np.where(z > 0, pts[..., 1] / z, np.nan)
    k1, k2, p1, p2, k3 = np.asarray(dist, dtype=float)[:5]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    u = K[0, 0] * xd + K[0, 1] * yd + K[0, 2]
    v = K[1, 1] * yd + K[1, 2]
    return np.stack([u, v], axis=-1)
