"""What the benchmark scripts share (one module; the scripts never import each other).

- The OpenPTV test_cavity data (../shared/data/openptv-test-cavity) and the settings of its benchmarks
  (``bench_real_data``, ``bench_likelihood_matching``, ``bench_mapping_correction``, ``bench_particle_centres``,
  ``bench_same_yardstick``, ``bench_selfcal_variants``): detection, gates, the decoy, the volume self-calibration,
  the matching over time, and the figures of one frame's matching against OpenPTV's own result.
- The matching by likelihood ratio of one detection setting (``run_setting``; benchmarks.research.likelihood_matching),
  measured as ``bench_likelihood_matching`` reports it and ``bench_real_data`` / ``bench_same_yardstick`` reuse it.
- The identification benchmarks' simulated tubes (``simulate``, ``cold_prepare``, the ``--data`` option,
  ``rel_errors``: bench_ident_timing, bench_ident_exact, bench_ident_noise, ab_timing, ident_equality).
"""

from __future__ import annotations

import pickle
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from benchmarks.research import likelihood_matching as L
from benchmarks.research.temporal_matching import persistence_support
from identification import prepare
from reconstruction.correspondence import match_views, observed_pixels
from reconstruction.triangulation import triangulate
from rig_sim.mechanics import PAPER_PARAMETERS, simulate_test
from vfmlab import openptv

ROOT = Path(__file__).resolve().parents[1]

# --- OpenPTV test_cavity -----------------------------------------------------------------------------------------

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
#: matching over time (benchmarks.research.temporal_matching.match_over_time) with the self-calibrated cameras on
#: DETECTION's particles of frames 0-4: 3-D links up to 1 mm per frame (particles move 0.2-1 mm; chance neighbours 1.5-5 mm),
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
    out = match_figures(cor.observations, cor.triangulation, P, tgt, dets, cams)
    if decoy:
        moved = [dets[0] + np.asarray(DECOY_SHIFT_PX), *dets[1:]]
        fake = match_views(moved, cams, bounds=bounds, **(gates or GATES)).observations
        out["our_points_3plus_views_with_cam1"] = with_cam1(cor.observations)
        out["decoy_points_3plus_views_with_cam1"] = with_cam1(fake)
    if straight is None:
        return out
    tri = triangulate(observed_pixels(dets, cor.observations), straight)
    return out, match_figures(cor.observations, tri, P, tgt, dets, straight)


def with_cam1(obs) -> int:
    return int((((obs >= 0).sum(axis=1) >= 3) & (obs[:, 0] >= 0)).sum())


def match_figures(obs, tri, P, tgt, dets, cams) -> dict:
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


def temporal_figures(frame: int, tm, tm_decoy, t: int, dets: list, cams: list) -> dict:
    """The issue's per-frame keys for frame index ``t`` of a TemporalMatch, and the decoy count."""
    obs, X = tm.observations[t], tm.points[t]
    nv = (obs >= 0).sum(axis=1)
    out = {"our_points": int(len(obs)), "our_points_3plus_views": int((nv >= 3).sum()),
           "reprojection_rms_px_ours": float(np.sqrt(np.nanmean(tm.rms[t] ** 2))),
           "our_points_3plus_views_with_cam1": with_cam1(obs),
           "decoy_points_3plus_views_with_cam1": with_cam1(tm_decoy.observations[t]),
           "recovered_from_tracks": int(tm.n_recovered[t]), "candidates": int(tm.n_candidates[t]),
           "candidates_in_smooth_triplets": int(tm.n_supported[t])}
    P, tgt = openptv_result(frame)
    if P is not None:
        out["openptv_points_3plus_views"] = int(((tgt >= 0).sum(axis=1) >= 3).sum())
        out["reprojection_median_px_openptv"] = _openptv_reprojection(P, tgt, dets, cams)
        out["agree_within_0p3mm"] = float(np.mean(cKDTree(X).query(P)[0] <= 0.3e-3)) if len(X) else 0.0
    return out


# --- matching by likelihood ratio (bench_likelihood_matching) ---------------------------------------------

