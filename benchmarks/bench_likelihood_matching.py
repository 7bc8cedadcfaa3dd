"""Matching by likelihood ratio on OpenPTV test_cavity (issue 14; benchmarks.research.likelihood_matching).

Cameras: the benchmark's volume self-calibration (``bench_real_data --selfcal-seed selected-ptvpar --body-weight
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

    python -m benchmarks.bench_likelihood_matching [--json] [--cameras PICKLE] [--detections dense ptv]
        [--no-baseline] [--gates 3 2.5 2.5] [--degree 3] [--uniform-density]   # the last three: what each part adds

The selection with a threshold is the prefix of the greedy selection without one (ranked by score, each
detection once), so one scoring per frame gives every threshold.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from benchmarks._common import (DATA, DECOY_FRACTION, DEGREE, DENSITY_RADIUS_PX, INCLUSIVE_DECOY_FRACTION,
                                LIKELIHOOD_GATES, TRAIN_FRAME, likelihood_options, run_setting, self_calibrated_cameras,
                                selfcal_bounds)


def cameras(path: str | None) -> tuple[list, str]:
    """The self-calibrated cameras: from the pickle ``path``, or computed as bench_real_data does (2-3 min)."""
    cams = self_calibrated_cameras(pickle_path=path)
    return cams, f"cached: {Path(path).name}" if path else "self-calibrated (seed selected-ptvpar, body weight 0.5)"


def table(res: dict) -> str:
    lines = [f"cameras: {res['cameras']}; gates {tuple(res['gates_px'])} px; model and threshold from frame "
             f"{TRAIN_FRAME} "
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
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--cameras", help="pickle with the self-calibrated cameras (key 'cameras'); default: compute them")
    ap.add_argument("--detections", nargs="+", choices=("dense", "ptv"), default=["dense", "ptv"])
    ap.add_argument("--no-baseline", action="store_true", help="skip the one-frame matching with SELFCAL_GATES")
    ap.add_argument("--gates", type=float, nargs=3, default=LIKELIHOOD_GATES,
                    metavar=("EPIPOLAR", "RADIUS", "RESIDUAL"),
                    help="candidates' gates, px (default %(default)s)")
    ap.add_argument("--degree", type=int, default=DEGREE, help="degree of the bias map (0: none)")
    ap.add_argument("--uniform-density", action="store_true", help="one detection density per image, not local")
    a = ap.parse_args(argv)
    gates, degree = tuple(a.gates), a.degree
    radius = None if a.uniform_density else DENSITY_RADIUS_PX
    opts = likelihood_options(gates, radius)
    if not (DATA / "parameters" / "ptv.par").is_file():
        print(f"data not found: {DATA}", file=sys.stderr)
        return 1
    cams, how = cameras(a.cameras)
    bounds = selfcal_bounds()
    res = {"cameras": how, "gates_px": list(gates), "degree": degree, "density_radius_px": radius,
           "settings": {}}
    for s in a.detections:
        res["settings"][s] = run_setting(s, cams, bounds, not a.no_baseline, opts, degree)
    print(json.dumps(res, indent=1) if a.json else table(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
