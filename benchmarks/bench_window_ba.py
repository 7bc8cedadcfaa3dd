"""The window refined in the board bundle adjustment, on rig_sim's renderings through a tank wall (issue 14).

Three cameras look through one 6 mm glass wall (90 mm from camera 0, tilted 2 deg) into water at a ChArUco board
at 170/200/230 mm with tilts up to 30 deg (``rig_sim/window_boards.py``); the views are rendered by rig_sim through
the window, the board detected, the cameras calibrated jointly four ways:

- ``nominal``: the true window, fixed;
- ``refined``: the window refined from a wrong start (plane 2 mm off, normal 2 deg off);
- ``wrong``: that wrong start kept fixed;
- ``straight``: no window (straight rays: the refraction absorbed by the pinhole and distortion, as before).

Then 2000 points of a tube (radius 10 mm at 200 mm, in the water) are projected exactly through the true windows
into the true cameras and triangulated with each calibration; the 3-D error is against the truth in the
calibration's own gauge (camera 0's frame, no alignment: ``rms_3d_um``) and after the best rigid motion
(``rms_3d_aligned_um``: the shape error). Prints a table, or one JSON object with ``--json``.

    python -m benchmarks.bench_window_ba [--views 18] [--json]
    python -m benchmarks.bench_window_ba --exact-noise 0.1   # exact projections + noise instead
"""

from __future__ import annotations

import argparse
import json
import logging
import time

import numpy as np


from rig_sim.calibration_scene import rigid_fit
from rig_sim.window_boards import board_views, exact_views, render_views, specimen_points, wall_rig, wrong_window
from reconstruction.calibration import calibrate_cameras, calibrate_from_detections
from reconstruction.targets import BoardSpec, detect_boards
from reconstruction.triangulation import triangulate


def _error_3d(est, truth, points) -> dict:
    """RMS and max 3-D error (m) of ``points`` projected exactly by ``truth`` and triangulated with ``est``."""
    px = np.stack([c.project(points) for c in truth])
    for c, cam in enumerate(truth):
        w, h = cam.image_size
        bad = ~(np.isfinite(px[c]).all(1) & (px[c] > 0).all(1) & (px[c, :, 0] < w - 1) & (px[c, :, 1] < h - 1))
        px[c, bad] = np.nan
    tri = triangulate(px, est)
    ok = tri.n_views >= 2
    e = np.linalg.norm(tri.points[ok] - points[ok], axis=1)
    R, t = rigid_fit(tri.points[ok], points[ok])
    ea = np.linalg.norm(tri.points[ok] @ R.T + t - points[ok], axis=1)
    return {"rms_3d_um": float(1e6 * np.sqrt(np.mean(e**2))), "max_3d_um": float(1e6 * e.max()),
            "rms_3d_aligned_um": float(1e6 * np.sqrt(np.mean(ea**2))), "max_3d_aligned_um": float(1e6 * ea.max()),
            "n_points": int(ok.sum())}


def run(n_views: int = 18) -> dict:
    spec = BoardSpec()
    cams = wall_rig()
    truth_win = cams[0].window
    rv, tv = board_views(n_views, extent=spec.extent)
    t0 = time.perf_counter()
    views = render_views(cams, spec, rv, tv)
    det = detect_boards(views.images, spec)
    sizes = {c.name: c.image_size for c in cams}
    out = {"views": n_views, "render_detect_s": time.perf_counter() - t0,
           "corners_per_camera": {c: int(sum(len(d) for d in det[c])) for c in det}}
    points = specimen_points()
    cases = {"nominal": dict(windows=truth_win), "refined": dict(windows=wrong_window(truth_win), refine_window=True),
             "wrong": dict(windows=wrong_window(truth_win)), "straight": {}}
    for label, kw in cases.items():
        t0 = time.perf_counter()
        res = calibrate_from_detections(det, spec, sizes, **kw)
        row = {"rms_px": float(res.rms_total), "seconds": time.perf_counter() - t0, **_error_3d(res.cameras, cams, points)}
        fit = res.window_fit
        if fit is not None:
            got = fit.refined[0]
            row.update(well_posed=fit.well_posed, plane_error_mm=1e3 * (got.offset - truth_win.offset),
                       plane_std_mm=1e3 * float(fit.offset_std[0]),
                       normal_error_deg=float(np.rad2deg(np.arccos(np.clip(got.normal @ truth_win.normal, -1, 1)))),
                       normal_std_deg=float(np.rad2deg(fit.normal_std[0])), max_correlation=float(fit.max_correlation.max()),
                       message=fit.message)
        out[label] = row
    return out