#: candidates' gates (epipolar_px, radius_px, max_residual_px): the matching over time's loose gates
LIKELIHOOD_GATES = (3.0, 2.5, 2.5)
#: threshold of the selection while the true-match model is measured on frame 0 (3 passes, bias map degree 3)
TRAIN_THRESHOLD = 10.0
DEGREE = 3
#: radius of the local detection density (px; None = one density per image: ``--uniform-density``)
DENSITY_RADIUS_PX = 25.0
#: thresholds tried on frame 0 (LLR, nats) and the criterion: decoy <= this fraction of the real count
THRESHOLDS = tuple(np.arange(4.0, 24.01, 0.5))
DECOY_FRACTION = 0.10
#: the inclusive operating point: decoy <= this fraction of the real count on frame 0 (OpenPTV's own >= 3-view points
#: with a camera are 57-77 % chance by the same decoy: bench_same_yardstick.py)
INCLUSIVE_DECOY_FRACTION = 0.30
TRAIN_FRAME = 0
FRAMES = (1, 2, 3, 4)
#: over time: the matching over time's persistence test (TEMPORAL: links <= 1 mm, second difference
#: <= 0.6 mm, residual change <= 0.5 px, motion >= 0.2 mm) and the bonuses (nats) tried on frame 0
PERSISTENCE = {k: TEMPORAL[k] for k in ("max_step_m", "max_accel_m", "max_residual_change_px", "min_motion_m")}
BONUSES = (3.0, 5.0, 8.0)


def detect(setting: str, frame: int) -> list:
    settings = DETECTION if setting == "dense" else {}
    return openptv.detect_frame(DATA, frame, **settings)


def decoy_of(dets: list) -> list:
    return [dets[0] + np.asarray(DECOY_SHIFT_PX), *dets[1:]]


def likelihood_options(gates: tuple = LIKELIHOOD_GATES, density_radius_px: float | None = DENSITY_RADIUS_PX) -> dict:
    """Keyword arguments of ``score_candidates`` / ``fit_true_model``: the candidates' gates (px) and the density
    radius (px; None = one density per image)."""
    return {"gates": tuple(gates), "density_radius_px": density_radius_px}


def scored(frames: dict, cams: list, bounds, model, opts: dict | None = None) -> dict:
    """Per frame: the candidates (with their 3-view subsets) and their LLR, real and decoy. ``opts``:
    :func:`likelihood_options` (default: LIKELIHOOD_GATES, DENSITY_RADIUS_PX)."""
    opts = opts or likelihood_options()
    return {f: tuple(L.score_candidates(d, cams, bounds, model, **opts)[:2] for d in (dets, decoy_of(dets)))
            for f, dets in frames.items()}


def ranked(cands, score) -> dict:
    """Greedy selection without threshold: per accepted match (rank order) its score, views, camera 1, RMS."""
    keep = L.select_by_score(cands.observations, score)
    obs = cands.observations[keep]
    return {"score": score[keep], "views": (obs >= 0).sum(axis=1), "cam1": obs[:, 0] >= 0, "rms": cands.rms[keep],
            "points": cands.points[keep]}


def at_threshold(r: dict, q: dict, T: float) -> dict:
    """Figures of real ``r`` and decoy ``q`` rankings at threshold ``T``."""
    k, kq = r["score"] >= T, q["score"] >= T
    real = int((k & r["cam1"] & (r["views"] >= 3)).sum())
    decoy = int((kq & q["cam1"] & (q["views"] >= 3)).sum())
    return {"threshold": float(T), "our_points_3plus_views": int((k & (r["views"] >= 3)).sum()),
            "our_points_3plus_views_with_cam1": real, "decoy_points_3plus_views_with_cam1": decoy,
            "real_minus_decoy": real - decoy, "decoy_fraction": decoy / max(real, 1),
            "four_view_points": int((k & (r["views"] == 4)).sum()),
            "reprojection_rms_px_ours": float(np.sqrt(np.mean(r["rms"][k] ** 2))) if k.any() else float("nan")}


