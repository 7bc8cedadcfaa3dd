"""The same yardstick for OpenPTV and for us: how many of the >= 3-view points are real (test_cavity, frames 1-4).

The issue compares our count of points seen by >= 3 cameras with OpenPTV's (``res/rt_is``). A count says nothing
of how many of the points are real particles. This benchmark measures both tools the same way:

1. match the frame as the tool does (OpenPTV: its own ``target_recognition`` and ``correspondences`` through
   ``optv``, test extra, with the data set's parameter files: every >= 3-view point of ``rt_is`` comes back, and all
   its rows in frames 1-2; ``rt_is_rows_reproduced``);
2. match it again with camera k's detections moved by DECOY_SHIFT_PX (20, 13 px): whatever is still matched with
   camera k is chance;
3. per camera k: R = >= 3-view points with camera k, D = the same in the decoy run, n = camera k's detections;
   estimated real points with camera k ``T = (R - D) / (1 - D / n)`` (a detection without a true match takes part
   by chance at the decoy's rate D / n); the chance share D / R.

Ours: the one-frame matching (``match_views``) with the volume-self-calibrated cameras (as ``bench_real_data.py``:
seed ``--selfcal-seed``, ``--body-weight``; about 2 min) at two operating points, OPERATING_POINTS: ``precise`` (the
benchmark's ``self_calibrated`` rows: OpenPTV's particle settings, gates 1.5 / 1.0 px) and ``dense`` (touching
particles split, 7 grey levels: about OpenPTV's chance share); and the matching over time (``over_time``:
``bench_real_data.temporal``'s, the decoy camera moved in every frame) and the matching by likelihood ratio
(``likelihood``, ``likelihood_over_time``, ``likelihood_inclusive``: ``bench_likelihood_matching.py``'s, frozen on
frame 0).

    python -m benchmarks.bench_same_yardstick [--json] [--frames 1 2 3 4]   # needs optv; 4-6 min
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np


from benchmarks import _common as B
from reconstruction.correspondence import match_views
from vfmlab import openptv

#: our operating points: particle detection (on top of openptv.PARTICLE_SETTINGS) and correspondence gates
OPERATING_POINTS = {
    "precise": ({}, B.SELFCAL_GATES),
    "dense": ({"split_touching": True, "threshold": 7.0}, B.SELFCAL_GATES),
}


def true_estimate(real: int, decoy: int, n_detections: int) -> float:
    """Real >= 3-view points with a camera, estimated from the decoy: ``(R - D) / (1 - D / n)``."""
    return float((real - decoy) / (1.0 - decoy / n_detections)) if n_detections else 0.0


def per_camera(real_obs: np.ndarray, decoy_obs: list[np.ndarray], n_detections: list[int]) -> dict:
    """The yardstick of one matching: ``real_obs`` ``(n_points, n_cameras)`` detection ids (-1: none), the decoy
    runs (one per camera moved), and each camera's number of detections."""
    nv = (real_obs >= 0).sum(axis=1)
    out = {"points_3plus_views": int((nv >= 3).sum()), "points_4_views": int((nv == 4).sum()), "cameras": {}}
    for k, (fake, n) in enumerate(zip(decoy_obs, n_detections)):
        R = int(((nv >= 3) & (real_obs[:, k] >= 0)).sum())
        D = int((((fake >= 0).sum(axis=1) >= 3) & (fake[:, k] >= 0)).sum())
        out["cameras"][f"cam{k + 1}"] = {"real": R, "decoy": D, "detections": int(n),
                                         "true_estimate": true_estimate(R, D, n),
                                         "chance_share": float(D / R) if R else None}
    return out


def _moved(dets: list[np.ndarray], k: int) -> list[np.ndarray]:
    return [d + np.asarray(B.DECOY_SHIFT_PX) if i == k else d for i, d in enumerate(dets)]


def ours(frame: int, cams: list, detection: dict, gates: dict) -> dict:
    """Our one-frame matching of ``frame`` with ``cams``, real and with each camera moved in turn."""
    dets = openptv.detect_frame(B.DATA, frame, **{**openptv.PARTICLE_SETTINGS, **detection})
    P, tgt = B.openptv_result(frame)
    bounds = (P.min(0) - 5e-3, P.max(0) + 5e-3)
    cor = match_views(dets, cams, bounds=bounds, **gates)
    decoys = [match_views(_moved(dets, k), cams, bounds=bounds, **gates).observations for k in range(len(dets))]
    out = per_camera(cor.observations, decoys, [len(d) for d in dets])
    fig = B.match_figures(cor.observations, cor.triangulation, P, tgt, dets, cams)
    out.update({k: fig[k] for k in ("reprojection_rms_px_ours", "agree_within_0p3mm")})
    return out


