"""Mapping correction in 3-D (benchmarks/research/mapping_correction.py) on OpenPTV's test_cavity, issue 14.

1. Is the cameras' remaining inconsistency depth-dependent? The self-calibrated cameras (as bench_real_data's
   ``--selfcal-seed selected-ptvpar --body-weight 0.5``), the matching over time's first pass (TEMPORAL's loose
   gates, DETECTION's particles, frames 0-4: verified matches); per camera the residual (projected - detected) fitted
   as a polynomial of the pixel (u, v), of the world point (x, y, z), or as the pixel map of degree 3 plus a depth
   slope (mapping_correction's model), each frame held out in turn: held-out RMS of what is left (px) per degree (key
   ``depth_dependence``).
2. The matching with no correction, with the 2-D pixel correction (temporal_matching.fit_pixel_correction, degree 3,
   as match_over_time), with the 3-D correction (fit_mapping_correction: a pixel map plus a depth slope, degrees
   chosen by the same held-out frames; the cameras wrapped in CorrectedCamera) and with both (the 3-D one fitted on
   what the 2-D one leaves), all fitted on the first pass's matches; the decoy (camera 1's detections moved by
   DECOY_SHIFT_PX in every frame) runs through the same pipeline, its corrections fitted on its own matches: matching
   over time (TEMPORAL's final gates), one-frame matching (OpenPTV's particle settings, SELFCAL_GATES and
   TIGHT_GATES, each frame's box as bench_real_data's self_calibrated rows), frames 1-4: points seen by >= 3
   cameras, >= 3-view points with camera 1 real vs decoy, reprojection RMS (key ``matching``); the disparity check
   at the self-calibration's first tolerances (key ``check``).

The corrections are fitted on the matches of frames 0-4 and scored on the matching of frames 1-4 (the same
particles: as the self-calibration and match_over_time's 2-D correction, the decoy is what checks it).

    python -m benchmarks.bench_mapping_correction [--json] [--cameras PICKLE]
        # --cameras: a pickle with key "cameras" (self-calibrated cameras) instead of the self-calibration (2-3 min)
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np


from benchmarks import _common as B
from reconstruction.correspondence import match_views, observed_pixels
from benchmarks.research.mapping_correction import (correction_at, correction_basis, corrected_cameras,
                                               fit_mapping_correction, held_out_rms, polynomial_basis)
from benchmarks.research.temporal_matching import (apply_pixel_correction, fit_pixel_correction,
                                              temporal_match)
from reconstruction.triangulation import triangulate
from reconstruction.volume_selfcal import disparity_map, loose_candidates
from vfmlab import openptv

FRAMES = (1, 2, 3, 4)
OPTIONS = {k: B.TEMPORAL[k] for k in ("max_step_m", "max_accel_m", "max_residual_change_px", "min_motion_m")}


def first_pass(dense: list, cams: list, bounds) -> dict:
    """The matching over time with TEMPORAL's loose gates: pixels ``(4, n, 2)``, points ``(n, 3)``, residuals
    ``(4, n, 2)`` and the frame of each match ``(n,)``."""
    g = B.TEMPORAL["loose_gates"]
    tm = temporal_match(dense, cams, bounds, epipolar_px=g[0], radius_px=g[1], max_residual_px=g[2], **OPTIONS)
    px = np.concatenate([observed_pixels(f, o) for f, o in zip(dense, tm.observations)], axis=1)
    tri = triangulate(px, cams, covariance=False)
    frame = np.concatenate([np.full(len(o), t) for t, o in enumerate(tm.observations)])
    return {"pixels": px, "points": tri.points, "residuals": tri.residuals, "frame": frame}


def _held_out_rms(Z: np.ndarray, r: np.ndarray, groups: np.ndarray, degree: int) -> float:
    """Held-out RMS (px) of ``r`` ``(n, 2)`` minus a least-squares polynomial of ``Z`` ``(n, k)`` in [-1, 1]."""
    A = polynomial_basis(Z, degree)
    pred = np.full_like(r, np.nan)
    for g in np.unique(groups):
        tr = groups != g
        pred[~tr] = A[~tr] @ np.linalg.lstsq(A[tr], r[tr], rcond=None)[0]
    return float(np.sqrt(np.mean(np.sum((r - pred) ** 2, axis=1))))


def depth_dependence(fp: dict, cams: list, bounds) -> dict:
    """Per camera: matches, residual RMS, and the held-out RMS left by polynomials of (u, v) (degrees 1-4), of
    (x, y, z) (degrees 1-3) and by mapping_correction's model (pixel map of degree 3 + depth slope of degree 0-3; no
    ridge, no robust refit, as the others), each frame held out in turn; residuals over 3 robust sigmas left out."""
    lo, hi = bounds
    out = {}
    for c, cam in enumerate(cams):
        r, X = fp["residuals"][c], fp["points"]
        ok = np.all(np.isfinite(r), axis=1) & np.all(np.isfinite(X), axis=1)
        e = np.linalg.norm(r - np.nanmedian(r[ok], axis=0), axis=1)
        ok &= e <= 3.0 * 1.4826 * np.median(e[ok])
        W, H = cam.image_size
        uv = 2.0 * fp["pixels"][c, ok] / [W - 1, H - 1] - 1.0
        xyz = 2.0 * (X[ok] - lo) / (hi - lo) - 1.0
        row = {"matches": int(ok.sum()), "residual_rms_px": float(np.sqrt(np.mean(np.sum(r[ok] ** 2, 1))))}
        for d in (1, 2, 3, 4):
            row[f"uv_degree{d}_px"] = _held_out_rms(uv, r[ok], fp["frame"][ok], d)
        for d in (1, 2, 3):
            row[f"xyz_degree{d}_px"] = _held_out_rms(xyz, r[ok], fp["frame"][ok], d)
        axis = int(np.argmax(np.abs(cam.R[2])))
        for e in (0, 1, 2, 3):  # the model of mapping_correction: pixel map of degree 3 + depth slope of degree e
            A = correction_basis(cam.project(X[ok]), X[ok], cam.image_size, axis, (lo[axis], hi[axis]), 3, e)
            row[f"uv3_depth_slope_degree{e}_px"] = held_out_rms(A, r[ok], fp["frame"][ok], ridge=0.0, clip_sigma=np.inf)
        out[cam.name] = row
    return out


def corrections(fp: dict, cams: list, bounds) -> dict:
    """The camera models as (pixel-correction coefficients or None, cameras): ``none``; ``pixel_2d``
    (fit_pixel_correction, degree 3, as match_over_time); ``mapping_3d`` (fit_mapping_correction, CorrectedCamera);
    ``pixel_2d+mapping_3d`` (the 3-D correction fitted on what the 2-D one leaves: the first pass's pixels moved by
    it, re-triangulated). Also the 3-D degrees and sizes (RMS over the matches, px)."""
    sizes = [c.image_size for c in cams]
    coef = fit_pixel_correction(fp["pixels"], fp["residuals"], sizes, degree=B.TEMPORAL["degree"])
    corr = fit_mapping_correction(cams, fp["points"], fp["residuals"], bounds, groups=fp["frame"])
    moved = np.stack(apply_pixel_correction(list(fp["pixels"]), coef, sizes))
    moved = np.where(np.isfinite(fp["pixels"]), moved, np.nan)
    tri = triangulate(moved, cams, covariance=False)
    corr2 = fit_mapping_correction(cams, tri.points, tri.residuals, bounds, groups=fp["frame"])
    c3, c23 = corrected_cameras(cams, corr, bounds), corrected_cameras(cams, corr2, bounds)

    def size(cs, X):
        return np.sqrt(np.nanmean(np.sum(correction_at(cs, X) ** 2, axis=-1), axis=1)).tolist()

    return {"models": {"none": (None, cams), "pixel_2d": (coef, cams), "mapping_3d": (None, c3),
                       "pixel_2d+mapping_3d": (coef, c23)},
            "models_3d": [[c.degree, c.depth_degree] for c in corr], "size_3d_px": size(c3, fp["points"]),
            "models_3d_after_2d": [[c.degree, c.depth_degree] for c in corr2],
            "size_3d_after_2d_px": size(c23, tri.points)}


def _moved(dets: list, coef, cams: list) -> list:
    return dets if coef is None else apply_pixel_correction(dets, coef, [c.image_size for c in cams])


def _with_cam1(obs: np.ndarray) -> int:
    return int((((obs >= 0).sum(axis=1) >= 3) & (obs[:, 0] >= 0)).sum())


def matching(dense: list, bright: list, model, bounds) -> dict:
    """Per frame of FRAMES: matching over time (final gates) and one-frame matching (SELFCAL_GATES, TIGHT_GATES)
    with one camera model: points seen by >= 3 cameras, those with camera 1, reprojection RMS (px)."""
    coef, cams = model
    g = B.TEMPORAL["gates"]
    frames = [_moved(d, coef, cams) for d in dense]
    tm = temporal_match(frames, cams, bounds, epipolar_px=g[0], radius_px=g[1], max_residual_px=g[2], **OPTIONS)
    out = {"temporal": {}, "one_frame": {}, "one_frame_tight": {}}
    for f in FRAMES:
        t = B.TEMPORAL_FRAMES.index(f)
        obs = tm.observations[t]
        out["temporal"][str(f)] = {"points_3plus": int(((obs >= 0).sum(1) >= 3).sum()), "with_cam1": _with_cam1(obs),
                                   "rms_px": float(np.sqrt(np.nanmean(tm.rms[t] ** 2)))}
        dets = _moved(bright[t], coef, cams)
        P = B.openptv_result(f)[0]  # the box of bench_real_data.frame_figures: OpenPTV's points of the frame, +- 5 mm
        box = (P.min(0) - 5e-3, P.max(0) + 5e-3)
        for key, gates in (("one_frame", B.SELFCAL_GATES), ("one_frame_tight", B.TIGHT_GATES)):
            cor = match_views(dets, cams, bounds=box, **gates)
            obs = cor.observations
            out[key][str(f)] = {"points_3plus": int(((obs >= 0).sum(1) >= 3).sum()), "with_cam1": _with_cam1(obs),
                                "rms_px": float(np.sqrt(np.nanmean(cor.triangulation.reprojection_rms ** 2)))}
    return out


def check(bright: list, model, bounds) -> dict:
    """Disparity peaks (RMS, max, px) at the self-calibration's first tolerances, frames 0-4, 2 x 2 x 2 sub-volumes."""
    coef, cams = model
    epi, rad, _ = B.SELFCAL["schedule"][0]
    px = []
    for dets in bright:
        d = _moved(dets, coef, cams)
        px.append(observed_pixels(d, loose_candidates(d, cams, bounds, epipolar_px=epi, radius_px=rad)))
    tri = triangulate(np.concatenate(px, axis=1), cams, covariance=False)
    m = disparity_map(tri.residuals, tri.points, bounds, grid=B.SELFCAL["grid"], half_width_px=max(epi, rad) + 1.0)
    return {"peak_rms_px": m.rms_peak_offset_px, "peak_max_px": m.max_peak_offset_px,
            "candidates": int(tri.points.shape[0])}