def with_openptv(row: dict, r: dict, frame: int) -> dict:
    """``row`` (:func:`at_threshold` of the real ranking ``r``) with ``our_points`` and the fraction of OpenPTV's
    points of ``frame`` with one of ours within 0.3 mm (``agree_within_0p3mm``)."""
    X = r["points"][r["score"] >= row["threshold"]]
    P = openptv_result(frame)[0]
    row = {**row, "our_points": int(len(X))}
    if P is not None:
        row["agree_within_0p3mm"] = float(np.mean(cKDTree(X).query(P)[0] <= 0.3e-3)) if len(X) else 0.0
    return row


def choose_threshold(r: dict, q: dict, fraction: float = DECOY_FRACTION) -> float:
    """Of THRESHOLDS, the one with the largest real - decoy on frame 0 among those whose decoy count is <=
    ``fraction`` of the real count (the highest threshold when none is)."""
    rows = [at_threshold(r, q, T) for T in THRESHOLDS]
    ok = [x for x in rows if x["decoy_fraction"] <= fraction]
    return float(max(ok, key=lambda x: x["real_minus_decoy"])["threshold"]) if ok else float(THRESHOLDS[-1])


def one_frame(sc: dict) -> dict:
    """The likelihood matching frame by frame: threshold from frame 0, figures of FRAMES and the sweep."""
    rank = {f: tuple(ranked(*x) for x in pair) for f, pair in sc.items()}
    T = choose_threshold(*rank[TRAIN_FRAME])
    return {"threshold": T, "train_frame": at_threshold(*rank[TRAIN_FRAME], T),
            "per_frame": {str(f): with_openptv(at_threshold(*rank[f], T), rank[f][0], f) for f in FRAMES},
            "sweep": {str(f): [at_threshold(*rank[f], t) for t in THRESHOLDS[::2]] for f in (TRAIN_FRAME, *FRAMES)}}


def over_time(sc: dict, fraction: float = DECOY_FRACTION, bonuses: tuple = BONUSES) -> dict:
    """The likelihood plus PERSISTENCE bonus for the candidates in a smooth triplet (frames 0-4): per bonus of
    ``bonuses`` the threshold from frame 0 (decoy <= ``fraction`` of real); the bonus with the largest real - decoy on
    frame 0."""
    frames = sorted(sc)
    sup = [persistence_support([sc[f][k][0] for f in frames], **PERSISTENCE) for k in (0, 1)]
    best = None
    for bonus in bonuses:
        rank = {f: tuple(ranked(sc[f][k][0], sc[f][k][1] + bonus * (sup[k][i] > 0)) for k in (0, 1))
                for i, f in enumerate(frames)}
        T = choose_threshold(*rank[TRAIN_FRAME], fraction)
        row = {"bonus": bonus, "threshold": T, "train_frame": at_threshold(*rank[TRAIN_FRAME], T),
               "per_frame": {str(f): with_openptv(at_threshold(*rank[f], T), rank[f][0], f) for f in FRAMES}}
        if best is None or row["train_frame"]["real_minus_decoy"] > best["train_frame"]["real_minus_decoy"]:
            best = row
    return best