def over_time(frames: list[int], cams: list) -> dict:
    """The matching over time (``bench_real_data.TEMPORAL`` on its DETECTION's particles of frames 0-4), real
    and with each camera's detections moved in every frame in turn (the whole pipeline, correction included)."""
    from benchmarks.research.temporal_matching import match_over_time

    bounds = B.selfcal_bounds()
    dets = [openptv.detect_frame(B.DATA, f, **B.DETECTION) for f in B.TEMPORAL_FRAMES]
    real = match_over_time(dets, cams, bounds, **B.TEMPORAL)[0]
    decoys = [match_over_time([_moved(d, k) for d in dets], cams, bounds, **B.TEMPORAL)[0] for k in range(len(cams))]
    out = {}
    for f in frames:
        t = B.TEMPORAL_FRAMES.index(f)
        out[str(f)] = per_camera(real.observations[t], [m.observations[t] for m in decoys], [len(d) for d in dets[t]])
    return out


def likelihood(frames: list[int], cams: list) -> dict:
    """The matching by likelihood ratio on DETECTION's particles (``bench_likelihood_matching.py``: model, threshold
    and persistence bonus chosen on frame 0 with camera 1's decoy, then frozen), one frame at a time
    (``likelihood``) and with the persistence bonus (``likelihood_over_time``); the decoy of each camera in turn
    through the same frozen model, threshold and bonus (moved in every frame)."""
    from benchmarks.research import likelihood_matching as L
    from benchmarks.research.temporal_matching import persistence_support

    bounds, every = B.selfcal_bounds(), (B.TRAIN_FRAME, *B.FRAMES)
    opts = B.likelihood_options()
    dets = {f: B.detect("dense", f) for f in every}
    model = L.fit_true_model(dets[B.TRAIN_FRAME], cams, bounds, threshold=B.TRAIN_THRESHOLD, degree=B.DEGREE,
                             **opts)
    sc = B.scored(dets, cams, bounds, model)
    one, ot = B.one_frame(sc), B.over_time(sc)
    inc = B.over_time(sc, B.INCLUSIVE_DECOY_FRACTION, (ot["bonus"],))

    def selections(moved_camera: int | None) -> dict:
        runs = {f: sc[f][0] if moved_camera is None else
                L.score_candidates(_moved(dets[f], moved_camera), cams, bounds, model, **opts)[:2] for f in every}
        sup = persistence_support([runs[f][0] for f in every], **B.PERSISTENCE)
        out = {}
        for i, f in enumerate(every):
            c, score = runs[f]
            out[f] = [c.observations[L.select_by_score(c.observations, score, one["threshold"])]]
            out[f] += [c.observations[L.select_by_score(c.observations, score + o["bonus"] * (sup[i] > 0),
                                                        o["threshold"])] for o in (ot, inc)]
        return out

    real, decoys = selections(None), [selections(k) for k in range(len(cams))]
    names = ("likelihood", "likelihood_over_time", "likelihood_inclusive")
    res = {name: {} for name in names}
    res["likelihood_settings"] = {name: {"threshold": o["threshold"], "bonus": o.get("bonus", 0.0)}
                                  for name, o in zip(names, (one, ot, inc))}
    for f in frames:
        n = [len(d) for d in dets[f]]
        for j, name in enumerate(names):
            res[name][str(f)] = per_camera(real[f][j], [d[f][j] for d in decoys], n)
    return res


