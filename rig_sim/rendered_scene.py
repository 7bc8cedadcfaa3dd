"""The rendered end-to-end scene of tests/test_recon_rendered.py (also benchmarks/bench_reconstruction.py
--part rendered): ChArUco calibration estimated from rendered board views, then 300 rendered sphere markers
on a deforming tube through 8 steps, with a marker hidden in one step and a camera missing in another."""

from __future__ import annotations

import numpy as np

from reconstruction.calibration import calibrate_from_detections
from reconstruction.cameras import rotation_matrix
from reconstruction.targets import detect_boards
from rig_sim import camera_ring, deform_cylinder, random_marker_layout, render_markers
from rig_sim.board import board_poses, render_board_views
from rig_sim.calibration_scene import SPEC, board_corners_world, rigid_fit

N_STEPS = 8
HIDDEN_MARKER, HIDDEN_STEP = 17, 3
MISSING_CAMERA, MISSING_STEP = "cam4", 5


def rendered_scene(n_steps: int = N_STEPS):
    """(true cameras, calibration, rendered frames, images per step, (R, t) calibration world -> truth)."""
    cams = camera_ring(6, image_size=(1224, 1024), seed=3)
    rv, tv = board_poses(cams, SPEC, 16, seed=0)
    views = render_board_views(cams, SPEC, rv, tv, seed=0)
    calib = calibrate_from_detections(detect_boards(views.images, SPEC), SPEC, {c.name: c.image_size for c in cams},
                                      fix_k3=True)
    # the estimated world frame is the calibration's own; map it to the truth frame through the
    # boards only (independent of the markers), to compare with the ground truth
    est, ok = board_corners_world(calib.board_rvecs, calib.board_tvecs)
    true = np.concatenate([SPEC.object_points() @ rotation_matrix(r).T + t for r, t in zip(views.rvecs[ok], views.tvecs[ok])])
    R, t = rigid_fit(est, true)
    layout = random_marker_layout(300, seed=2)
    pts, nrm, prof = deform_cylinder(layout, 1 + 0.05 * np.arange(n_steps), 1 + 0.02 * np.arange(n_steps), bulge=0.03)
    frames, images = [], []
    for k in range(n_steps):
        p = pts[k].copy()
        if k == HIDDEN_STEP:
            p[HIDDEN_MARKER] = np.nan  # e.g. a bubble over the marker
        fr = render_markers(cams, p, nrm[k], prof[k], marker_radius=0.2e-3, seed=10 + k)
        imgs = {c.name: im for c, im in zip(cams, fr.images)}
        if k == MISSING_STEP:
            del imgs[MISSING_CAMERA]
            fr.truth.visible[4] = False
        frames.append(fr)
        images.append(imgs)
    return cams, calib, frames, images, (R, t)
