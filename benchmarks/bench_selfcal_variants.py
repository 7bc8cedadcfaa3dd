"""Volume self-calibration variants on OpenPTV test_cavity: does any lower both the calibration-body RMS and the
cross-camera disparity? (issue 14; docs/validation/reconstruction.md, "The body against the particles").

Seed: the body calibration with only the terms its dots determine, ptv.par's media (``bench_real_data.py
--selfcal-seed selected-ptvpar``); frames 0-4, OpenPTV's particle settings, the benchmark's volume and settings.
Per variant: body RMS per camera (px; on all matched dots and without the dots 3 robust sigmas off in the seed),
the disparity check at the first pass's tolerances (RMS / max, px; per camera) and the time. Then the diagnosis of
the base variant: its body residuals per body depth, and a pose-only refit of each camera on the body alone
(what it costs the particles).

    python -m benchmarks.bench_selfcal_variants [--json]      # 7-12 min (18 self-calibrations of 16-45 s each)
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
from scipy.optimize import least_squares


from benchmarks import _common as B
from reconstruction import volume_selfcal as V
from reconstruction.calibration_body import camera_parameters, camera_with_parameters
from vfmlab import openptv

FREE = B.SELFCAL["free"]
VARIANTS = {  # name: (self_calibrate options, use the cleaned dots, per-camera noise weights)
    "base (body weight 0.5)": ({"body_weight": 0.5}, False, False),
    "per-camera noise weights": ({}, False, True),
    "body dots 3 sigma off dropped, 0.5": ({"body_weight": 0.5}, True, False),
    "body dots 3 sigma off dropped, 1.0": ({"body_weight": 1.0}, True, False),
    "+ window offset, 0.5": ({"body_weight": 0.5, "free": FREE + ("window_offset",)}, False, False),
    "+ focal length, 0.5": ({"body_weight": 0.5, "free": FREE + ("focal_length",)}, False, False),
    "+ focal length, 1.0": ({"body_weight": 1.0, "free": FREE + ("focal_length",)}, False, False),
    "+ focal length, aspect, 0.5": ({"body_weight": 0.5, "free": FREE + ("focal_length", "aspect")}, False, False),
    "+ focal length, k2, 0.5": ({"body_weight": 0.5, "free": FREE + ("focal_length", "k2")}, False, False),
    "camera 1's body left out, 0.5": ({"body_weight": np.array([0.0, 0.5, 0.5, 0.5])}, False, False),
    "camera 2's body left out, 0.5": ({"body_weight": np.array([0.5, 0.0, 0.5, 0.5])}, False, False),
    "camera 3's body left out, 0.5": ({"body_weight": np.array([0.5, 0.5, 0.0, 0.5])}, False, False),
    "camera 4's body left out, 0.5": ({"body_weight": np.array([0.5, 0.5, 0.5, 0.0])}, False, False),
    "body z scale 0.97, 0.5": ({"body_weight": 0.5, "z_scale": 0.97}, False, False),
    "body z scale 1.03, 0.5": ({"body_weight": 0.5, "z_scale": 1.03}, False, False),
    "body seen by cameras 3-4 +2 mm along z (fixed), 0.5": ({"body_weight": 0.5, "far_shift_mm": 2.0}, False, False),
    "body sides: offset refined, 0.5": ({"body_weight": 0.5, "body_sides": True}, False, False),
    "body sides: offset refined, 1.0": ({"body_weight": 1.0, "body_sides": True}, False, False),
}


def _peak_rms(m, c) -> float:
    n2 = np.sum(m.peak_px[c] ** 2, -1)
    ok = np.isfinite(n2)
    return float(np.sqrt(np.sum(n2[ok] * m.counts[c][ok]) / max(m.counts[c][ok].sum(), 1)))


def _clean(seed, pts, px) -> np.ndarray:
    """``px`` without the dots more than 3 robust sigmas off in the seed (the body's defective point 31 and a few)."""
    out = px.copy()
    for c, cam in enumerate(seed):
        r = np.linalg.norm(cam.project(pts) - px[c], axis=1)
        med = np.nanmedian(r)
        out[c, r > med + 3 * 1.4826 * np.nanmedian(np.abs(r - med))] = np.nan
    return out


def _kept_particles(sc, frames, bounds):
    """Pixels ``(4, n, 2)`` and points ``(n, 3)`` of the candidates on the peaks at the last tolerances."""
    pixels, X, res = V._candidates_all_frames(frames, sc.cameras, bounds, 1.5, 1.0, 3)
    ok = V.consistent_candidates(res, X, V.disparity_map(res, X, bounds, grid=(2, 2, 2), half_width_px=4.0), bounds, 0.5)
    return pixels[:, ok], X[ok]


def diagnose(sc, frames, bounds, pts, px) -> dict:
    """Body residual means per body depth, and a pose-only body refit of each camera with its cost on the particles."""
    P, X = _kept_particles(sc, frames, bounds)
    z = np.round(pts[:, 2] * 1e3, 1)
    out = {}
    for c, cam in enumerate(sc.cameras):
        ok = np.all(np.isfinite(px[c]), 1)
        r = cam.project(pts) - px[c]
        depth = {f"{lvl:+.0f}": [round(float(v), 2) for v in np.nanmean(r[ok & (z == lvl)], 0)] for lvl in np.unique(z)}
        mask = np.zeros(18, bool)
        mask[:6] = True

        def f(x, cam=cam, ok=ok, c=c):
            return (camera_with_parameters(x, cam, mask).project(pts[ok]) - px[c, ok]).ravel()

        sol = least_squares(f, camera_parameters(cam)[mask], x_scale="jac", loss="soft_l1", f_scale=1.0)
        moved = camera_with_parameters(sol.x, cam, mask)
        seen = np.all(np.isfinite(P[c]), 1)
        d0, d1 = cam.project(X[seen]) - P[c, seen], moved.project(X[seen]) - P[c, seen]
        out[cam.name] = {"body_residual_mean_px_per_depth_mm": depth,
                         "pose_only_body_refit_rms_px": float(np.sqrt(np.mean(np.sum(sol.fun.reshape(-1, 2) ** 2, 1)))),
                         "pose_only_body_refit_centre_moved_mm": 1e3 * float(np.linalg.norm(moved.center - cam.center)),
                         "particles": int(seen.sum()),
                         "particle_rms_px_before_after_refit": [float(np.sqrt(np.mean(np.sum(d ** 2, 1)))) for d in (d0, d1)]}
    return out


def run() -> dict:
    imported = openptv.load_cameras(B.DATA)
    pts, px = openptv.body_dots(B.DATA, imported)
    t = time.perf_counter()
    seed, _ = B.selected_body_calibration(imported, False)
    res = {"seed_s": time.perf_counter() - t, "seed_body_rms_px": V.body_rms(seed, pts, px).tolist(), "variants": {}}
    frames = [openptv.detect_frame(B.DATA, f) for f in B.SELFCAL_FRAMES]
    bounds = B.selfcal_bounds()
    clean = _clean(seed, pts, px)
    base = None
    for name, (opts, use_clean, noise) in VARIANTS.items():
        if noise:  # particles' scatter per camera (base, kept candidates) over the seed's body scatter
            P, X = _kept_particles(base, frames, bounds)
            sp = np.sqrt(np.nanmean(np.sum((np.stack([c.project(X) for c in base.cameras]) - P) ** 2, -1), axis=1))
            opts = {"body_weight": sp / V.body_rms(seed, pts, px)}
        body, all_dots, clean_dots = pts, px.copy(), clean.copy()
        opts = dict(opts)
        if "z_scale" in opts:  # the body's depth levels scaled
            body = pts * np.array([1.0, 1.0, opts.pop("z_scale")])
        if "far_shift_mm" in opts:  # cameras 3-4 see the body shifted along z (to first order: their dots moved)
            d = np.array([0.0, 0.0, 1e-3 * opts.pop("far_shift_mm")])
            for c in (2, 3):
                move = seed[c].project(pts + d) - seed[c].project(pts)
                all_dots[c] -= move
                clean_dots[c] -= move
        dots = clean_dots if use_clean else all_dots
        t = time.perf_counter()
        sc = V.self_calibrate(frames, seed, bounds, body, dots, **{**B.SELFCAL, "body_sides": False, **opts})
        base = base or sc
        res["variants"][name] = {
            "s": time.perf_counter() - t, "message": sc.message,
            "body_weight": np.round(np.atleast_1d(opts.get("body_weight", 1.0)), 3).tolist(),
            "body_rms_px": V.body_rms(sc.cameras, body, all_dots, sc.far_side, sc.body_offset_m).tolist(),
            "body_rms_px_clean_dots": V.body_rms(sc.cameras, body, clean_dots, sc.far_side, sc.body_offset_m).tolist(),
            "body_offset_mm": 1e3 * sc.body_offset_m,
            "check_rms_px": [sc.maps[0].rms_peak_offset_px, sc.check_map.rms_peak_offset_px],
            "check_max_px": [sc.maps[0].max_peak_offset_px, sc.check_map.max_peak_offset_px],
            "check_rms_px_per_camera_after": [_peak_rms(sc.check_map, c) for c in range(len(seed))],
            "focal_change_percent": [100 * (b.K[1, 1] / a.K[1, 1] - 1) for a, b in zip(seed, sc.cameras)]}
    res["diagnosis_base"] = diagnose(base, frames, bounds, pts, px)
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="one JSON object")
    a = ap.parse_args(argv)
    res = run()
    if a.json:
        print(json.dumps(res))
        return 0
    f = lambda v: " / ".join(f"{x:.2f}" for x in v)  # noqa: E731
    print(f"seed body RMS (px): {f(res['seed_body_rms_px'])}")
    print("| variant | body RMS after (px) | without the outlying dots (px) | check RMS before -> after (max) (px) | per camera after (px) | focal change (%) | body offset (mm) |")
    print("|---|---|---|---|---|---|---|")
    for name, v in res["variants"].items():
        print(f"| {name} | {f(v['body_rms_px'])} | {f(v['body_rms_px_clean_dots'])} | {v['check_rms_px'][0]:.2f} -> "
              f"{v['check_rms_px'][1]:.2f} ({v['check_max_px'][1]:.2f}) | {f(v['check_rms_px_per_camera_after'])} | "
              f"{f(v['focal_change_percent'])} | {v['body_offset_mm']:.2f} |")
    print(json.dumps(res["diagnosis_base"], indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
