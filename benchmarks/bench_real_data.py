"""Real data: OpenPTV test_cavity (../shared/data/openptv-test-cavity), 4 cameras through 6 mm glass into water.

For frames 1-4: detect particles, match them across the 4 cameras along the epipolar curves through the
window, triangulate, and compare with OpenPTV's own 3-D result (res/rt_is.1000F; a peer's answer, not ground
truth), with three calibrations:

- ``imported``: OpenPTV's calibration with its media (refraction);
- ``own``: ours from the calibration body (cal/camN.tif + target_on_a_side.txt), seeded by the imported one:
  dot centres refined on the image, outlying dots dropped, focal length kept (one view of this body does not fix
  it), k1-k3, p1, p2, aspect and the window's tilt refined, ptv.par's indices in physical order
  (vfmlab.openptv.BODY_FIT, PHYSICAL_MEDIA);
- ``no_refraction``: the imported calibration with the media ignored (straight rays). Its reprojection RMS
  is that of the same correspondences as ``imported``, triangulated with straight rays;
- ``self_calibrated``: the imported calibration (``--selfcal-seed``: or the body calibration with the model
  its dots determine, key ``selected_body_model``) corrected by the volume self-calibration on the particles of
  frames 0-4 (reconstruction.volume_selfcal, Wieneke 2008: loose 3-view candidates, disparity peaks per camera and
  sub-volume, bundle adjustment with the calibration body). ``self_calibration`` holds its diagnostics:
  disparity peaks per pass, the check at the first pass's tolerances, the body RMS after, and the matching
  with tight gates (real vs decoy) with ``own`` and with the self-calibrated cameras;
- ``temporal``: matching over time with the self-calibrated cameras (benchmarks.research.temporal_matching.match_over_time,
  TEMPORAL) on DETECTION's particles of frames 0-4: a >= 3-camera match is kept when it persists as a smooth track
  with a constant residual per camera; the decoy runs through the same pipeline. ``temporal_diagnostics``: the same
  without the pixel correction, the correction's size, the true matches with camera 1 estimated among one frame's
  candidates and, with ``--temporal-variants``, one setting changed at a time;
- ``likelihood``, ``likelihood_over_time``, ``likelihood_inclusive``: matching by likelihood ratio with the
  self-calibrated cameras on DETECTION's particles (benchmarks.research.likelihood_matching, bench_likelihood_matching:
  model, threshold and persistence bonus chosen on frame 0, the decoy through the same pipeline): one frame at a
  time and over time with the decoy <= 10 % of the real count on frame 0, and over time at the inclusive operating
  point (decoy <= 30 %).

    python -m benchmarks.bench_real_data [--json] [--frames 1 2 3 4]
    python -m benchmarks.bench_real_data --selfcal-seed selected-ptvpar --body-weight 0.5 --skip-dense --frames 1
        # self-calibration seeded by the body calibration with the model its dots determine (select_body_model)
    python -m benchmarks.bench_real_data --selfcal-seed selected-ptvpar --body-weight 0.5 --skip-dense --temporal-variants
        # key temporal: matching over time (benchmarks.research.temporal_matching) with the self-calibrated cameras
    python -m benchmarks.bench_real_data --rendered   # rig_sim window renderer instead
    python -m benchmarks.bench_real_data --openptv-check   # OpenPTV's own matches, re-triangulated (needs optv)
    python -m benchmarks.bench_real_data --openptv-persistence   # how many of OpenPTV's points persist over time
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from benchmarks._common import (DATA, DECOY_SHIFT_PX, DETECTION, SELFCAL_GATES, TEMPORAL, TEMPORAL_FRAMES, TIGHT_GATES,
                                corner_distortion_change, frame_figures, openptv_result, run_setting,
                                selected_body_calibration, self_calibration, selfcal_bounds, temporal_figures,
                                with_cam1)
from benchmarks.research.temporal_matching import (apply_pixel_correction, frame_candidates, link_frames,
                                                   match_over_time, smooth_triplets)
from reconstruction.triangulation import triangulate
from vfmlab import openptv


def run(frames: list[int], selfcal_seed: str = "imported", dense: bool = True, body_weight: float = 1.0,
        variants: bool = False) -> dict:
    imported = openptv.load_cameras(DATA)
    straight = [c.without_window() for c in imported]
    body = openptv.calibrate_body_folder(DATA, imported, media=openptv.PHYSICAL_MEDIA, **openptv.BODY_FIT)
    own = [b.camera for b in body]
    out = {"imported": {}, "own": {}, "no_refraction": {},
           "calibration_body_rms_px": {b.camera.name: b.rms for b in body},
           "calibration_body_well_posed": {b.camera.name: b.well_posed for b in body},
           "calibration_body_rms_px_imported": {}, "detections_per_camera": {}}
    pts, body_px = openptv.body_dots(DATA, imported)
    for cam, px in zip(imported, body_px):
        out["calibration_body_rms_px_imported"][cam.name] = float(np.sqrt(np.nanmean(np.sum((cam.project(pts) - px) ** 2, 1))))
    out["calibration_body_corner_distortion_change_px"] = {
        b.camera.name: corner_distortion_change(b.camera, c) for b, c in zip(body, imported)}
    seed_cams = imported
    if selfcal_seed.startswith("selected"):
        seed_cams, out["selected_body_model"] = selected_body_calibration(imported, selfcal_seed == "selected")
    sc, out["self_calibration"] = self_calibration(seed_cams, body_px, pts, body_weight)
    out["self_calibration"]["seed"] = selfcal_seed
    out["self_calibration"]["body_rms_px_seed"] = {
        c.name: float(np.sqrt(np.nanmean(np.sum((c.project(pts) - px) ** 2, 1)))) for c, px in zip(seed_cams, body_px)}
    out["self_calibrated"] = {}
    out["calibration_body_rms_px_self_calibrated"] = dict(zip(out["calibration_body_rms_px"], sc.body_rms_px.tolist()))
    out["temporal"], out["temporal_diagnostics"] = temporal(frames, sc.cameras)
    out["likelihood"], out["likelihood_over_time"], out["likelihood_inclusive"] = likelihood_matching(frames,
                                                                                                     sc.cameras)
    if variants:
        out["temporal_diagnostics"]["variants"] = temporal_variants(frames, sc.cameras)
    for f in frames:
        if dense:
            dets = openptv.detect_frame(DATA, f, **DETECTION)
            out["imported"][str(f)], out["no_refraction"][str(f)] = frame_figures(f, dets, imported,
                                                                                   straight=straight, decoy=True)
            out["own"][str(f)] = frame_figures(f, dets, own, decoy=True)
            out["detections_per_camera"][str(f)] = [len(d) for d in dets]
        bright = openptv.detect_frame(DATA, f)
        out["self_calibrated"][str(f)] = frame_figures(f, bright, sc.cameras, gates=SELFCAL_GATES, decoy=True)
        out["self_calibration"]["imported_same_matching"][str(f)] = frame_figures(f, bright, imported,
                                                                                  gates=SELFCAL_GATES, decoy=True)
        out["self_calibration"]["tight_gates"][str(f)] = {
            name: _real_and_decoy(f, bright, cams) for name, cams in (("imported", imported),
                                                                       ("self_calibrated", sc.cameras))}
        if selfcal_seed != "imported":
            out["self_calibration"]["tight_gates"][str(f)]["seed"] = _real_and_decoy(f, bright, seed_cams)
    return out


#: ``--temporal-variants``: TEMPORAL with one setting changed at a time (key temporal_diagnostics.variants)
TEMPORAL_VARIANTS = {"second difference <= 0.4 mm": {"max_accel_m": 0.4e-3},
                     "second difference <= 0.8 mm": {"max_accel_m": 0.8e-3},
                     "residual change <= 0.4 px": {"max_residual_change_px": 0.4},
                     "residual change <= 0.7 px": {"max_residual_change_px": 0.7},
                     "no residual test": {"max_residual_change_px": float("inf")},
                     "static chains allowed": {"min_motion_m": 0.0}}


def temporal_variants(frames: list[int], cams: list) -> dict:
    """Per TEMPORAL_VARIANTS entry and frame of ``frames``: points seen by >= 3 cameras, >= 3-view matches with
    camera 1, real and decoy, and the reprojection RMS (px)."""
    bounds = selfcal_bounds()
    dets = [openptv.detect_frame(DATA, f, **DETECTION) for f in TEMPORAL_FRAMES]
    decoy = [[d[0] + np.asarray(DECOY_SHIFT_PX), *d[1:]] for d in dets]
    out = {}
    for name, change in TEMPORAL_VARIANTS.items():
        opts = {**TEMPORAL, **change}
        tm, tm_decoy = match_over_time(dets, cams, bounds, **opts)[0], match_over_time(decoy, cams, bounds, **opts)[0]
        out[name] = {str(f): {"our_points_3plus_views": int(((tm.observations[t] >= 0).sum(1) >= 3).sum()),
                              "our_points_3plus_views_with_cam1": with_cam1(tm.observations[t]),
                              "decoy_points_3plus_views_with_cam1": with_cam1(tm_decoy.observations[t]),
                              "reprojection_rms_px_ours": float(np.sqrt(np.nanmean(tm.rms[t] ** 2)))}
                     for f in frames for t in [TEMPORAL_FRAMES.index(f)]}
    return out


def temporal(frames: list[int], cams: list) -> tuple[dict, dict]:
    """Matching over time (TEMPORAL) with ``cams`` on DETECTION's particles of TEMPORAL_FRAMES, the same with
    camera 1's detections moved by DECOY_SHIFT_PX in every frame (the whole pipeline, correction included), per
    frame of ``frames``; diagnostics: without the pixel correction, the correction's size, and per frame the
    true >= 3-view matches with camera 1 among the single-frame candidates (estimated from the decoy)."""
    bounds = selfcal_bounds()
    dets = [openptv.detect_frame(DATA, f, **DETECTION) for f in TEMPORAL_FRAMES]
    decoy = [[d[0] + np.asarray(DECOY_SHIFT_PX), *d[1:]] for d in dets]
    runs = {}
    for name, degree in (("corrected", TEMPORAL["degree"]), ("no_correction", 0)):
        opts = {**TEMPORAL, "degree": degree}
        runs[name] = (match_over_time(dets, cams, bounds, **opts), match_over_time(decoy, cams, bounds, **opts)[0])
    out, diag = {}, {"settings": {k: list(v) if isinstance(v, tuple) else v for k, v in TEMPORAL.items()},
                     "no_correction": {}, "candidates_with_cam1": {}}
    (tm, corrected, coef), tm_decoy = runs["corrected"]
    sizes = [c.image_size for c in cams]
    diag["correction_rms_px"] = [float(np.sqrt(np.mean(np.sum((a - b) ** 2, 1))))
                                 for a, b in zip(corrected[1], dets[1])]
    diag["correction_max_px"] = _correction_max(coef, sizes)
    for f in frames:
        t = TEMPORAL_FRAMES.index(f)
        out[str(f)] = temporal_figures(f, tm, tm_decoy, t, corrected[t], cams)
        (m0, c0, _), d0 = runs["no_correction"]
        diag["no_correction"][str(f)] = temporal_figures(f, m0, d0, t, c0[t], cams)
        diag["candidates_with_cam1"][str(f)] = _true_candidates(dets[t], decoy[t], cams, bounds)
    return out, diag


def likelihood_matching(frames: list[int], cams: list) -> tuple[dict, dict, dict]:
    """Matching by likelihood ratio (benchmarks.bench_likelihood_matching, DETECTION's particles; model and
    threshold measured on frame 0, the decoy through the same pipeline), per frame of ``frames`` in 1-4: one frame
    at a time, with the persistence bonus (frames 0-4), and the same at the inclusive operating point (decoy <= 30 %
    of real on frame 0)."""
    res = run_setting("dense", cams, selfcal_bounds(), baseline=False)
    keys = ("our_points", "our_points_3plus_views", "our_points_3plus_views_with_cam1",
            "decoy_points_3plus_views_with_cam1", "reprojection_rms_px_ours", "agree_within_0p3mm", "threshold")
    out = tuple({str(f): {k: res[name]["per_frame"][str(f)][k] for k in keys} for f in frames
                 if str(f) in res[name]["per_frame"]}
                for name in ("likelihood", "likelihood_over_time", "likelihood_inclusive"))
    for rows in out:
        for f, row in rows.items():
            tgt = openptv_result(int(f))[1]
            if tgt is not None:
                row["openptv_points_3plus_views"] = int(((tgt >= 0).sum(axis=1) >= 3).sum())
    return out


def _correction_max(coef, sizes) -> list[float]:
    """Largest correction (px) of each camera over a 33 x 33 lattice of its image."""
    grids = [np.stack(np.meshgrid(np.linspace(0, W - 1, 33), np.linspace(0, H - 1, 33)), -1).reshape(-1, 2)
             for W, H in sizes]
    moved = apply_pixel_correction(grids, coef, sizes)
    return [float(np.max(np.linalg.norm(m - g, axis=1))) for m, g in zip(moved, grids)]


def _true_candidates(dets: list, decoy: list, cams: list, bounds) -> dict:
    """Single-frame candidates (frame_candidates) with camera 1, per gate set (epipolar, radius, residual px): camera 1
    detections taking part, real and decoy, and the true ones estimated as (real - decoy) / (1 - decoy / n_cam1)
    (a detection with a true match also takes part by chance at the decoy's rate)."""
    out = {}
    for g in (TEMPORAL["gates"], TEMPORAL["loose_gates"]):
        n = []
        for d in (dets, decoy):
            obs = frame_candidates(d, cams, bounds, epipolar_px=g[0], radius_px=g[1], max_residual_px=g[2]).observations
            n.append(len(np.unique(obs[obs[:, 0] >= 0, 0])))
        out["/".join(f"{v:g}" for v in g)] = {"cam1_detections_real": n[0], "cam1_detections_decoy": n[1],
                                              "true_estimate": float((n[0] - n[1]) / (1 - n[1] / len(dets[0])))}
    return out


def _real_and_decoy(frame: int, dets: list, cams: list) -> dict:
    """Points with >= 3 views including camera 1 with TIGHT_GATES, real and with camera 1's detections moved."""
    r = frame_figures(frame, dets, cams, gates=TIGHT_GATES, decoy=True)
    return {k: r[k] for k in ("our_points", "our_points_3plus_views", "our_points_3plus_views_with_cam1",
                              "decoy_points_3plus_views_with_cam1", "reprojection_rms_px_ours", "agree_within_0p3mm")}


def openptv_check(frames: list[int]) -> dict:
    """OpenPTV's own correspondences, re-triangulated with our import of its calibration: per frame and number of
    views, how many, their reprojection RMS (median, px) and the distance of our point to OpenPTV's (median, mm).

    Needs ``optv`` (the test extra): its detection lists are not in the data set, so they are recomputed with
    its own ``preprocess_image`` + ``target_recognition`` and ``targ_rec.par``, sorted by y as ``rt_is`` indexes
    them; OpenPTV pixels -0.5 = OpenCV's."""
    from optv.image_processing import preprocess_image
    from optv.parameters import ControlParams, TargetParams
    from optv.segmentation import target_recognition

    cpar = ControlParams(4)
    cpar.read_control_par(str(DATA / "parameters" / "ptv.par"))
    tpar = TargetParams()
    tpar.read(str(DATA / "parameters" / "targ_rec.par"))
    cams = openptv.load_cameras(DATA)
    out = {}
    for f in frames:
        P, tgt = openptv_result(f)
        px = np.full((len(cams), len(P), 2), np.nan)
        for c in range(len(cams)):
            img = preprocess_image(openptv.read_image(openptv.frame_path(DATA, c + 1, f)), 0, cpar, 25)
            targets = target_recognition(img, tpar, c, cpar)
            targets.sort_y()
            xy = np.array([t.pos() for t in targets]) - 0.5
            seen = (tgt[:, c] >= 0) & (tgt[:, c] < len(xy))
            px[c, seen] = xy[tgt[seen, c]]
        tri = triangulate(px, cams)
        dist = np.linalg.norm(tri.points - P, axis=1) * 1e3
        out[str(f)] = {f"{k}_views": {"n": int((tri.n_views == k).sum()),
                                      "reprojection_rms_px_median": float(np.nanmedian(tri.reprojection_rms[tri.n_views == k])),
                                      "distance_to_openptv_mm_median": float(np.nanmedian(dist[tri.n_views == k]))}
                       for k in (2, 3, 4)}
    return out


#: OpenPTV's points shifted by this much (m) for the persistence decoy: beyond the 1 mm links, within the volume
PERSISTENCE_DECOY_SHIFT_M = (2.0e-3, 1.5e-3, 0.0)


def openptv_persistence() -> dict:
    """How many of OpenPTV's own points of frames 2 and 3 continue in its frames before and after as a smooth
    track, with TEMPORAL's criteria (links <= max_step_m, second difference <= max_accel_m, motion >=
    min_motion_m; no residual test: OpenPTV's pixel lists are not in the data set), by number of cameras.
    The decoy: the same points shifted by PERSISTENCE_DECOY_SHIFT_M (what chance neighbours give)."""
    res = {f: openptv_result(f) for f in range(1, 5)}
    kw = {"max_accel_m": TEMPORAL["max_accel_m"], "min_motion_m": TEMPORAL["min_motion_m"]}
    out = {}
    for f in (2, 3):
        prev, (P, tgt), nxt = res[f - 1][0], res[f], res[f + 1][0]
        n_views = (tgt >= 0).sum(axis=1)
        row = {}
        for name, shift in (("real", 0.0), ("decoy", np.asarray(PERSISTENCE_DECOY_SHIFT_M))):
            pts = [prev, P + shift, nxt]
            links = [link_frames(pts[0], pts[1], TEMPORAL["max_step_m"]),
                     link_frames(pts[1], pts[2], TEMPORAL["max_step_m"])]
            persistent = np.zeros(len(P), bool)
            persistent[smooth_triplets(pts, links, **kw)[:, 2]] = True
            for k in (2, 3, 4):
                row[f"{name}_{k}_views_persistent"] = int((persistent & (n_views == k)).sum())
        row.update({f"openptv_{k}_views": int((n_views == k).sum()) for k in (2, 3, 4)})
        out[str(f)] = row
    return out


def table(res: dict) -> str:
    keys = ["our_points", "our_points_3plus_views", "openptv_points_3plus_views", "reprojection_rms_px_ours",
            "reprojection_median_px_openptv", "agree_within_0p3mm", "our_points_3plus_views_with_cam1",
            "decoy_points_3plus_views_with_cam1"]
    lines = ["| calibration | frame | " + " | ".join(keys) + " |", "|" + "---|" * (len(keys) + 2)]
    for cal in ("imported", "own", "self_calibrated", "temporal", "likelihood", "likelihood_over_time",
                "likelihood_inclusive", "no_refraction"):
        for f, row in res.get(cal, {}).items():
            lines.append(f"| {cal} | {f} | " + " | ".join(_fmt(row.get(k)) for k in keys) + " |")
    lines.append("")
    lines.append("calibration body RMS, own (px): " + ", ".join(f"{k} {v:.3f}" for k, v in res["calibration_body_rms_px"].items()))
    lines.append("calibration body RMS, imported (px): " + ", ".join(f"{k} {v:.3f}" for k, v in res["calibration_body_rms_px_imported"].items()))
    lines.append("calibration body RMS, self-calibrated (px): " + ", ".join(
        f"{k} {v:.3f}" for k, v in res["calibration_body_rms_px_self_calibrated"].items()))
    if "selected_body_model" in res:
        lines.append("calibration body, selected model (px): " + ", ".join(
            f"{k} {v['model']} {v['rms_px']:.3f}" for k, v in res["selected_body_model"].items()))
    lines.append("")
    lines.append("self-calibration: " + json.dumps(res["self_calibration"]))
    return "\n".join(lines)


def _fmt(v) -> str:
    return "-" if v is None else (f"{v:.3f}" if isinstance(v, float) else str(v))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--frames", type=int, nargs="+", default=[1, 2, 3, 4])
    ap.add_argument("--rendered", action="store_true",
                    help="instead: rig_sim markers rendered through tilted windows (1224 x 1024 px, 4 cameras), 3-D RMS "
                         "error with and without the window model")
    ap.add_argument("--openptv-check", action="store_true",
                    help="instead: OpenPTV's own correspondences re-triangulated with our import (needs optv)")
    ap.add_argument("--selfcal-seed", choices=("imported", "selected", "selected-ptvpar"), default="imported",
                    help="seed of the volume self-calibration: the imported calibration, or the calibration body with "
                         "the model the dots determine (select_body_model; key selected_body_model), with the media in "
                         "physical order or as ptv.par writes them (selected-ptvpar)")
    ap.add_argument("--body-weight", type=float, default=1.0,
                    help="weight of the body's dot residuals against the particles' in the self-calibration")
    ap.add_argument("--skip-dense", action="store_true",
                    help="development: skip the imported/own/no_refraction matchings (the issue's keys stay empty)")
    ap.add_argument("--temporal-variants", action="store_true",
                    help="also the matching over time with one setting changed at a time (TEMPORAL_VARIANTS; "
                         "about 1 min each)")
    ap.add_argument("--openptv-persistence", action="store_true",
                    help="instead: how many of OpenPTV's own points of frames 2-3 persist as smooth tracks in its "
                         "frames before and after (TEMPORAL's criteria), with a decoy")
    a = ap.parse_args(argv)
    if a.openptv_persistence:
        print(json.dumps(openptv_persistence(), indent=1))
        return 0
    if a.openptv_check:
        print(json.dumps(openptv_check(a.frames), indent=1))
        return 0
    if a.rendered:
        from rig_sim.rendered_window import rendered_window_errors

        e = rendered_window_errors(image_size=(1224, 1024), n_markers=150)
        print(json.dumps(e) if a.json else f"rendered through 10 deg windows: 3-D RMS {e['window'] * 1e6:.2f} um with the "
              f"window model ({e['window_n']} markers), {e['straight'] * 1e6:.0f} um with straight rays")
        return 0
    if not (DATA / "parameters" / "ptv.par").is_file():
        print(f"data not found: {DATA}", file=sys.stderr)
        return 1
    res = run(a.frames, selfcal_seed=a.selfcal_seed, dense=not a.skip_dense, body_weight=a.body_weight,
              variants=a.temporal_variants)
    print(json.dumps(res, indent=1) if a.json else table(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
