"""Benchmark of the marker reconstruction on rendered images (rig_sim).

1. ``--part timing``: time per step for 6 cameras x 2448 x 2048 px and 300 markers: detection
   (serial / threads / processes, whole images / guided by the tracker), correspondence,
   triangulation, tracking and the marker-centre offset, median over repeats, all in one run; and
   the reference: reading the images from HDF5 plus one threshold / connected-components pass;
   then (also alone: ``--part step``) the goal figures: one loaded step as the pipeline runs it
   (guided detection in threads + the tracker's correspondence and tracking) and its ratio to
   that reference, measured alternately, median and max over the repeats.
   ``--part profile``: cProfile of that step in one thread.
2. ``--part rendered``: the end-to-end figures of tests/test_recon_rendered.py, before (serial
   whole-image detection) and after (threads, guided detection).
3. ``--part accuracy``: 3-D error and completeness against ground truth versus sensor noise and
   defocus blur (true calibration, reference step + one inflated step).

Run:  OMP_NUM_THREADS=1 python -m benchmarks.bench_reconstruction [--quick] [--repeats 5]
      [--part timing|step|profile|rendered|accuracy|all]
"""

from __future__ import annotations

import argparse
import copy
import os
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import cv2
import h5py
import numpy as np
from scipy.spatial import cKDTree

from reconstruction.correspondence import observed_pixels
from reconstruction.detection import detect_markers
from reconstruction.pipeline import (
    ReconstructionSettings,
    SeriesTracker,
    convergence_point,
    detect_all,
    detect_step,
    expected_diameter_px,
    points_from_detections,
    reconstruct_series,
    track_series,
)
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


CPU = {}  # wall-time median -> CPU-time median of the same calls (this process, all threads)


def _median_time(fn, repeats):
    times, cpus = [], []
    out = None
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        out = fn()
        times.append(time.perf_counter() - t)
        cpus.append(time.process_time() - c)
    wall = float(np.median(times))
    CPU[wall] = float(np.median(cpus))
    return wall, out


def _write_h5(path, cams, images):
    """The step's images stored as a session stores them (one gzip-1 chunk per frame)."""
    with h5py.File(path, "w") as f:
        for cam, img in zip(cams, images):
            f.create_dataset(cam.name, data=img[None], chunks=(1, *img.shape), compression="gzip", compression_opts=1)


def _read_h5(path, cams):
    with h5py.File(path, "r") as f:
        return {c.name: f[c.name][0] for c in cams}


def _threshold_cc(images):
    """The floor of any detection: one global threshold and one connected-components pass per image."""
    for img in images.values():
        _, mask = cv2.threshold(img, 0, 1, cv2.THRESH_BINARY_INV | cv2.THRESH_OTSU)
        cv2.connectedComponentsWithStats(mask, connectivity=8)


def _detect_one(args):
    img, kw = args
    return detect_markers(img, **kw)


def _process_pool_detect(pool, images, cams, settings):
    target = convergence_point(cams)
    jobs = []
    for c in cams:
        d = expected_diameter_px(c, settings.marker_diameter, target)
        jobs.append((images[c.name], {"diameter_range": (max(0.45 * d, 2.0), max(1.7 * d, 4.0))}))
    return list(pool.map(_detect_one, jobs))


