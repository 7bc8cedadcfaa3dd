"""Rendered marker images: geometry of the ground truth and the image content agree."""

import numpy as np
import pytest

from rig_sim.cameras import camera_ring
from rig_sim.render import SceneStyle, render_markers
from rig_sim.sensor import SensorModel
from rig_sim.specimen_geometry import deform_cylinder, random_marker_layout


@pytest.fixture(scope="module")
def scene():
    cams = camera_ring(3, image_size=(816, 683), seed=3)
    layout = random_marker_layout(150, seed=2)
    pts, nrm, prof = deform_cylinder(layout, [1.0, 1.15], [1.0, 1.08], bulge=0.03)
    return cams, pts, nrm, prof


def test_ring_sees_specimen(scene):
    cams, pts, nrm, prof = scene
    for cam in cams:
        uv = cam.project(np.zeros((1, 3)))[0]
        assert abs(uv[0] - cam.image_size[0] / 2) < 0.1 * cam.image_size[0]
        assert abs(uv[1] - cam.image_size[1] / 2) < 0.1 * cam.image_size[1]
        # the specimen (35 mm long) spans a good part of the image width
        ends = cam.project(np.array([[0, 0, -0.0175], [0, 0, 0.0175]]))
        assert 0.45 * cam.image_size[0] < abs(ends[1, 0] - ends[0, 0]) < 0.8 * cam.image_size[0]


def test_truth_consistent(scene):
    cams, pts, nrm, prof = scene
    fr = render_markers(cams, pts[1], nrm[1], prof[1], marker_radius=0.25e-3, seed=5)
    t = fr.truth
    assert t.visible.shape == (3, 150) and t.centres.shape == (3, 150, 2)
    assert np.isnan(t.centres[~t.visible]).all() and np.isfinite(t.centres[t.visible]).all()
    # a marker is seen only if it (nearly) faces the camera: a sphere just beyond the limb still shows
    # whole; partly hidden ones are rendered but not "visible"; about half of the ring is seen per camera
    for ci, cam in enumerate(cams):
        view = cam.center - t.sphere_centres
        facing = np.einsum("ij,ij->i", view, nrm[1]) / np.linalg.norm(view, axis=1)
        assert (facing[t.visible[ci]] > -0.06).all()
        assert (facing[t.visible[ci]] > 0.1).mean() > 0.8
        partial = (t.coverage[ci] > 0) & (t.coverage[ci] < 0.999)
        assert partial.any() and not (t.visible[ci] & partial).any()
        assert 0.35 < t.visible[ci].mean() < 0.6
    # sphere centres sit one radius outside the wall
    np.testing.assert_allclose(np.linalg.norm(t.sphere_centres - pts[1], axis=1), 0.25e-3, rtol=1e-12)
    # perspective: the outline centroid differs from the projected centre, but by far less than a pixel
    bias = np.linalg.norm(t.centroids - t.centres, axis=-1)[t.visible]
    assert 1e-5 < np.max(bias) < 0.05


def test_rendered_blob_centroid_matches_truth(scene):
    """Noise-free, blur-free render: a background-subtracted grey-value centroid lands on the truth."""
    cams, pts, nrm, prof = scene
    style = SceneStyle(n_glare=0, n_debris=0, texture_contrast=0.0, background_step=1, supersample=8)
    sensor = SensorModel(full_well=1e9, read_noise=0.0, blur_sigma=0.0, bit_depth=16, vignetting=0.0, gradient=0.0)
    fr = render_markers(cams[:1], pts[0], nrm[0], prof[0], marker_radius=0.25e-3, style=style, sensor=sensor, seed=1)
    # shot noise is negligible at a full well of 1e9 electrons
    img = fr.images[0].astype(float)
    t = fr.truth
    errs = []
    for m in np.flatnonzero(t.visible[0])[:40]:
        c = t.centroids[0, m]
        r = t.radius_px[0, m]
        h = int(np.ceil(r + 4))
        u0, v0 = int(round(c[0])) - h, int(round(c[1])) - h
        win = img[v0 : v0 + 2 * h + 1, u0 : u0 + 2 * h + 1]
        V, U = np.mgrid[v0 : v0 + 2 * h + 1, u0 : u0 + 2 * h + 1]
        ring = np.hypot(U - c[0], V - c[1]) > r + 2
        if np.ptp(win[ring]) > 0.05 * np.median(win[ring]):
            continue  # near the silhouette: background not flat
        wgt = np.clip(np.median(win[ring]) - win, 0, None) * ~ring
        errs.append([np.sum(wgt * U) / wgt.sum() - c[0], np.sum(wgt * V) / wgt.sum() - c[1]])
    errs = np.array(errs)
    assert len(errs) >= 10
    assert np.sqrt(np.mean(errs**2)) < 0.02  # measured 0.012 px (shading gradient in the window)



def test_render_mechanics_simulation():
    """The renderer takes the mechanics simulator's steps: markers move with the wall, truth follows."""
    from rig_sim.imaging import render_simulated_steps, specimen_frame
    from rig_sim.materials import PAPER_PARAMETERS
    from rig_sim.simulate import simulate_test

    sim = simulate_test("neohookean", PAPER_PARAMETERS["neohookean"], stretches=(1.1,), pressures=(0.0, 16e3),
                        n_markers=120, clamped=False, seed=1)
    cams = camera_ring(2, image_size=(612, 512), seed=0)
    frames = render_simulated_steps(cams, sim, seed=3)
    assert len(frames) == sim.n_steps
    for s, fr in enumerate(frames):
        pts, nrm, prof = specimen_frame(sim, s)
        np.testing.assert_allclose(fr.truth.surface_points, pts)
        vis = fr.truth.visible
        assert vis.sum() > 60
        np.testing.assert_allclose(fr.truth.centres[vis], np.concatenate(
            [c.project(fr.truth.sphere_centres)[vis[i]] for i, c in enumerate(cams)]), atol=1e-9)
    # steps: reference, stretched, stretched + inflated: markers seen throughout move outwards when inflated
    both = frames[1].truth.visible & frames[2].truth.visible
    off = [np.abs(f.truth.centres[..., 1] - np.array([c.K[1, 2] for c in cams])[:, None])[both] for f in frames[1:]]
    assert both.sum() > 40 and np.mean(off[1] > off[0]) > 0.95
