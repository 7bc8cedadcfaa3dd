"""Camera model: batched rotations and projection agree with OpenCV."""

import cv2
import numpy as np

from reconstruction.cameras import Camera, rotation_matrix
from rig_sim.cameras import camera_ring


def test_rotation_matrix_batched_matches_rodrigues():
    r = np.random.default_rng(0).normal(size=(7, 3))
    R = rotation_matrix(r)
    for i in range(7):
        np.testing.assert_allclose(R[i], cv2.Rodrigues(r[i])[0], atol=1e-14)
    np.testing.assert_allclose(rotation_matrix(np.zeros(3)), np.eye(3))


def test_projection_matches_cv2_projectpoints():
    rng = np.random.default_rng(1)
    for cam in camera_ring(6):
        X = rng.uniform(-0.012, 0.012, (200, 3)) * np.array([1, 1, 1.6])
        ref, _ = cv2.projectPoints(X, cam.rvec, cam.tvec, cam.K, cam.dist)
        np.testing.assert_allclose(cam.project(X), ref.reshape(-1, 2), atol=1e-9)


def test_undistort_inverts_distortion():
    cam = camera_ring(1, distortion=(-0.2, 0.3, 1e-3, -1e-3, 0.05))[0]
    X = np.random.default_rng(2).uniform(-0.01, 0.01, (100, 3))
    xc = cam.to_camera(X)
    np.testing.assert_allclose(cam.undistort_pixels(cam.project(X)), xc[:, :2] / xc[:, 2:], atol=1e-12)


def test_camera_ring_geometry():
    cams = camera_ring(6, jitter=0.0)
    centres = np.array([c.center for c in cams])
    np.testing.assert_allclose(np.linalg.norm(centres[:, :2], axis=1), 0.150, rtol=1e-12)
    for c in cams:  # the optical axis passes through the origin and image x runs along the specimen axis
        np.testing.assert_allclose(c.to_camera(np.zeros(3))[:2], 0, atol=1e-12)
        np.testing.assert_allclose(c.R[0], [0, 0, 1], atol=1e-12)
    assert isinstance(cams[0], Camera) and cams[0].image_size == (2448, 2048)