def run(pickle_path: str | None = None) -> dict:
    t0 = time.time()
    cams = B.self_calibrated_cameras(pickle_path=pickle_path)
    bounds = B.selfcal_bounds()
    dense = [openptv.detect_frame(B.DATA, f, **B.DETECTION) for f in B.TEMPORAL_FRAMES]
    bright = [openptv.detect_frame(B.DATA, f) for f in B.TEMPORAL_FRAMES]
    shift = np.asarray(B.DECOY_SHIFT_PX)
    data = {"real": (dense, bright), "decoy": ([[d[0] + shift, *d[1:]] for d in dense],
                                                [[d[0] + shift, *d[1:]] for d in bright])}
    out = {"matching": {}, "check": {}, "corrections": {}}
    for name, (dn, br) in data.items():
        fp = first_pass(dn, cams, bounds)
        if name == "real":
            out["depth_dependence"] = depth_dependence(fp, cams, bounds)
        fitted = corrections(fp, cams, bounds)
        models = fitted.pop("models")
        out["corrections"][name] = {"matches": int(fp["points"].shape[0]), **fitted}
        for key, model in models.items():
            out["matching"].setdefault(key, {})[name] = matching(dn, br, model, bounds)
            if name == "real":
                out["check"][key] = check(br, model, bounds)
    out["seconds"] = time.time() - t0
    return out


