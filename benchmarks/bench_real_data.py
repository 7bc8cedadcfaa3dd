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
- ``temporal``: matching over time with the self-calibrated cameras (reconstruction.temporal_matching.match_over_time,
  TEMPORAL) on DETECTION's particles of frames 0-4: a >= 3-camera match is kept when it persists as a smooth track
  with a constant residual per camera; the decoy runs through the same pipeline. ``temporal_diagnostics``: the same
  without the pixel correction, the correction's size, the true matches with camera 1 estimated among one frame's
  candidates and, with ``--temporal-variants``, one setting changed at a time;
- ``likelihood``, ``likelihood_over_time``, ``likelihood_inclusive``: matching by likelihood ratio with the
  self-calibrated cameras on DETECTION's particles (reconstruction.likelihood_matching, bench_likelihood_matching.py:
  model, threshold and persistence bonus chosen on frame 0, the decoy through the same pipeline): one frame at a
  time and over time with the decoy <= 10 % of the real count on frame 0, and over time at the inclusive operating
  point (decoy <= 30 %).

    python benchmarks/bench_real_data.py [--json] [--frames 1 2 3 4]
    python benchmarks/bench_real_data.py --selfcal-seed selected-ptvpar --body-weight 0.5 --skip-dense --frames 1
        # self-calibration seeded by the body calibration with the model its dots determine (select_body_model)
    python benchmarks/bench_real_data.py --selfcal-seed selected-ptvpar --body-weight 0.5 --skip-dense --temporal-variants
        # key temporal: matching over time (reconstruction.temporal_matching) with the self-calibrated cameras
    python benchmarks/bench_real_data.py --rendered   # rig_sim window renderer instead
    python benchmarks/bench_real_data.py --openptv-check   # OpenPTV's own matches, re-triangulated (needs optv)
    python benchmarks/bench_real_data.py --openptv-persistence   # how many of OpenPTV's points persist over time
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from reconstruction.correspondence import match_views, observed_pixels  # noqa: E402
from reconstruction.triangulation import triangulate  # noqa: E402
from vfmlab import openptv  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "openptv-test-cavity"
#: correspondence gates (px) and particle detection: denser than vfmlab.openptv.PARTICLE_SETTINGS (OpenPTV's own
#: targ_rec thresholds), which the CI test uses on frame 1 with tighter gates to stay fast. Touching particles are
#: split at their peaks (as OpenPTV does: 78-82 % of its detections within 1 px of ours, 57-69 % without); the
#: cameras face each other in pairs, so opposite pairs seed candidates too (OpenPTV's 2-view points are mostly such).
GATES = {"epipolar_px": 2.0, "max_reprojection_px": 1.3, "max_pair_angle_deg": 180.0}
DETECTION = {"threshold": 6.0, "min_sum": 100.0, "pixels_range": (3, 500), "split_touching": True}
#: decoy: camera 1's detections moved by this (px) before matching; what is still matched with camera 1 is chance
DECOY_SHIFT_PX = (20.0, 13.0)
#: volume self-calibration of the imported calibration: OpenPTV's particle settings (fewer, brighter particles than
#: DETECTION: fewer chance candidates), frames 0-4, the box of OpenPTV's points (1st-99th percentile, 5 mm margin),
#: and the settings of `vfmlab calibrate --self-calibrate` (openptv.SELFCAL_SETTINGS: 2 x 2 x 2 sub-volumes; pose, k1,
#: principal point and window tilt refined per camera with the body's dots; the body as the cameras on its far side
#: see it offset along its normal)
SELFCAL_FRAMES = (0, 1, 2, 3, 4)
SELFCAL = openptv.SELFCAL_SETTINGS
#: matching after the self-calibration: the same particles, gates tighter than GATES (at DETECTION's density and
#: GATES, chance coincidences dominate whatever the calibration); the imported calibration is matched the same way
SELFCAL_GATES = {"epipolar_px": 1.5, "max_reprojection_px": 1.0, "max_pair_angle_deg": 180.0}
TIGHT_GATES = {"epipolar_px": 1.0, "max_reprojection_px": 0.7, "max_pair_angle_deg": 180.0}
#: matching over time (reconstruction.temporal_matching.match_over_time) with the self-calibrated cameras on DETECTION's
#: particles of frames 0-4: 3-D links up to 1 mm per frame (particles move 0.2-1 mm; chance neighbours 1.5-5 mm),
#: second difference <= 0.6 mm (depth noise of 3-view points; 0.4 mm: 8-14 % fewer real matches), residual per
#: camera changing <= 0.5 px per frame, >= 0.2 mm of motion over a triplet (a static chance match persists as well
#: as a true one); a pixel correction map (degree 3) fit on the matches with loose gates (epipolar, radius,
#: residual px), then the final gates
TEMPORAL_FRAMES = (0, 1, 2, 3, 4)
TEMPORAL = {"max_step_m": 1e-3, "max_accel_m": 0.6e-3, "max_residual_change_px": 0.5, "min_motion_m": 0.2e-3,
            "loose_gates": (3.0, 2.5, 2.5), "gates": (2.0, 1.5, 1.5), "degree": 3}


