"""Benchmarks of the simulated cameras and the joint calibration.

Run: ``OMP_NUM_THREADS=1 python -m benchmarks.bench_calib [--quick]``

Prints: marker-image render time (full 2448 x 2048 frames, 300 markers), ChArUco calibration of a
6-camera ring on rendered images (intrinsic/extrinsic errors vs ground truth, 3-D error of points
on the specimen triangulated with the estimated cameras), and the real stereo data set.
"""

from __future__ import annotations

import argparse
import glob
import os
import statistics
import time

import cv2
import numpy as np

from reconstruction.calibration import calibrate_from_detections
from reconstruction.cameras import Camera, rotation_matrix
from reconstruction.targets import BoardSpec, detect_board, detect_boards
from reconstruction.triangulation import triangulate
from rig_sim.board import board_poses, render_board_views
from rig_sim.cameras import camera_ring, specimen_triangulation_error
from rig_sim.render import render_markers
from rig_sim.specimen_geometry import deform_cylinder, random_marker_layout


def _timed(fn, repeat):
    wall, cpu = [], []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return out, statistics.median(wall), statistics.median(cpu)


def bench_render(repeat: int) -> None:
    cams = camera_ring(6)
    layout = random_marker_layout(300, seed=1)
    pts, nrm, prof = deform_cylinder(layout, [1.0, 1.15], [1.0, 1.1], bulge=0.02)
    fr, wall, cpu = _timed(lambda: render_markers(cams, pts[1], nrm[1], prof[1], seed=0), repeat)
    t = fr.truth
    seen2 = (t.visible.sum(0) >= 2).mean()
    bias = np.linalg.norm(t.centroids - t.centres, axis=-1)[t.visible]
    print(f"render 6 x 2448x2048, 300 markers: median {wall / 6:.2f} s wall, {cpu / 6:.2f} s CPU per image")
    print(f"  markers visible per camera {t.visible.sum(1).tolist()}, seen by >= 2 cameras {100 * seen2:.1f} %")
    print(f"  marker image radius {np.nanmedian(t.radius_px):.1f} px; |outline centroid - projected centre| "
          f"median {np.median(bias):.5f} px, max {bias.max():.5f} px")


def _align(est_rv, est_tv, true_rv, true_tv, spec):
    obj = spec.object_points()
    ok = np.isfinite(est_rv).all(-1)
    a = np.concatenate([obj @ rotation_matrix(r).T + t for r, t in zip(est_rv[ok], est_tv[ok])])
    b = np.concatenate([obj @ rotation_matrix(r).T + t for r, t in zip(true_rv[ok], true_tv[ok])])
    ca, cb = a.mean(0), b.mean(0)
    U, _, Vt = np.linalg.svd((a - ca).T @ (b - cb))
    R = Vt.T @ np.diag([1, 1, np.sign(np.linalg.det(Vt.T @ U.T))]) @ U.T
    return R, cb - R @ ca


