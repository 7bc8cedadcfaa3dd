"""Flat-window refraction: exact forward/backward consistency, and the cost of ignoring it."""

import numpy as np

from rig_sim.cameras import camera_ring
from rig_sim.refraction import project_refracted, rays_in_water, tilted_window
from rig_sim.refraction_study import refraction_error


def test_refracted_projection_lies_on_refracted_ray():
    cam = camera_ring(1)[0]
    win = tilted_window(np.deg2rad(20), azimuth=0.3)
    X = np.random.default_rng(0).uniform(-0.01, 0.01, (50, 3))
    px = project_refracted(cam, win, X)
    o, d = rays_in_water(cam, win, cam.undistort_pixels(px))
    v = cam.to_camera(X) - o
    np.testing.assert_allclose(np.linalg.norm(v - np.sum(v * d, 1)[:, None] * d, axis=1), 0, atol=1e-12)
    # water magnifies: points appear further from the image centre than without the window
    c = cam.K[:2, 2]
    assert np.median(np.linalg.norm(px - c, axis=1) / np.linalg.norm(cam.project(X) - c, axis=1)) > 1.2


def test_ignoring_refraction_error_grows_with_window_tilt():
    """A pinhole + distortion calibration through the window absorbs a square-on window, not a tilted one."""
    e0 = refraction_error(0.0, n_views=24)
    e10 = refraction_error(np.deg2rad(10), n_views=24)
    assert e0.rms < 2e-6  # measured 0.9 um
    assert 3e-6 < e10.rms < 10e-6  # measured 5.5 um
    assert e10.calibration_rms > 3 * e0.calibration_rms