def openptv_result(frame: int):
    path = DATA / "res" / f"rt_is.1000{frame}"
    return openptv.read_rt_is(path) if path.is_file() else (None, None)


def frame_figures(frame: int, dets: list, cams: list, straight: list | None = None,
                  gates: dict | None = None, decoy: bool = False) -> dict | tuple[dict, dict]:
    """Figures of one frame with ``cams``; with ``straight`` also those of the same matches triangulated
    with straight rays (returned second). ``gates``: correspondence gates (default GATES). ``decoy``: also
    match once more with camera 1's detections moved by DECOY_SHIFT_PX, and report the points with >= 3
    views including camera 1 in both runs (``*_3plus_views_with_cam1``): the decoy count is what chance
    coincidences alone give at this particle density, calibration and gates."""
    P, tgt = openptv_result(frame)
    bounds = None if P is None else (P.min(0) - 5e-3, P.max(0) + 5e-3)
    cor = match_views(dets, cams, bounds=bounds, **(gates or GATES))
    out = _figures(cor.observations, cor.triangulation, P, tgt, dets, cams)
    if decoy:
        moved = [dets[0] + np.asarray(DECOY_SHIFT_PX), *dets[1:]]
        fake = match_views(moved, cams, bounds=bounds, **(gates or GATES)).observations
        out["our_points_3plus_views_with_cam1"] = _with_cam1(cor.observations)
        out["decoy_points_3plus_views_with_cam1"] = _with_cam1(fake)
    if straight is None:
        return out
    tri = triangulate(observed_pixels(dets, cor.observations), straight)
    return out, _figures(cor.observations, tri, P, tgt, dets, straight)


def _with_cam1(obs) -> int:
    return int((((obs >= 0).sum(axis=1) >= 3) & (obs[:, 0] >= 0)).sum())


def _figures(obs, tri, P, tgt, dets, cams) -> dict:
    nv = (obs >= 0).sum(axis=1)
    out = {"our_points": int(len(nv)), "our_points_3plus_views": int((nv >= 3).sum()),
           "reprojection_rms_px_ours": float(np.sqrt(np.nanmean(tri.reprojection_rms**2)))}
    if P is not None:
        out["openptv_points_3plus_views"] = int(((tgt >= 0).sum(axis=1) >= 3).sum())
        out["reprojection_median_px_openptv"] = _openptv_reprojection(P, tgt, dets, cams)
        d = cKDTree(tri.points[np.all(np.isfinite(tri.points), axis=1)]).query(P)[0]
        out["agree_within_0p3mm"] = float(np.mean(d <= 0.3e-3))
    return out


def _openptv_reprojection(P, tgt, dets, cams) -> float:
    """Median distance (px) from OpenPTV's points, projected with ``cams``, to our nearest detection in the
    cameras OpenPTV says saw them (its own detection lists are not in the data set)."""
    d = []
    for c, cam in enumerate(cams):
        seen = tgt[:, c] >= 0
        pp = cam.project(P[seen])
        fin = np.all(np.isfinite(pp), axis=1)
        d.append(cKDTree(dets[c]).query(pp[fin])[0])
    return float(np.median(np.concatenate(d)))


def selected_body_calibration(imported: list, physical_media: bool = True) -> tuple[list, dict]:
    """Per camera, :func:`reconstruction.calibration_body.select_body_model` on the refined dots of
    ``cal/camN.tif`` (matched as ``openptv.calibrate_body_folder`` does), seeded by the imported camera with
    PHYSICAL_MEDIA (``physical_media``; else ptv.par's as written): only the terms the body's dots determine
    over the whole image are refined, the others keep the imported values. Returns the cameras and per camera
    the chosen model, its body RMS (px), the candidates' figures and the change of the projection at the image corners vs ``imported`` (px)."""
    sel = openptv.select_body_folder(DATA, imported, media=openptv.PHYSICAL_MEDIA if physical_media else None)
    cams = [s.calibration.camera for s in sel]
    info = {seed.name: {"model": s.chosen, "rms_px": s.calibration.rms,
                        "corner_distortion_change_px": corner_distortion_change(s.calibration.camera, seed),
                        "candidates": s.table} for seed, s in zip(imported, sel)}
    return cams, info