def run_exact(noise_px: float, n_views: int = 18) -> dict:
    """Exact projections (8 x 6 corners, 5 mm) with Gaussian pixel noise: the window refined from 2 mm / 2 deg off,
    for the shared wall with the board at three depths, at one depth, and for one window per camera."""
    obj = np.array([[i * 5e-3, j * 5e-3, 0] for j in range(6) for i in range(8)])
    out = {}
    for label, per_camera, depths in (("shared_3_depths", False, (0.17, 0.2, 0.23)), ("shared_1_depth", False, (0.2,)),
                                      ("per_camera_3_depths", True, (0.17, 0.2, 0.23))):
        cams = wall_rig(per_camera=per_camera)
        rv, tv = board_views(n_views, depths=depths, extent=(0.035, 0.025))
        uv = exact_views(cams, obj, rv, tv, noise_px=noise_px, seed=1)
        res = calibrate_cameras(uv, obj, [c.image_size for c in cams], [c.name for c in cams],
                                windows=[wrong_window(c.window) for c in cams], refine_window=True)
        fit = res.window_fit
        truth = [cams[[c.name for c in cams].index(g[0])].window for g in fit.cameras]
        out[label] = {"rms_px": float(res.rms_total), "well_posed": fit.well_posed,
                      "plane_error_mm": [1e3 * (w.offset - t.offset) for w, t in zip(fit.refined, truth)],
                      "plane_std_mm": (1e3 * fit.offset_std).tolist(),
                      "normal_error_deg": [float(np.rad2deg(np.arccos(np.clip(w.normal @ t.normal, -1, 1))))
                                           for w, t in zip(fit.refined, truth)],
                      "normal_std_deg": np.rad2deg(fit.normal_std).tolist(),
                      "max_correlation": fit.max_correlation.max(axis=1).tolist(), "message": fit.message}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=18, help="board views (cycled over the three depths)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--exact-noise", type=float, default=None, metavar="PX",
                    help="instead: exact projections with this pixel noise (shared wall at 3 depths / 1 depth, "
                         "one window per camera)")
    a = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    if a.exact_noise is not None:
        r = run_exact(a.exact_noise, a.views)
        if a.json:
            print(json.dumps(r))
            return
        print(f"exact projections + {a.exact_noise} px noise, {a.views} views")
        for label, x in r.items():
            f = ", ".join(f"{e:+.3f} ± {s:.3f} mm" for e, s in zip(x["plane_error_mm"], x["plane_std_mm"]))
            n = ", ".join(f"{e:.3f} ± {s:.3f} deg" for e, s in zip(x["normal_error_deg"], x["normal_std_deg"]))
            print(f"{label}: RMS {x['rms_px']:.3f} px, well posed {x['well_posed']}, plane {f}, normal {n}, "
                  f"max correlation {max(x['max_correlation']):.4f}")
        return
    r = run(a.views)
    if a.json:
        print(json.dumps(r))
        return
    print(f"{r['views']} views rendered through the wall; corners per camera {r['corners_per_camera']}")
    print("| calibration | RMS [px] | 3-D RMS [um] | 3-D max [um] | aligned RMS [um] | aligned max [um] "
          "| plane error [mm] | normal error [deg] |")
    print("|---|---|---|---|---|---|---|---|")
    for label in ("nominal", "refined", "wrong", "straight"):
        x = r[label]
        pe = f"{x['plane_error_mm']:+.3f} ± {x['plane_std_mm']:.3f}" if "plane_error_mm" in x else "-"
        ne = f"{x['normal_error_deg']:.3f} ± {x['normal_std_deg']:.3f}" if "normal_error_deg" in x else "-"
        print(f"| {label} | {x['rms_px']:.4f} | {x['rms_3d_um']:.1f} | {x['max_3d_um']:.1f} | {x['rms_3d_aligned_um']:.1f} "
              f"| {x['max_3d_aligned_um']:.1f} | {pe} | {ne} |")


if __name__ == "__main__":
    main()
