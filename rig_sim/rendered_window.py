"""Markers rendered through tilted flat windows (rig_sim), detected, and triangulated with and without the window."""

import dataclasses

import numpy as np
from scipy.spatial import cKDTree

from reconstruction.detection import detect_markers
from reconstruction.triangulation import triangulate
from rig_sim.cameras import camera_ring
from rig_sim.refraction import tilted_window
from rig_sim.render import SceneStyle, render_markers
from rig_sim.specimen_geometry import deform_cylinder, random_marker_layout


def rendered_window_errors(image_size=(816, 683), n_cameras=4, n_markers=100, tilt_deg=10.0) -> dict:
    """3-D RMS error (m) of triangulated detections against the true sphere centres, with the window
    model and with straight rays; detections are associated with markers through the truth (< 1 px)."""
    cams = camera_ring(n_cameras, image_size=image_size, seed=0)
    pts, nrm, prof = deform_cylinder(random_marker_layout(n_markers, seed=4), [1.0], [1.0])
    wins = [tilted_window(np.deg2rad(tilt_deg), azimuth=0.7 * i) for i in range(n_cameras)]
    fr = render_markers(cams, pts[0], nrm[0], prof[0], style=SceneStyle(n_glare=0, n_debris=0), seed=1, windows=wins)
    truth = fr.truth
    px = np.full((n_cameras, n_markers, 2), np.nan)
    for i, im in enumerate(fr.images):
        found = detect_markers(im).centres
        vis = np.flatnonzero(truth.visible[i])
        dist, j = cKDTree(found).query(truth.centroids[i, vis])
        px[i, vis[dist < 1.0]] = found[j[dist < 1.0]]
    windowed = [dataclasses.replace(c, window=w.to_window(c)) for c, w in zip(cams, wins)]
    out = {}
    for label, cs in (("window", windowed), ("straight", cams)):
        tri = triangulate(px, cs)
        good = tri.n_views >= 2
        out[label] = float(np.sqrt(np.mean(np.sum((tri.points[good] - truth.sphere_centres[good]) ** 2, axis=1))))
        out[f"{label}_n"] = int(good.sum())
    return out
