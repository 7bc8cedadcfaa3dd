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


def test_render_through_window():
    """Rendering through a window: a window of index 1 changes nothing; a real one magnifies, truth follows."""
    from rig_sim.refraction import FlatWindow
    from rig_sim.render import SceneStyle, render_markers
    from rig_sim.specimen_geometry import deform_cylinder, random_marker_layout

    cams = camera_ring(2, image_size=(612, 512), focal_length=0.018, seed=0)
    pts, nrm, prof = deform_cylinder(random_marker_layout(100, seed=4), [1.0], [1.0])
    style = SceneStyle(n_glare=0, n_debris=0)
    plain = render_markers(cams, pts[0], nrm[0], prof[0], style=style, seed=1).truth
    void = FlatWindow(np.array([0, 0, 1.0]), n_glass=1.0, n_water=1.0)
    same = render_markers(cams, pts[0], nrm[0], prof[0], style=style, seed=1, windows=[void, void]).truth
    np.testing.assert_array_equal(same.visible, plain.visible)
    np.testing.assert_allclose(same.centres[same.visible], plain.centres[plain.visible], atol=1e-9)
    np.testing.assert_allclose(same.centroids[same.visible], plain.centroids[plain.visible], atol=1e-6)
    wins = [tilted_window(np.deg2rad(10)), tilted_window(np.deg2rad(5), azimuth=1.0)]
    fr = render_markers(cams, pts[0], nrm[0], prof[0], style=style, seed=1, windows=wins)
    t = fr.truth
    assert t.visible.sum() > 60
    for i, (cam, win) in enumerate(zip(cams, wins)):
        np.testing.assert_allclose(t.centres[i, t.visible[i]], project_refracted(cam, win, t.sphere_centres[t.visible[i]]))
    assert np.nanmedian(t.radius_px) > 1.08 * np.nanmedian(plain.radius_px)  # water magnifies (measured 1.12)
    # the rendered blobs sit on the truth: the pixel at the refracted centroid is dark
    img = fr.images[0].astype(float)
    tissue = np.percentile(img, 90)
    for m in np.flatnonzero(t.visible[0])[:10]:
        u, v = np.rint(t.centroids[0, m]).astype(int)
        assert img[v, u] < 0.4 * tissue


def test_board_through_window_detected_at_truth():
    from reconstruction.targets import BoardSpec, detect_board
    from rig_sim.board import board_poses, render_board_views

    cams = camera_ring(2, image_size=(816, 683), focal_length=0.018, seed=1)
    spec = BoardSpec()
    rv, tv = board_poses(cams, spec, 2, seed=0, offset=1e-3)
    views = render_board_views(cams, spec, rv, tv, seed=0, windows=[tilted_window(np.deg2rad(10))] * 2)
    errs = []
    for ci, c in enumerate(cams):
        for v in range(2):
            det = detect_board(views.images[c.name][v], spec)
            if len(det) and views.seen[ci, v]:
                errs.append(det.points - views.points[ci, v, det.ids])
    assert errs
    errs = np.concatenate(errs)
    assert np.sqrt(np.mean(np.sum(errs**2, 1))) < 0.12


def test_refracted_outline_centroid_matches_supersampled_image():
    from rig_sim.render import _marker_coverage, _polygon_centroid, _refracted_outline
    from rig_sim.specimen_geometry import deform_cylinder, random_marker_layout

    cam = camera_ring(1, image_size=(1224, 1024))[0]
    pts, nrm, prof = deform_cylinder(random_marker_layout(300, seed=1), [1.0], [1.0])
    c = pts[0] + 0.2e-3 * nrm[0]
    face = np.sum((cam.center - c) * nrm[0], 1) > 0.5 * np.linalg.norm(cam.center - c, axis=1)
    win = tilted_window(np.deg2rad(10))
    exact, area = _polygon_centroid(_refracted_outline(cam, win, c[face][:30], 0.2e-3))
    _, _, _, sampled, sampled_area = _marker_coverage(cam, c[face][:30], 0.2e-3, prof[0], pts[0][face][:30, 2], 12, 8, win)
    assert np.sqrt(np.mean((sampled - exact) ** 2)) < 0.006  # 8x8 samples per pixel: measured 0.0027 px
    np.testing.assert_allclose(sampled_area, area, rtol=5e-3)
