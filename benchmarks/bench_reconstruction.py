"""Benchmark of the marker reconstruction on rendered images (rig_sim).

1. Time per step for 6 cameras x 2448 x 2048 px and 300 markers: detection, correspondence,
   triangulation, tracking and the marker-centre offset, median over repeats.
2. 3-D error and completeness against ground truth versus sensor noise and defocus blur
   (true calibration, reference step + one inflated step).

Run:  OMP_NUM_THREADS=1 PYTHONPATH=. python benchmarks/bench_reconstruction.py [--quick] [--repeats 5]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.spatial import cKDTree

from reconstruction.correspondence import observed_pixels
from reconstruction.pipeline import ReconstructionSettings, detect_all, points_from_detections, track_series
from reconstruction.surface import marker_surface_points, surface_normals
from reconstruction.tracking import match_step
from reconstruction.triangulation import triangulate
from rig_sim import SensorModel, camera_ring, deform_cylinder, random_marker_layout, render_markers


def _frames(cams, sensor=SensorModel(), n_steps=2, seed=0):
    layout = random_marker_layout(300, seed=2)
    lt = 1 + 0.05 * np.arange(n_steps)
    lz = 1 + 0.02 * np.arange(n_steps)
    pts, nrm, prof = deform_cylinder(layout, lt, lz, bulge=0.03)
    return [render_markers(cams, pts[k], nrm[k], prof[k], marker_radius=0.2e-3, sensor=sensor, seed=seed + k)
            for k in range(n_steps)]


def _median_time(fn, repeats):
    times = []
    out = None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times)), out


def timing(size, repeats):
    cams = camera_ring(6, image_size=size, seed=3)
    frames = _frames(cams)
    settings = ReconstructionSettings(marker_diameter=0.4e-3, specimen_radius=0.010)
    imgs = [{c.name: im for c, im in zip(cams, fr.images)} for fr in frames]
    t_det, found = _median_time(lambda: detect_all(imgs[1], cams, settings), repeats)
    dets = [d.centres for d in found]
    ref = points_from_detections([d.centres for d in detect_all(imgs[0], cams, settings)], cams, settings)
    t_corr, step = _median_time(lambda: points_from_detections(dets, cams, settings), repeats)
    px = observed_pixels(step.detections, step.observations)
    t_tri, _ = _median_time(lambda: triangulate(px, cams), repeats)
    t_trk, _ = _median_time(lambda: match_step(ref.centres, step.centres), repeats)
    t_srf, _ = _median_time(lambda: marker_surface_points(step.centres, 0.2e-3, surface_normals(step.centres)), repeats)
    n_det = sum(len(d) for d in dets)
    print(f"\n## Time per step: 6 cameras x {size[0]}x{size[1]} px, 300 markers "
          f"({n_det} detections, {step.centres.shape[0]} points), median of {repeats}\n")
    print("| stage | time [ms] |\n|---|---|")
    rows = [("detection (6 images)", t_det), ("correspondence (incl. candidate triangulation, bootstrap)", t_corr),
            ("triangulation (final N-view DLT + Gauss-Newton + covariance)", t_tri), ("tracking (match_step)", t_trk),
            ("marker-centre offset (normals + offset)", t_srf)]
    for name, t in rows:
        print(f"| {name} | {t * 1e3:.0f} |")
    print(f"| **total** | **{sum(t for _, t in rows) * 1e3:.0f}** |")


def accuracy(size, noise_levels, blurs):
    cams = camera_ring(6, image_size=size, seed=3)
    settings = ReconstructionSettings(marker_diameter=0.4e-3, specimen_radius=0.010)
    print(f"\n## 3-D error vs noise and blur: 6 cameras x {size[0]}x{size[1]} px, 300 markers, true calibration,"
          " steps 0 and 1 (5 % inflation, 2 % extension)\n")
    print("| full well [e-] | read noise [e-] | blur sigma [px] | centroid RMS [px] | 3-D RMS [um] | 3-D p99 [um] "
          "| surface RMS [um] | completeness [%] | wrong ids |")
    print("|---|---|---|---|---|---|---|---|---|")
    for full_well, read in noise_levels:
        for blur in blurs:
            sensor = SensorModel(full_well=full_well, read_noise=read, blur_sigma=blur)
            frames = _frames(cams, sensor, seed=7)
            imgs = [{c.name: im for c, im in zip(cams, fr.images)} for fr in frames]
            stats = [detect_all(im, cams, settings) for im in imgs]
            cen_err = []
            for fr, st in zip(frames, stats):
                for c, d in enumerate(st):
                    t = fr.truth.centroids[c][fr.truth.visible[c]]
                    dd = cKDTree(d.centres).query(t)[0]
                    cen_err.append(dd[dd < 1.0])
            res = track_series([[d.centres for d in st] for st in stats], cams, settings)
            tc = np.array([fr.truth.sphere_centres for fr in frames])
            ts = np.array([fr.truth.surface_points for fr in frames])
            gt = cKDTree(tc[0]).query(res.centres[0])[1]
            errs, serrs, comp, wrong = [], [], [], 0
            for k in range(len(frames)):
                v = res.visible[k]
                nn = cKDTree(tc[k]).query(res.centres[k, v])[1]
                wrong += int((nn != gt[v]).sum())
                errs.append(np.linalg.norm(res.centres[k, v] - tc[k][gt[v]], axis=1))
                serrs.append(np.linalg.norm(res.positions[k, v] - ts[k][gt[v]], axis=1))
                seen2 = frames[k].truth.visible.sum(axis=0) >= 2
                right = np.zeros(tc.shape[1], bool)
                right[gt[v][nn == gt[v]]] = True
                comp.append(right[seen2].mean())
            e, se, ce = np.concatenate(errs), np.concatenate(serrs), np.concatenate(cen_err)
            print(f"| {full_well:.0f} | {read:.0f} | {blur:.1f} | {np.sqrt(np.mean(ce**2)):.3f} | "
                  f"{np.sqrt(np.mean(e**2)) * 1e6:.2f} | {np.percentile(e, 99) * 1e6:.1f} | "
                  f"{np.sqrt(np.mean(se**2)) * 1e6:.2f} | {100 * min(comp):.1f} | {wrong} |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="half resolution, fewer repeats and configurations")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--skip-accuracy", action="store_true")
    args = ap.parse_args()
    size = (1224, 1024) if args.quick else (2448, 2048)
    timing(size, 2 if args.quick else args.repeats)
    if not args.skip_accuracy:
        noise = [(12000, 6)] if args.quick else [(30000, 3), (12000, 6), (3000, 12)]
        blurs = [0.8] if args.quick else [0.5, 1.2, 2.5]
        accuracy(size, noise, blurs)


if __name__ == "__main__":
    main()