class OpenPTV:
    """OpenPTV's own detection and correspondences on the data set (``optv``), with its parameter files."""

    def __init__(self):
        from optv.calibration import Calibration
        from optv.parameters import ControlParams, TargetParams, VolumeParams

        par = B.DATA / "parameters"
        self.cpar = ControlParams(4)
        self.cpar.read_control_par(str(par / "ptv.par"))
        self.tpar = TargetParams()
        self.tpar.read(str(par / "targ_rec.par"))
        self.vpar = VolumeParams()
        self.vpar.read_volume_par(str(par / "criteria.par"))
        self.cals = []
        for c in range(4):
            cal = Calibration()
            cal.from_file(str(B.DATA / "cal" / f"cam{c + 1}.tif.ori"), str(B.DATA / "cal" / f"cam{c + 1}.tif.addpar"))
            self.cals.append(cal)

    def targets(self, frame: int, camera: int):
        from optv.image_processing import preprocess_image
        from optv.segmentation import target_recognition

        img = preprocess_image(openptv.read_image(openptv.frame_path(B.DATA, camera + 1, frame)), 0, self.cpar, 25)
        t = target_recognition(img, self.tpar, camera, self.cpar)
        t.sort_y()  # rt_is indexes the targets sorted by y
        return t

    def match(self, frame: int, moved_camera: int | None = None) -> tuple[np.ndarray, list[int]]:
        """Its correspondences ``(n_points, 4)`` target ids (-1: none; quadruplets, triplets, pairs) and the
        number of targets per camera; ``moved_camera``'s targets moved by DECOY_SHIFT_PX first."""
        from optv.correspondences import MatchedCoords, correspondences

        img_pts, flat = [], []
        for c in range(4):
            t = self.targets(frame, c)
            for i in range(len(t)):
                if c == moved_camera:
                    x, y = t[i].pos()
                    t[i].set_pos((x + B.DECOY_SHIFT_PX[0], y + B.DECOY_SHIFT_PX[1]))
                t[i].set_pnr(i)
            img_pts.append(t)
            flat.append(MatchedCoords(t, self.cpar, self.cals[c]))
        _, corresp, _ = correspondences(img_pts, flat, self.cals, self.vpar, self.cpar)
        obs = np.concatenate([np.asarray(c).T for c in corresp], axis=0).astype(int)
        return obs, [len(t) for t in img_pts]

    def yardstick(self, frame: int) -> dict:
        real, n = self.match(frame)
        out = per_camera(real, [self.match(frame, k)[0] for k in range(4)], n)
        _, tgt = B.openptv_result(frame)
        out["rt_is_points_3plus_views"] = int(((tgt >= 0).sum(axis=1) >= 3).sum())
        ours_rows = {tuple(r) for r in real.tolist()}
        out["rt_is_rows_reproduced"] = float(np.mean([tuple(r) in ours_rows for r in tgt.astype(int).tolist()]))
        return out


def run(frames: list[int], cams: list) -> dict:
    optv = OpenPTV()
    out = {"decoy_shift_px": list(B.DECOY_SHIFT_PX), "openptv": {}}
    out.update({name: {} for name in OPERATING_POINTS})
    for f in frames:
        out["openptv"][str(f)] = optv.yardstick(f)
        for name, (detection, gates) in OPERATING_POINTS.items():
            out[name][str(f)] = ours(f, cams, detection, gates)
    out["over_time"] = over_time(frames, cams)
    out.update(likelihood(frames, cams))
    return out


def table(res: dict) -> str:
    rows = ["| matching | frame | points seen by >= 3 cameras | per camera 1-4: real vs decoy -> estimated real "
            "(chance share) |", "|---|---|---|---|"]
    for name in ("openptv", *OPERATING_POINTS, "over_time", "likelihood", "likelihood_over_time",
                 "likelihood_inclusive"):
        for f, r in res[name].items():
            cells = [f"{c['real']} vs {c['decoy']} -> {c['true_estimate']:.0f} ({100 * (c['chance_share'] or 0):.0f} %)"
                     for c in r["cameras"].values()]
            rows.append(f"| {name} | {f} | {r['points_3plus_views']} | {'; '.join(cells)} |")
    return "\n".join(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--frames", type=int, nargs="+", default=[1, 2, 3, 4])
    ap.add_argument("--selfcal-seed", choices=("imported", "selected", "selected-ptvpar"), default="selected-ptvpar")
    ap.add_argument("--body-weight", type=float, default=0.5)
    a = ap.parse_args(argv)
    try:
        import optv  # noqa: F401
    except ImportError:
        print("needs OpenPTV's Python package optv (pip install -e '.[test]')", file=sys.stderr)
        return 1
    res = run(a.frames, B.self_calibrated_cameras(a.selfcal_seed, a.body_weight))
    print(json.dumps(res, indent=1) if a.json else table(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