def timing(size, repeats):
    cams = camera_ring(6, image_size=size, seed=3)
    frames = _frames(cams, n_steps=3)
    serial = ReconstructionSettings(marker_diameter=0.4e-3, specimen_radius=0.010, workers=1, guided_detection=False)
    after = ReconstructionSettings(marker_diameter=0.4e-3, specimen_radius=0.010)
    threads = ReconstructionSettings(marker_diameter=0.4e-3, specimen_radius=0.010, guided_detection=False)
    imgs = [{c.name: im for c, im in zip(cams, fr.images)} for fr in frames]
    # tracker after the reference and the first loaded step: step 2 is the timed one
    tracker = SeriesTracker(cams, after)
    for k in range(2):
        found = detect_step(imgs[k], cams, after, tracker if k else None)
        tracker.add([d.centres for d in found], quality=[d.quality for d in found], found=found)
    step = imgs[2]
    with tempfile.TemporaryDirectory() as tmp:
        h5 = Path(tmp) / "step.h5"
        _write_h5(h5, cams, frames[2].images)
        t_read, _ = _median_time(lambda: _read_h5(h5, cams), repeats)
        t_floor, _ = _median_time(lambda: _threshold_cc(_read_h5(h5, cams)), repeats)
    t_serial, found = _median_time(lambda: detect_all(step, cams, serial), repeats)
    t_threads, _ = _median_time(lambda: detect_all(step, cams, threads), repeats)
    with ProcessPoolExecutor(max_workers=2) as pool:
        _process_pool_detect(pool, step, cams, serial)  # start the workers
        t_procs, _ = _median_time(lambda: _process_pool_detect(pool, step, cams, serial), repeats)
    t_guided, guided = _median_time(lambda: detect_step(step, cams, after, tracker), repeats)
    dets = [d.centres for d in found]
    ref = points_from_detections([d.centres for d in detect_all(imgs[0], cams, serial)], cams, serial)
    t_corr, pts = _median_time(lambda: points_from_detections(dets, cams, serial), repeats)
    px = observed_pixels(pts.detections, pts.observations)
    t_tri, _ = _median_time(lambda: triangulate(px, cams), repeats)
    t_trk, _ = _median_time(lambda: match_step(ref.centres, pts.centres), repeats)
    t_srf, _ = _median_time(lambda: marker_surface_points(pts.centres, 0.2e-3, surface_normals(pts.centres)), repeats)
    rest = t_corr + t_tri + t_trk + t_srf
    print(f"\n## Time per step: 6 cameras x {size[0]}x{size[1]} px, 300 markers (a loaded step after the reference; "
          f"{sum(len(d) for d in dets)} detections full-image, {sum(len(d) for d in guided)} guided, "
          f"{pts.centres.shape[0]} points), median of {repeats}, all rows in one run\n")
    print("| stage | wall time [ms] | CPU time [ms] |\n|---|---|---|")
    rows = [("detection, serial, whole images (before)", t_serial),
            ("detection, 2 threads, whole images", t_threads),
            ("detection, 2 processes (persistent pool, images pickled), whole images", t_procs),
            ("detection, 2 threads, guided by the tracker (after)", t_guided),
            ("correspondence (incl. candidate triangulation, bootstrap)", t_corr),
            ("triangulation (final N-view DLT + Gauss-Newton + covariance)", t_tri), ("tracking (match_step)", t_trk),
            ("marker-centre offset (normals + offset)", t_srf),
            ("**total before** (serial whole-image detection + the rest)", t_serial + rest),
            ("**total after** (threads + guided detection + the rest)", t_guided + rest),
            ("reference: read the 6 images from HDF5 (gzip 1, as a session)", t_read),
            ("reference: read + one Otsu threshold + connected components per image, serial", t_floor)]
    for name, t in rows:
        cpu = CPU.get(t, sum(CPU.get(x, np.nan) for x in (t_corr, t_tri, t_trk, t_srf)) +
                      CPU.get(t_serial if "before" in name else t_guided, np.nan))
        print(f"| {name} | {t * 1e3:.0f} | {cpu * 1e3:.0f} |")
    print(f"\n(process pool: CPU time of the parent only.) Load average at the end: {os.getloadavg()[0]:.1f} "
          f"on {os.cpu_count()} cores.")
    print(f"\nratio total after / reference (read + threshold + components): {(t_guided + rest) / t_floor:.2f}; "
          f"detection speed-up: threads {t_serial / t_threads:.2f}x, processes {t_serial / t_procs:.2f}x, "
          f"threads + guided {t_serial / t_guided:.2f}x")
    step_timing(cams, frames[2].images, step, tracker, after, repeats)


def _one_step(step, cams, settings, tracker):
    """One loaded step as reconstruct_series runs it (guided detection in threads, then the
    tracker's correspondence + tracking), on a copy of ``tracker``: (detection s, add s)."""
    tr = copy.deepcopy(tracker)
    t0 = time.perf_counter()
    found = detect_step(step, cams, settings, tr)
    t1 = time.perf_counter()
    tr.add([d.centres for d in found], quality=[d.quality for d in found], found=found)
    return t1 - t0, time.perf_counter() - t1


def step_timing(cams, images, step, tracker, settings, repeats):
    """The goal figures: wall time of one step and its ratio to the reference (read the images
    from HDF5 + one Otsu threshold + connected components per image), the two measured
    alternately, one ratio per repeat."""
    with tempfile.TemporaryDirectory() as tmp:
        h5 = Path(tmp) / "step.h5"
        _write_h5(h5, cams, images)
        _one_step(step, cams, settings, tracker)  # warm-up
        rows = []
        for _ in range(repeats):
            t = time.perf_counter()
            _threshold_cc(_read_h5(h5, cams))
            ref = time.perf_counter() - t
            c = time.process_time()
            det, add = _one_step(step, cams, settings, tracker)
            rows.append((ref, det, add, time.process_time() - c))
    ref, det, add, cpu = np.array(rows).T
    tot = det + add
    ratio = tot / ref
    print(f"\n## One loaded step as the pipeline runs it (detect_step: {settings.workers or os.cpu_count()} threads, "
          f"guided; then SeriesTracker.add: correspondence + tracking), {repeats} repeats alternating with the "
          "reference\n")
    print("| figure | median | max |\n|---|---|---|")
    for name, v in (("detection (detect_step) [ms]", det * 1e3), ("correspondence + tracking (add) [ms]", add * 1e3),
                    ("**step** [ms]", tot * 1e3), ("step, CPU time [ms]", cpu * 1e3),
                    ("reference: read + threshold + components [ms]", ref * 1e3),
                    ("**ratio step / reference**", ratio)):
        fmt = ".2f" if "ratio" in name else ".0f"
        print(f"| {name} | {np.median(v):{fmt}} | {np.max(v):{fmt}} |")
    print(f"\nLoad average at the end: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores.")