def corner_distortion_change(cam, ref) -> float:
    """Largest change (px) at the four image corners of the distortion displacement (distorted minus
    pinhole pixel, each camera's own K and distortion) of ``cam`` vs ``ref``."""
    from reconstruction.cameras import project_points

    W, H = ref.image_size
    u = np.array([[0, 0], [W - 1, 0], [0, H - 1], [W - 1, H - 1]], float)

    def disp(c):
        K = c.K
        x = np.c_[(u[:, 0] - K[0, 2]) / K[0, 0], (u[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(u))]
        return project_points(K, c.dist, x) - u

    return float(np.max(np.linalg.norm(disp(cam) - disp(ref), axis=1)))


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
    from benchmarks.research.temporal_matching import match_over_time

    bounds = selfcal_bounds()
    dets = [openptv.detect_frame(DATA, f, **DETECTION) for f in TEMPORAL_FRAMES]
    decoy = [[d[0] + np.asarray(DECOY_SHIFT_PX), *d[1:]] for d in dets]
    out = {}
    for name, change in TEMPORAL_VARIANTS.items():
        opts = {**TEMPORAL, **change}
        tm, tm_decoy = match_over_time(dets, cams, bounds, **opts)[0], match_over_time(decoy, cams, bounds, **opts)[0]
        out[name] = {str(f): {"our_points_3plus_views": int(((tm.observations[t] >= 0).sum(1) >= 3).sum()),
                              "our_points_3plus_views_with_cam1": _with_cam1(tm.observations[t]),
                              "decoy_points_3plus_views_with_cam1": _with_cam1(tm_decoy.observations[t]),
                              "reprojection_rms_px_ours": float(np.sqrt(np.nanmean(tm.rms[t] ** 2)))}
                     for f in frames for t in [TEMPORAL_FRAMES.index(f)]}
    return out


def temporal(frames: list[int], cams: list) -> tuple[dict, dict]:
    """Matching over time (TEMPORAL) with ``cams`` on DETECTION's particles of TEMPORAL_FRAMES, the same with
    camera 1's detections moved by DECOY_SHIFT_PX in every frame (the whole pipeline, correction included), per
    frame of ``frames``; diagnostics: without the pixel correction, the correction's size, and per frame the
    true >= 3-view matches with camera 1 among the single-frame candidates (estimated from the decoy)."""
    from benchmarks.research.temporal_matching import match_over_time

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
        out[str(f)] = _temporal_figures(f, tm, tm_decoy, t, corrected[t], cams)
        (m0, c0, _), d0 = runs["no_correction"]
        diag["no_correction"][str(f)] = _temporal_figures(f, m0, d0, t, c0[t], cams)
        diag["candidates_with_cam1"][str(f)] = _true_candidates(dets[t], decoy[t], cams, bounds)
    return out, diag


def likelihood_matching(frames: list[int], cams: list) -> tuple[dict, dict, dict]:
    """Matching by likelihood ratio (benchmarks/bench_likelihood_matching.py, DETECTION's particles; model and
    threshold measured on frame 0, the decoy through the same pipeline), per frame of ``frames`` in 1-4: one frame
    at a time, with the persistence bonus (frames 0-4), and the same at the inclusive operating point (decoy <= 30 %
    of real on frame 0)."""
    import bench_likelihood_matching as BL

    res = BL.run_setting("dense", cams, selfcal_bounds(), baseline=False)
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
    from benchmarks.research.temporal_matching import apply_pixel_correction

    grids = [np.stack(np.meshgrid(np.linspace(0, W - 1, 33), np.linspace(0, H - 1, 33)), -1).reshape(-1, 2)
             for W, H in sizes]
    moved = apply_pixel_correction(grids, coef, sizes)
    return [float(np.max(np.linalg.norm(m - g, axis=1))) for m, g in zip(moved, grids)]


def _temporal_figures(frame: int, tm, tm_decoy, t: int, dets: list, cams: list) -> dict:
    """The issue's per-frame keys for frame index ``t`` of a TemporalMatch, and the decoy count."""
    obs, X = tm.observations[t], tm.points[t]
    nv = (obs >= 0).sum(axis=1)
    out = {"our_points": int(len(obs)), "our_points_3plus_views": int((nv >= 3).sum()),
           "reprojection_rms_px_ours": float(np.sqrt(np.nanmean(tm.rms[t] ** 2))),
           "our_points_3plus_views_with_cam1": _with_cam1(obs),
           "decoy_points_3plus_views_with_cam1": _with_cam1(tm_decoy.observations[t]),
           "recovered_from_tracks": int(tm.n_recovered[t]), "candidates": int(tm.n_candidates[t]),
           "candidates_in_smooth_triplets": int(tm.n_supported[t])}
    P, tgt = openptv_result(frame)
    if P is not None:
        out["openptv_points_3plus_views"] = int(((tgt >= 0).sum(axis=1) >= 3).sum())
        out["reprojection_median_px_openptv"] = _openptv_reprojection(P, tgt, dets, cams)
        out["agree_within_0p3mm"] = float(np.mean(cKDTree(X).query(P)[0] <= 0.3e-3)) if len(X) else 0.0
    return out


def _true_candidates(dets: list, decoy: list, cams: list, bounds) -> dict:
    """Single-frame candidates (frame_candidates) with camera 1, per gate set (epipolar, radius, residual px): camera 1
    detections taking part, real and decoy, and the true ones estimated as (real - decoy) / (1 - decoy / n_cam1)
    (a detection with a true match also takes part by chance at the decoy's rate)."""
    from benchmarks.research.temporal_matching import frame_candidates

    out = {}
    for g in (TEMPORAL["gates"], TEMPORAL["loose_gates"]):
        n = []
        for d in (dets, decoy):
            obs = frame_candidates(d, cams, bounds, epipolar_px=g[0], radius_px=g[1], max_residual_px=g[2]).observations
            n.append(len(np.unique(obs[obs[:, 0] >= 0, 0])))
        out["/".join(f"{v:g}" for v in g)] = {"cam1_detections_real": n[0], "cam1_detections_decoy": n[1],
                                              "true_estimate": float((n[0] - n[1]) / (1 - n[1] / len(dets[0])))}
    return out


def selfcal_bounds() -> tuple[np.ndarray, np.ndarray]:
    """The box of OpenPTV's points of frames 1-4 (1st-99th percentile) with a 5 mm margin, m."""
    P = np.concatenate([openptv_result(f)[0] for f in range(1, 5)])
    return np.percentile(P, 1, axis=0) - 5e-3, np.percentile(P, 99, axis=0) + 5e-3


def _summary(m) -> dict:
    return {"peak_rms_px": m.rms_peak_offset_px, "peak_max_px": m.max_peak_offset_px,
            "peak_height_over_mean_median": float(np.nanmedian(m.peak_height)), "candidates": int(m.counts[0].sum())}


def self_calibration(cams: list, body_px: np.ndarray, pts: np.ndarray, body_weight: float = 1.0):
    """:func:`reconstruction.volume_selfcal.self_calibrate` of ``cams`` (the imported calibration) with the
    body's dots ``body_px`` (``(4, n_body, 2)`` px) at ``pts`` on SELFCAL_FRAMES; returns it and its diagnostics."""
    from reconstruction.volume_selfcal import self_calibrate

    frames = [openptv.detect_frame(DATA, f) for f in SELFCAL_FRAMES]
    sc = self_calibrate(frames, cams, selfcal_bounds(), pts, body_px, body_weight=body_weight, **SELFCAL)
    passes = [{"tolerances_px": list(t), "candidates": n, "consistent": u, "particle_rms_px": r,
               "disparity_before": _summary(m)}
              for t, n, u, r, m in zip(SELFCAL["schedule"], sc.n_candidates, sc.n_used, sc.particle_rms_px, sc.maps)]
    return sc, {"message": sc.message, "passes": passes, "disparity_after_last_tolerances": _summary(sc.maps[-1]),
                "check_first_tolerances": {"before": _summary(sc.maps[0]), "after": _summary(sc.check_map)},
                "tight_gates": {}, "imported_same_matching": {}}


def self_calibrated_cameras(seed: str = "selected-ptvpar", body_weight: float = 0.5,
                            pickle_path: str | None = None) -> list:
    """The self-calibrated cameras as :func:`run` makes them (``seed``, ``body_weight``; 2-3 min), or those saved in
    ``pickle_path`` (a pickle of a dict with key ``cameras``: skips the self-calibration while developing)."""
    if pickle_path:
        with open(pickle_path, "rb") as f:
            return pickle.load(f)["cameras"]
    imported = openptv.load_cameras(DATA)
    pts, body_px = openptv.body_dots(DATA, imported)
    seed_cams = imported
    if seed.startswith("selected"):
        seed_cams = selected_body_calibration(imported, seed == "selected")[0]
    return self_calibration(seed_cams, body_px, pts, body_weight)[0].cameras


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
    from benchmarks.research.temporal_matching import link_frames, smooth_triplets

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
        sys.path.insert(0, str(ROOT / "tests"))
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
