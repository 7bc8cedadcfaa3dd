"""The flat-window camera model: identities and invariants (no data files)."""

import dataclasses

import numpy as np
import pytest

from reconstruction.cameras import Camera
from reconstruction.refraction import Window
from reconstruction.triangulation import triangulate


def _camera(window=None):
    K = np.array([[2000.0, 0, 640], [0, 2000.0, 512], [0, 0, 1]])
    return Camera("c", K, [0.01, 0, 0, 0, 0], [0.1, -0.2, 0.05], [0.002, -0.001, 0.3], (1280, 1024), window=window)


def test_void_window_changes_nothing_and_real_one_obeys_snell():
    X = np.random.default_rng(0).uniform(-0.02, 0.02, (200, 3))
    plain = _camera()
    n = plain.R[2]  # window square to the optical axis, 0.1 m in front of the camera
    void = Window(n, n @ plain.center + 0.1, (0.006,), (1.0,), 1.0)
    np.testing.assert_allclose(_camera(void).project(X), plain.project(X), atol=1e-9)
    water = _camera(dataclasses.replace(void, indices=(1.52,), n_bath=1.333))
    px = water.project(X)
    o, d = water.rays(px)  # the ray in the bath through the projected pixel passes through the point
    v = X - o
    np.testing.assert_allclose(np.linalg.norm(v - np.sum(v * d, 1)[:, None] * d, axis=1), 0, atol=1e-11)
    # Snell's invariant: sin(angle to the normal) * n is the same in air and in water
    xy = water.undistort_pixels(px[:1])[0]
    air = np.array([xy[0], xy[1], 1.0]) @ water.R  # the pixel's ray in air, world frame
    sin_air = np.linalg.norm(np.cross(air / np.linalg.norm(air), n))
    assert np.isclose(sin_air * 1.0, np.linalg.norm(np.cross(d[0], n)) * 1.333, rtol=1e-9)


def test_points_not_in_the_bath_are_nan_and_triangulation_recovers_points():
    cams = []
    for k, ang in enumerate((-0.3, 0.3, 0.0)):
        R = np.array([[np.cos(ang), 0, -np.sin(ang)], [0, 1, 0], [np.sin(ang), 0, np.cos(ang)]])
        import cv2

        c = Camera(f"c{k}", [[2000, 0, 640], [0, 2000, 512], [0, 0, 1]], np.zeros(5), cv2.Rodrigues(R)[0], [0, 0, 0.3], (1280, 1024))
        cams.append(dataclasses.replace(c, window=Window([0, 0, 1.0], -0.2, (0.005,), (1.5,), 1.333)))
    assert np.all(np.isnan(cams[0].project(np.array([[0, 0, -0.25]]))))  # in the air, before the window
    X = np.random.default_rng(1).uniform(-0.01, 0.01, (50, 3))
    tri = triangulate(np.stack([c.project(X) for c in cams]), cams)
    np.testing.assert_allclose(tri.points, X, atol=1e-10)


def test_window_validation_names_the_parameter():
    with pytest.raises(ValueError, match="normal"):
        Window([0, 0, 0], 0.1)
    with pytest.raises(ValueError, match="same length"):
        Window([0, 0, 1], 0.1, (0.001, 0.002), (1.5,))
    with pytest.raises(ValueError, match="indices must be >= 1"):
        Window([0, 0, 1], 0.1, (0.001,), (0.5,))