def table(res: dict) -> str:
    lines = ["Depth dependence (held-out RMS left, px; matches of the first pass, frames 0-4):",
             "| camera | matches | residual RMS | (u,v) deg 1 / 2 / 3 / 4 | (x,y,z) deg 1 / 2 / 3 "
             "| (u,v) deg 3 + depth x (u,v) deg 0 / 1 / 2 / 3 |", "|---|---|---|---|---|---|"]
    for cam, r in res["depth_dependence"].items():
        uv = " / ".join(f"{r[f'uv_degree{d}_px']:.3f}" for d in (1, 2, 3, 4))
        xyz = " / ".join(f"{r[f'xyz_degree{d}_px']:.3f}" for d in (1, 2, 3))
        sl = " / ".join(f"{r[f'uv3_depth_slope_degree{e}_px']:.3f}" for e in (0, 1, 2, 3))
        lines.append(f"| {cam} | {r['matches']} | {r['residual_rms_px']:.3f} | {uv} | {xyz} | {sl} |")
    lines += ["", "corrections: " + json.dumps(res["corrections"]), "",
              "| model | matching | frame | points seen by >= 3 cameras | with camera 1, real vs decoy | real - decoy "
              "| RMS (px) |",
              "|---|---|---|---|---|---|---|"]
    for model, runs in res["matching"].items():
        for kind in ("temporal", "one_frame", "one_frame_tight"):
            for f, r in runs["real"][kind].items():
                d = runs["decoy"][kind][f]
                lines.append(f"| {model} | {kind} | {f} | {r['points_3plus']} | {r['with_cam1']} vs {d['with_cam1']} "
                             f"| {r['with_cam1'] - d['with_cam1']} | {r['rms_px']:.3f} |")
    lines += ["", "check (disparity peaks at the first tolerances): " + json.dumps(res["check"]),
              f"{res['seconds']:.0f} s"]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--cameras", help="pickle with key 'cameras': self-calibrated cameras (skips the self-calibration)")
    a = ap.parse_args(argv)
    res = run(a.cameras)
    print(json.dumps(res, indent=1) if a.json else table(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