def run_setting(setting: str, cams: list, bounds, baseline: bool, opts: dict | None = None,
                degree: int = DEGREE) -> dict:
    """The likelihood matching of one detection setting (``dense``: DETECTION; ``ptv``: OpenPTV's) on frames 0-4:
    model and threshold from frame 0, one frame at a time, over time, the inclusive operating point, the decoy's
    own model and (``baseline``) the one-frame matching with SELFCAL_GATES. ``opts``: :func:`likelihood_options`;
    ``degree``: of the bias map."""
    t0 = time.time()
    frames = {f: detect(setting, f) for f in (TRAIN_FRAME, *FRAMES)}
    opts = opts or likelihood_options()
    model = L.fit_true_model(frames[TRAIN_FRAME], cams, bounds, threshold=TRAIN_THRESHOLD, degree=degree, **opts)
    sc = scored(frames, cams, bounds, model, opts)
    out = {"detections_per_camera": {str(f): [len(x) for x in d] for f, d in frames.items()},
           "sigma_px": model.sigma_px.tolist(), "likelihood": one_frame(sc), "likelihood_over_time": over_time(sc)}
    # the inclusive operating point: the same score (bonus included), only the threshold lower
    out["likelihood_inclusive"] = over_time(sc, INCLUSIVE_DECOY_FRACTION, (out["likelihood_over_time"]["bonus"],))
    # check: the decoy with a model measured on its own frame 0 (camera 1 moved there too), the same threshold
    own = L.fit_true_model(decoy_of(frames[TRAIN_FRAME]), cams, bounds, threshold=TRAIN_THRESHOLD, degree=degree,
                           **opts)
    T = out["likelihood"]["threshold"]
    out["decoy_with_its_own_model"] = {str(f): int(at_threshold(
        ranked(*sc[f][0]), ranked(*L.score_candidates(decoy_of(frames[f]), cams, bounds, own, **opts)[:2]), T)
        ["decoy_points_3plus_views_with_cam1"]) for f in FRAMES}
    out["sigma_px_decoy_own_model"] = own.sigma_px.tolist()
    if baseline:
        out["one_frame_selfcal_gates"] = {}
        for f in FRAMES:
            b = frame_figures(f, frames[f], cams, gates=SELFCAL_GATES, decoy=True)
            out["one_frame_selfcal_gates"][str(f)] = {k: b[k] for k in (
                "our_points_3plus_views", "our_points_3plus_views_with_cam1", "decoy_points_3plus_views_with_cam1",
                "reprojection_rms_px_ours")}
    out["seconds"] = time.time() - t0
    return out


# --- identification: the simulated tubes --------------------------------------------------------------------------

NEOHOOKEAN = {"mu": 200e3}  # no paper value; stiff enough to pass 150 mmHg without a limit point


def params_of(model):
    """The parameters the benchmarks simulate ``model`` with: the paper's, NEOHOOKEAN for the neo-Hookean."""
    return NEOHOOKEAN if model == "neohookean" else PAPER_PARAMETERS[model]


class _ClampedReference:
    """The fields of rig_sim's SimulatedTest that the benchmark uses, from rig_sim/clamped_reference.py."""

    def __init__(self, model):
        from rig_sim.clamped_reference import clamped_tube

        pos, p, f = clamped_tube(model, params_of(model), np.array([15.0, 30.0, 45.0, 60.0, 75.0, 90.0]) * 133.322387415)
        self.positions = self.exact_positions = pos
        self.pressure, self.axial_force, self.thickness = p, f, 1.3e-3


def simulate(model, *, clamped: bool = True, wall: str = "membrane", synth: bool = False):
    """rig_sim's tube of ``model`` at its paper parameters (300 markers; ``clamped`` ends or free), or with
    ``synth`` (clamped membrane only) the independent clamped-tube solver's (6 pressures, 15-90 mmHg)."""
    if clamped and synth and wall == "membrane":
        return _ClampedReference(model)
    return simulate_test(model, params_of(model), clamped=clamped, wall=wall, n_markers=300)


def cold_prepare(sim, *, clamped: bool = True, **options):
    """``prepare`` without the in-process mesh and surface-state caches (what a first run pays)."""
    import identification.vfm as vfm

    getattr(vfm, "_MESH_CACHE", {}).clear()
    getattr(vfm, "_STATE_CACHE", {}).clear()
    return prepare(sim.positions, sim.pressure, sim.axial_force, thickness=sim.thickness,
                   ends="clamped" if clamped else "free", **options)


def add_data_argument(ap) -> None:
    """The ``--data`` option of the identification benchmarks: clamped ends unless "homogeneous"; "clamped-synth"
    is ``simulate(..., synth=True)``."""
    ap.add_argument("--data", choices=["clamped", "clamped-synth", "homogeneous"], default="clamped",
                    help="membrane tube clamped on cannulae (rig_sim, default; or the tests' independent solver, "
                         "6 pressures 15-90 mmHg) or homogeneous")


def rel_errors(result, truth):
    """Relative error of each of ``truth``'s parameters in ``result.parameters``: {name: estimate / truth - 1}."""
    return {k: result.parameters[k] / truth[k] - 1.0 for k in truth}
