"""Matching by likelihood ratio on OpenPTV test_cavity (issue 14; reconstruction.likelihood_matching).

Cameras: the benchmark's volume self-calibration (``bench_real_data.py --selfcal-seed selected-ptvpar --body-weight
0.5``: seed = the body calibration with the terms its dots determine, frames 0-4, body sides), or a cached copy
(``--cameras PICKLE``: a dict with key ``cameras``, as ``make_selfcal_cache.py`` writes it).

Per detection setting (``dense`` = bench_real_data.DETECTION, 2,900-4,100 particles per image; ``ptv`` = OpenPTV's
particle settings, 780-1,350):

1. **Frame 0 only** (not reported below): the true-match model (bias map of degree 3 and per-camera scatter,
   ``fit_true_model``, TRAIN_THRESHOLD) is measured on the real detections; then the threshold is chosen on frame 0
   by the stated criterion: of THRESHOLDS, the one with the largest real - decoy among those whose decoy count
   (camera 1's detections moved by DECOY_SHIFT_PX, scored with the same frozen model) is <= DECOY_FRACTION of the
   real count (>= 3-view matches with camera 1).
2. **Frames 1-4**: the real detections and the decoy run through the identical pipeline with that frozen model and
   threshold: >= 3-view points with camera 1 (real, decoy), points seen by >= 3 cameras, reprojection RMS (on the
   detections moved by the bias map, px). Also the whole threshold sweep (key ``sweep``).
3. Baseline: the one-frame matching of the benchmark (``match_views`` with SELFCAL_GATES, bench_real_data.frame_figures)
   on the same detections, with its decoy (``--no-baseline`` skips it; for ``dense`` it takes ~1 min per frame).
4. Over time (``likelihood_over_time``): the same scores plus a bonus for the candidates in a smooth triplet of
   frames 0-4 (the matching over time's persistence test, PERSISTENCE); bonus (BONUSES) and threshold chosen on
   frame 0 (the bonus with the largest real - decoy there at its threshold by the same criterion).
5. Check of the decoy: the decoy's frame 0 measures its own model (camera 1's detections moved there too), scored
   at the same threshold (key ``decoy_with_its_own_model``).

    PYTHONPATH=$PWD python benchmarks/bench_likelihood_matching.py [--json] [--cameras PICKLE] [--detections dense ptv]
        [--no-baseline] [--gates 3 2.5 2.5] [--degree 3] [--uniform-density]   # the last three: what each part adds

The selection with a threshold is the prefix of the greedy selection without one (ranked by score, each
detection once), so one scoring per frame gives every threshold.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_real_data as B  # noqa: E402
from benchmarks.research import likelihood_matching as L  # noqa: E402
from benchmarks.research.temporal_matching import persistence_support  # noqa: E402
from vfmlab import openptv  # noqa: E402

#: candidates' gates (epipolar_px, radius_px, max_residual_px): the matching over time's loose gates
GATES = (3.0, 2.5, 2.5)
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
#: over time: the matching over time's persistence test (bench_real_data.TEMPORAL: links <= 1 mm, second difference
#: <= 0.6 mm, residual change <= 0.5 px, motion >= 0.2 mm) and the bonuses (nats) tried on frame 0
PERSISTENCE = {k: B.TEMPORAL[k] for k in ("max_step_m", "max_accel_m", "max_residual_change_px", "min_motion_m")}
BONUSES = (3.0, 5.0, 8.0)


def cameras(path: str | None) -> tuple[list, str]:
    """The self-calibrated cameras: from the pickle ``path``, or computed as bench_real_data does (2-3 min)."""
    cams = B.self_calibrated_cameras(pickle_path=path)
    return cams, f"cached: {Path(path).name}" if path else "self-calibrated (seed selected-ptvpar, body weight 0.5)"


def detect(setting: str, frame: int) -> list:
    settings = B.DETECTION if setting == "dense" else {}
    return openptv.detect_frame(B.DATA, frame, **settings)


def decoy_of(dets: list) -> list:
    return [dets[0] + np.asarray(B.DECOY_SHIFT_PX), *dets[1:]]


def scored(frames: dict, cams: list, bounds, model) -> dict:
    """Per frame: the candidates (with their 3-view subsets) and their LLR, real and decoy."""
    opts = {"gates": GATES, "density_radius_px": DENSITY_RADIUS_PX}
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
    P = B.openptv_result(frame)[0]
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


def run_setting(setting: str, cams: list, bounds, baseline: bool) -> dict:
    t0 = time.time()
    frames = {f: detect(setting, f) for f in (TRAIN_FRAME, *FRAMES)}
    opts = {"gates": GATES, "density_radius_px": DENSITY_RADIUS_PX}
    model = L.fit_true_model(frames[TRAIN_FRAME], cams, bounds, threshold=TRAIN_THRESHOLD, degree=DEGREE, **opts)
    sc = scored(frames, cams, bounds, model)
    out = {"detections_per_camera": {str(f): [len(x) for x in d] for f, d in frames.items()},
           "sigma_px": model.sigma_px.tolist(), "likelihood": one_frame(sc), "likelihood_over_time": over_time(sc)}
    # the inclusive operating point: the same score (bonus included), only the threshold lower
    out["likelihood_inclusive"] = over_time(sc, INCLUSIVE_DECOY_FRACTION, (out["likelihood_over_time"]["bonus"],))
    # check: the decoy with a model measured on its own frame 0 (camera 1 moved there too), the same threshold
    own = L.fit_true_model(decoy_of(frames[TRAIN_FRAME]), cams, bounds, threshold=TRAIN_THRESHOLD, degree=DEGREE,
                           **opts)
    T = out["likelihood"]["threshold"]
    out["decoy_with_its_own_model"] = {str(f): int(at_threshold(
        ranked(*sc[f][0]), ranked(*L.score_candidates(decoy_of(frames[f]), cams, bounds, own, **opts)[:2]), T)
        ["decoy_points_3plus_views_with_cam1"]) for f in FRAMES}
    out["sigma_px_decoy_own_model"] = own.sigma_px.tolist()
    if baseline:
        out["one_frame_selfcal_gates"] = {}
        for f in FRAMES:
            b = B.frame_figures(f, frames[f], cams, gates=B.SELFCAL_GATES, decoy=True)
            out["one_frame_selfcal_gates"][str(f)] = {k: b[k] for k in (
                "our_points_3plus_views", "our_points_3plus_views_with_cam1", "decoy_points_3plus_views_with_cam1",
                "reprojection_rms_px_ours")}
    out["seconds"] = time.time() - t0
    return out


def table(res: dict) -> str:
    lines = [f"cameras: {res['cameras']}; gates {GATES} px; model and threshold from frame {TRAIN_FRAME} "
             f"(decoy <= {DECOY_FRACTION:.0%} of real)", "",
             "| detections | matching | frame | points seen by >= 3 cameras | >= 3-view with camera 1, real vs decoy "
             "| real - decoy | decoy fraction | reprojection RMS (px) |", "|---|---|---|---|---|---|---|---|"]
    for s, o in res["settings"].items():
        lk, ot, inc = o["likelihood"], o["likelihood_over_time"], o["likelihood_inclusive"]
        rows = [("likelihood, LLR >= %g" % lk["threshold"], lk["per_frame"]),
                ("likelihood + persistence %g, >= %g" % (ot["bonus"], ot["threshold"]), ot["per_frame"]),
                ("inclusive (decoy <= %.0f %%): persistence %g, >= %g" % (100 * INCLUSIVE_DECOY_FRACTION, inc["bonus"],
                                                                       inc["threshold"]), inc["per_frame"])]
        if "one_frame_selfcal_gates" in o:
            rows.append(("one frame, SELFCAL_GATES", o["one_frame_selfcal_gates"]))
        for name, per in rows:
            for f, r in per.items():
                a, b = r["our_points_3plus_views_with_cam1"], r["decoy_points_3plus_views_with_cam1"]
                lines.append(f"| {s} | {name} | {f} | {r['our_points_3plus_views']} | {a} vs {b} | {a - b} | "
                             f"{b / max(a, 1):.3f} | {r['reprojection_rms_px_ours']:.3f} |")
    for s, o in res["settings"].items():
        lines.append("")
        lines.append(f"{s}: sigma per camera {np.round(o['sigma_px'], 3).tolist()} px; frame {TRAIN_FRAME} at the "
                     f"threshold: {json.dumps(o['likelihood']['train_frame'])}; over time: "
                     f"{json.dumps(o['likelihood_over_time']['train_frame'])}")
        lines.append(f"{s}: decoy with a model measured on its own frame {TRAIN_FRAME}, same threshold: "
                     f"{o['decoy_with_its_own_model']} (sigma "
                     f"{np.round(o['sigma_px_decoy_own_model'], 3).tolist()} px)")
        lines.append(f"{s}, sweep (threshold: real vs decoy with camera 1):")
        for f, rows in o["likelihood"]["sweep"].items():
            lines.append(f"  frame {f}: " + ", ".join(f"{r['threshold']:g}: {r['our_points_3plus_views_with_cam1']} vs "
                                                     f"{r['decoy_points_3plus_views_with_cam1']}" for r in rows))
    return "\n".join(lines)


def main(argv=None) -> int:
    global GATES, DEGREE, DENSITY_RADIUS_PX
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--cameras", help="pickle with the self-calibrated cameras (key 'cameras'); default: compute them")
    ap.add_argument("--detections", nargs="+", choices=("dense", "ptv"), default=["dense", "ptv"])
    ap.add_argument("--no-baseline", action="store_true", help="skip the one-frame matching with SELFCAL_GATES")
    ap.add_argument("--gates", type=float, nargs=3, default=GATES, metavar=("EPIPOLAR", "RADIUS", "RESIDUAL"),
                    help="candidates' gates, px (default %(default)s)")
    ap.add_argument("--degree", type=int, default=DEGREE, help="degree of the bias map (0: none)")
    ap.add_argument("--uniform-density", action="store_true", help="one detection density per image, not local")
    a = ap.parse_args(argv)
    GATES, DEGREE = tuple(a.gates), a.degree
    DENSITY_RADIUS_PX = None if a.uniform_density else DENSITY_RADIUS_PX
    if not (B.DATA / "parameters" / "ptv.par").is_file():
        print(f"data not found: {B.DATA}", file=sys.stderr)
        return 1
    cams, how = cameras(a.cameras)
    bounds = B.selfcal_bounds()
    res = {"cameras": how, "gates_px": list(GATES), "degree": DEGREE, "density_radius_px": DENSITY_RADIUS_PX,
           "settings": {}}
    for s in a.detections:
        res["settings"][s] = run_setting(s, cams, bounds, not a.no_baseline)
    print(json.dumps(res, indent=1) if a.json else table(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