def bench_calibration(n_cams: int, n_views: int, size: tuple[int, int], fix_k3: bool) -> None:
    spec = BoardSpec()
    cams = camera_ring(n_cams, image_size=size, seed=1)
    rv, tv = board_poses(cams, spec, n_views, seed=0)
    t0 = time.perf_counter()
    views = render_board_views(cams, spec, rv, tv, seed=0)
    t_render = time.perf_counter() - t0
    t0 = time.perf_counter()
    det = detect_boards(views.images, spec)
    t_det = time.perf_counter() - t0
    errs = []
    for ci, c in enumerate(cams):
        for v, d in enumerate(det[c.name]):
            if len(d):
                e = d.points - views.points[ci, v, d.ids]
                errs.append(e[np.isfinite(e).all(1)])
    errs = np.concatenate(errs)
    t0 = time.perf_counter()
    res = calibrate_from_detections(det, spec, {c.name: c.image_size for c in cams}, fix_k3=fix_k3)
    t_cal = time.perf_counter() - t0
    R, t = _align(res.board_rvecs, res.board_tvecs, views.rvecs, views.tvecs, spec)
    est = []
    for c in res.cameras:
        Rn = c.R @ R.T
        est.append(Camera(c.name, c.K, c.dist, cv2.Rodrigues(Rn)[0].ravel(), c.tvec - Rn @ t, c.image_size))
    print(f"calibration {n_cams} cameras {size[0]}x{size[1]}, {n_views} ChArUco poses (fix_k3={fix_k3}): render {t_render:.1f} s, "
          f"detect {t_det:.1f} s, adjust {t_cal:.2f} s")
    print(f"  corner detection error vs truth: RMS {np.sqrt(np.mean(np.sum(errs**2, 1))):.3f} px over {len(errs)} corners")
    print(f"  RMS reprojection {res.rms_total:.4f} px (per camera {np.round(res.rms, 4).tolist()}), "
          f"{res.n_observations} observations, {res.n_outliers} outliers, converged {res.converged}")
    df = [abs(a.K[0, 0] / b.K[0, 0] - 1) for a, b in zip(est, cams)]
    dc = [np.linalg.norm(a.K[:2, 2] - b.K[:2, 2]) for a, b in zip(est, cams)]
    dr = [np.rad2deg(np.linalg.norm(cv2.Rodrigues(a.R @ b.R.T)[0])) for a, b in zip(est, cams)]
    dt = [1e6 * np.linalg.norm(a.center - b.center) for a, b in zip(est, cams)]
    print(f"  max |fx error| {100 * max(df):.3f} %, max |c error| {max(dc):.2f} px, max rotation error {max(dr):.4f} deg, "
          f"max centre error {max(dt):.1f} um")
    e, seen = specimen_triangulation_error(cams, est, n_points=3000)
    print(f"  specimen-surface points triangulated with the estimated cameras (exact pixels): 3-D error RMS "
          f"{1e6 * np.sqrt(np.mean(e**2)):.2f} um, max {1e6 * e.max():.2f} um ({seen.sum()} points)")


def bench_stereo() -> None:
    # the shared data sit beside the repository (../shared/data/...)
    root = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared", "data", "opencv-stereo-chessboard")
    spec = BoardSpec(kind="chessboard", columns=9, rows=6, square_size=1.0, subpix_half_window=5)
    ids = sorted(os.path.basename(p)[4:6] for p in glob.glob(f"{root}/left*.jpg"))
    det = {s: [detect_board(cv2.imread(f"{root}/{s}{i}.jpg", cv2.IMREAD_GRAYSCALE), spec) for i in ids] for s in ("left", "right")}
    res = calibrate_from_detections(det, spec, {"left": (640, 480), "right": (640, 480)})
    px = np.stack([np.stack([d.points for d in det[s]]) for s in ("left", "right")])
    P = triangulate(px.reshape(2, -1, 2), res.cameras).points.reshape(len(ids), 6, 9, 3)
    d = np.concatenate([np.linalg.norm(np.diff(P, axis=1), axis=-1).ravel(), np.linalg.norm(np.diff(P, axis=2), axis=-1).ravel()]) - 1
    print(f"real stereo (OpenCV samples, 13 pairs): joint BA RMS {res.rms_total:.4f} px (left {res.rms[0]:.4f}, right {res.rms[1]:.4f}); "
          f"init (calibrateCamera alone) {np.round(res.initial_rms, 4).tolist()}")
    print(f"  T = {np.round(res.cameras[1].tvec, 4).tolist()} squares; corner spacing error mean {d.mean():.5f}, std {d.std():.5f}, "
          f"max {np.abs(d).max():.4f} square")


def bench_refraction() -> None:
    from rig_sim.refraction_study import refraction_error

    print("ignoring flat-window refraction (4 cameras, window 80 mm from the lens, 3 mm glass, water; noise-free board):")
    print("  tilt [deg] | calibration RMS [px] | 3-D error RMS [um] | max [um]")
    for deg in (0, 5, 10, 20, 30):
        r = refraction_error(np.deg2rad(deg))
        print(f"  {deg:10d} | {r.calibration_rms:20.3f} | {1e6 * r.rms:18.1f} | {1e6 * r.max:8.1f}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="reduced resolution and repeats")
    args = ap.parse_args()
    bench_stereo()
    if args.quick:
        bench_render(1)
        bench_calibration(4, 24, (1224, 1024), True)
    else:
        bench_render(3)
        bench_calibration(4, 24, (1224, 1024), True)
        bench_calibration(6, 36, (2448, 2048), True)
    bench_refraction()


if __name__ == "__main__":
    main()