def profile(size):
    """cProfile of one loaded step (as ``_one_step``, one thread so that the profile sees all the
    work), the 25 functions with the largest cumulative time, and the per-stage wall times."""
    import cProfile
    import pstats

    cams = camera_ring(6, image_size=size, seed=3)
    frames = _frames(cams, n_steps=3)
    one = ReconstructionSettings(marker_diameter=0.4e-3, specimen_radius=0.010, workers=1)
    imgs = [{c.name: im for c, im in zip(cams, fr.images)} for fr in frames]
    tracker = SeriesTracker(cams, one)
    for k in range(2):
        found = detect_step(imgs[k], cams, one, tracker if k else None)
        tracker.add([d.centres for d in found], quality=[d.quality for d in found], found=found)
    det, add = _one_step(imgs[2], cams, one, tracker)
    print(f"\n## Profile of one loaded step, one thread: detection {det * 1e3:.0f} ms, correspondence + tracking "
          f"{add * 1e3:.0f} ms (wall)\n")
    prof = cProfile.Profile()
    prof.runcall(_one_step, imgs[2], cams, one, tracker)
    pstats.Stats(prof, stream=sys.stdout).sort_stats("cumulative").print_stats(25)


def step_only(size, repeats):
    """Only the goal figures (:func:`step_timing`), without the detection variants of :func:`timing`."""
    cams = camera_ring(6, image_size=size, seed=3)
    frames = _frames(cams, n_steps=3)
    after = ReconstructionSettings(marker_diameter=0.4e-3, specimen_radius=0.010)
    imgs = [{c.name: im for c, im in zip(cams, fr.images)} for fr in frames]
    tracker = SeriesTracker(cams, after)
    for k in range(2):
        found = detect_step(imgs[k], cams, after, tracker if k else None)
        tracker.add([d.centres for d in found], quality=[d.quality for d in found], found=found)
    step_timing(cams, frames[2].images, imgs[2], tracker, after, repeats)


def rendered(n_steps=8):
    """The end-to-end figures of tests/test_recon_rendered.py (estimated calibration, 1224 x 1024, glare,
    debris, a hidden marker, a missing camera), before (serial whole-image detection) and after."""
    from rig_sim.rendered_scene import rendered_scene

    cams, calib, frames, images, (R, t) = rendered_scene(n_steps)
    print("\n## Rendered end to end (tests/test_recon_rendered.py: estimated calibration, 6 cameras 1224x1024, "
          "300 markers, 8 steps, glare/debris, a hidden marker, camera 4 missing in step 5)\n")
    print("| detection | time, 8 steps [s] | 3-D RMS [um] | max [um] | completeness, worst step except 5 [%] | "
          "step 5 [%] | swaps | wrong ids |\n|---|---|---|---|---|---|---|---|")
    for label, settings in (("serial, whole images (before)", ReconstructionSettings(
            marker_diameter=0.4e-3, specimen_radius=0.010, workers=1, guided_detection=False)),
            ("2 threads, guided (after)", ReconstructionSettings(marker_diameter=0.4e-3, specimen_radius=0.010))):
        t0 = time.perf_counter()
        res = reconstruct_series(images, calib.cameras, settings)
        dt = time.perf_counter() - t0
        centres = res.centres @ R.T + t
        truth = np.array([f.truth.sphere_centres for f in frames])
        gt = cKDTree(truth[0]).query(centres[0])[1]
        errs, comp, wrong = [], [], 0
        for k in range(n_steps):
            v = res.visible[k]
            fin = np.flatnonzero(np.isfinite(truth[k]).all(1))
            nearest = fin[cKDTree(truth[k][fin]).query(centres[k, v])[1]]
            wrong += int((nearest != gt[v]).sum())
            seen2 = frames[k].truth.visible.sum(axis=0) >= 2
            right = np.zeros(truth.shape[1], bool)
            right[gt[v][nearest == gt[v]]] = True
            comp.append(right[seen2].mean())
            errs.append(np.linalg.norm(centres[k, v] - truth[k][gt[v]], axis=1))
        e = np.concatenate(errs)
        print(f"| {label} | {dt:.1f} | {np.sqrt(np.mean(e**2)) * 1e6:.2f} | {e.max() * 1e6:.1f} | "
              f"{100 * min(c for k, c in enumerate(comp) if k != 5):.1f} | {100 * comp[5]:.1f} | "
              f"{int(res.diagnostics['swaps'].sum())} | {wrong} |", flush=True)


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
    ap.add_argument("--part", choices=("timing", "step", "profile", "rendered", "accuracy", "all"), default="all")
    args = ap.parse_args()
    size = (1224, 1024) if args.quick else (2448, 2048)
    if args.part in ("timing", "all"):
        timing(size, 2 if args.quick else args.repeats)
    if args.part == "step":
        step_only(size, args.repeats)
    if args.part == "profile":
        profile(size)
    if args.part in ("rendered", "all"):
        rendered()
    if args.part in ("accuracy", "all"):
        noise = [(12000, 6)] if args.quick else [(30000, 3), (12000, 6), (3000, 12)]
        blurs = [0.8] if args.quick else [0.5, 1.2, 2.5]
        accuracy(size, noise, blurs)


if __name__ == "__main__":
    main()
