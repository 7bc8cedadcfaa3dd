"""Particle centre estimators (reconstruction.particle_centres) compared on synthetic and real images.

1. ``synthetic``: Gaussian particle images integrated over the pixels (widths 0.7-1.6 px, peaks 10-200 grey
   levels, 1.5 grey levels of noise, 8-bit, 40 % of the particles with a partner 2.5-5 px away) with known
   centres: error per estimator, isolated and touching particles (same blobs for every estimator).
2. ``residuals``: real images (OpenPTV test_cavity), the self-calibrated cameras: the matches over time of the
   benchmark's dense detections (bench_real_data.DETECTION, TEMPORAL without the residual test and without the
   pixel correction) found with every estimator's centres (the same particles; the selection favours none),
   re-triangulated with each estimator's own centres: reprojection residual per camera (raw, and after each
   estimator's own degree-3 pixel correction), the change of a camera's residual from frame to frame along the
   same track, and the residual of touching and isolated detections.
3. ``matching``: the matching itself with each estimator's centres, real vs decoy (camera 1's detections moved
   by bench_real_data.DECOY_SHIFT_PX): over time (TEMPORAL, frames 0-4) and one frame at a time with OpenPTV's
   particle settings (SELFCAL_GATES and TIGHT_GATES). The cameras are self-calibrated on the centroids.

    python -m benchmarks.bench_particle_centres [--json] [--parts synthetic residuals matching] [--cameras PKL]

``--cameras``: a pickle of a dict with key ``cameras`` (the self-calibrated cameras of bench_real_data, seed
selected-ptvpar, body weight 0.5); without it the self-calibration is run first (about 2 min).
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np
from scipy.spatial import cKDTree


from benchmarks import _common as B
from reconstruction.correspondence import observed_pixels
from reconstruction.particle_centres import CENTRE_ESTIMATORS
from reconstruction.particles import detect_particles
from reconstruction.triangulation import triangulate
from vfmlab import openptv

#: synthetic images: (particles before partners, seed) per image, 512 x 512 px
SYNTHETIC = [(150, 0), (400, 0), (150, 1), (400, 1), (400, 2)]


def synthetic() -> dict:
    """Centre error (px) per estimator on the blobs of SYNTHETIC's images (DETECTION's settings), isolated
    particles (no true neighbour within 5 px) and touching ones; the true centre assigned by the centroid."""
    from rig_sim.particle_images import particle_image

    err = {c: {"isolated": [], "touching": []} for c in CENTRE_ESTIMATORS}
    for n, seed in SYNTHETIC:
        img, truth = particle_image((512, 512), n, seed=seed)
        dets = {c: detect_particles(img, centre=c, **B.DETECTION).centres for c in CENTRE_ESTIMATORS}
        d, i = cKDTree(truth).query(dets["centroid"])
        near = cKDTree(truth).query(truth, k=2)[0][:, 1][i] <= 5.0
        for c, xy in dets.items():
            e = np.linalg.norm(xy - truth[i], axis=1)
            err[c]["isolated"].append(e[(d <= 1.5) & ~near])
            err[c]["touching"].append(e[(d <= 1.5) & near])
    return {c: {k: _stats(np.concatenate(v)) for k, v in row.items()} for c, row in err.items()}


def _stats(e: np.ndarray) -> dict:
    e = e[np.isfinite(e)]
    return {"n": int(e.size), "rms_px": float(np.sqrt(np.mean(e**2))), "median_px": float(np.median(e)),
            "p90_px": float(np.percentile(e, 90))}


def detections(frames, settings: dict, estimators=CENTRE_ESTIMATORS) -> dict:
    """Per estimator, per frame, per camera: the centres of the same blobs, px."""
    imgs = {f: [openptv.read_image(openptv.frame_path(B.DATA, c + 1, f)) for c in range(4)] for f in frames}
    return {c: [[detect_particles(im, centre=c, **{**openptv.PARTICLE_SETTINGS, **settings}).centres
                 for im in imgs[f]] for f in frames] for c in estimators}


def residuals(cams: list, dets: dict) -> dict:
    """Matches over time (TEMPORAL without the residual test, no pixel correction) found with every estimator's
    centres (the same detections in the same cameras: the same particles), re-triangulated per estimator:
    residual per camera, raw and after the estimator's own pixel correction, and its frame-to-frame change
    along tracks (links: mutual nearest 3-D points within TEMPORAL's step, the centroids' points)."""
    from benchmarks.research.temporal_matching import apply_pixel_correction, fit_pixel_correction, match_over_time

    opts = {**B.TEMPORAL, "max_residual_change_px": float("inf"), "degree": 0}
    runs = {c: match_over_time(f, cams, B.selfcal_bounds(), **opts)[0].observations for c, f in dets.items()}
    common = [_common_rows([runs[c][t] for c in dets]) for t in range(len(B.TEMPORAL_FRAMES))]
    pts = [triangulate(observed_pixels(f, o), cams, covariance=False).points
           for f, o in zip(dets["centroid"], common)]
    sizes = [c.image_size for c in cams]
    links = [_mutual_links(a, b, B.TEMPORAL["max_step_m"]) for a, b in zip(pts[:-1], pts[1:])]
    out = {"matches_per_frame": {c: [len(o) for o in r] for c, r in runs.items()},
           "common_per_frame": [len(o) for o in common], "links_per_pair": [len(k) for k in links]}
    for c, frames in dets.items():
        px = [observed_pixels(f, o) for f, o in zip(frames, common)]
        raw = [triangulate(p, cams, covariance=False).residuals for p in px]
        allpx, allres = np.concatenate(px, axis=1), np.concatenate(raw, axis=1)
        coef = fit_pixel_correction(allpx, allres, sizes, degree=3)
        fixed = [triangulate(np.stack(apply_pixel_correction(list(p), coef, sizes)), cams, covariance=False).residuals
                 for p in px]
        out[c] = {"raw": _residual_figures(raw, links), "corrected": _residual_figures(fixed, links),
                  "by_neighbour": _by_neighbour(fixed, dets["centroid"], common)}
    return out


def _by_neighbour(res: list, frames: list, obs: list, touching_px: float = 5.0) -> dict:
    """Residual RMS (px, clipped at 3 px) of the observations whose detection has another within ``touching_px``
    in its image (touching, mostly split blobs) and of the others, pooled over cameras and frames."""
    r, near = [], []
    for x, dets, o in zip(res, frames, obs):
        for c, d in enumerate(dets):
            seen = o[:, c] >= 0
            nn = cKDTree(d).query(d[o[seen, c]], k=2)[0][:, 1]
            r.append(np.linalg.norm(x[c, seen], axis=-1))
            near.append(nn <= touching_px)
    r, near = np.concatenate(r), np.concatenate(near)
    return {k: {"n": int(m.sum()), "residual_rms_px": float(np.sqrt(np.mean(np.minimum(r[m], 3) ** 2)))}
            for k, m in (("touching", near), ("isolated", ~near))}


def _common_rows(obs: list) -> np.ndarray:
    """Rows ``(k, n_cameras)`` present in every array of ``obs``."""
    keep = set(map(tuple, obs[0].tolist()))
    for o in obs[1:]:
        keep &= set(map(tuple, o.tolist()))
    return np.array(sorted(keep), np.int64).reshape(-1, obs[0].shape[1])


def _mutual_links(a: np.ndarray, b: np.ndarray, max_step: float) -> np.ndarray:
    d_ab, j = cKDTree(b).query(a, distance_upper_bound=max_step)
    _, i = cKDTree(a).query(b)
    ok = np.flatnonzero(np.isfinite(d_ab))
    ok = ok[i[j[ok]] == ok]
    return np.stack([ok, j[ok]], axis=1)


def _residual_figures(res: list, links: list) -> dict:
    """res[t] ``(n_cameras, m_t, 2)``: per camera the RMS and median of the residual norm (px, clipped at
    3 px: chance matches), and of its change along the links; fraction of changes <= 0.5 px."""
    out = {}
    for c in range(res[0].shape[0]):
        r = np.concatenate([np.linalg.norm(x[c], axis=-1) for x in res])
        ch = np.concatenate([np.linalg.norm(res[t + 1][c, k[:, 1]] - res[t][c, k[:, 0]], axis=-1)
                             for t, k in enumerate(links)])
        r, ch = r[np.isfinite(r)], ch[np.isfinite(ch)]
        out[f"cam{c + 1}"] = {"residual_rms_px": float(np.sqrt(np.mean(np.minimum(r, 3) ** 2))),
                              "residual_median_px": float(np.median(r)),
                              "change_median_px": float(np.median(ch)),
                              "change_rms_px": float(np.sqrt(np.mean(np.minimum(ch, 3) ** 2))),
                              "change_within_0p5px": float(np.mean(ch <= 0.5)), "n_changes": int(ch.size)}
    return out


def matching(cams: list, dense: dict, bright: dict, frames: list[int]) -> dict:
    """Real vs decoy per estimator: over time (TEMPORAL on ``dense``, frames 0-4) and one frame at a time
    (``bright``: OpenPTV's particle settings, frames ``frames``) with SELFCAL_GATES and TIGHT_GATES."""
    from benchmarks.research.temporal_matching import match_over_time

    bounds = B.selfcal_bounds()
    out = {}
    for c in dense:
        dets = dense[c]
        decoy = [[d[0] + np.asarray(B.DECOY_SHIFT_PX), *d[1:]] for d in dets]
        (tm, corrected, _), tm_decoy = match_over_time(dets, cams, bounds, **B.TEMPORAL), \
            match_over_time(decoy, cams, bounds, **B.TEMPORAL)[0]
        row = {"temporal": {}, "one_frame": {}, "one_frame_tight": {}}
        for f in frames:
            t = B.TEMPORAL_FRAMES.index(f)
            row["temporal"][str(f)] = _keys(B.temporal_figures(f, tm, tm_decoy, t, corrected[t], cams))
            one = bright[c][frames.index(f)]
            row["one_frame"][str(f)] = _keys(B.frame_figures(f, one, cams, gates=B.SELFCAL_GATES, decoy=True))
            row["one_frame_tight"][str(f)] = _keys(B.frame_figures(f, one, cams, gates=B.TIGHT_GATES, decoy=True))
        out[c] = row
    return out


def _keys(r: dict) -> dict:
    return {k: r[k] for k in ("our_points_3plus_views", "our_points_3plus_views_with_cam1",
                              "decoy_points_3plus_views_with_cam1", "reprojection_rms_px_ours", "agree_within_0p3mm")}


def report(res: dict) -> str:
    lines = []
    if "synthetic" in res:
        lines += ["synthetic: centre error (px), rms / median / p90 (n)"]
        for c, row in res["synthetic"].items():
            lines.append(f"  {c:9s} " + "   ".join(f"{k} {v['rms_px']:.3f} / {v['median_px']:.3f} / {v['p90_px']:.3f} "
                                                   f"({v['n']})" for k, v in row.items()))
    if "residuals" in res:
        r = res["residuals"]
        lines += [f"real residuals, matches per frame {r['matches_per_frame']}, common to all {r['common_per_frame']}, "
                  f"links {r['links_per_pair']}: "
                  "per camera residual rms / median, change median / within 0.5 px"]
        for c in r:
            if c not in CENTRE_ESTIMATORS:
                continue
            for kind in ("raw", "corrected"):
                lines.append(f"  {c:9s} {kind:9s} " + "  ".join(
                    f"{k} {v['residual_rms_px']:.3f}/{v['residual_median_px']:.3f} {v['change_median_px']:.3f}/"
                    f"{v['change_within_0p5px']:.2f}" for k, v in r[c][kind].items()))
            t, i = r[c]["by_neighbour"]["touching"], r[c]["by_neighbour"]["isolated"]
            lines.append(f"  {c:9s} corrected, all cameras: touching {t['residual_rms_px']:.3f} ({t['n']}), "
                         f"isolated {i['residual_rms_px']:.3f} ({i['n']})")
    if "matching" in res:
        lines += ["matching, per frame: points seen by >= 3 cameras, with camera 1 real vs decoy, RMS px"]
        for c, row in res["matching"].items():
            for kind, fr in row.items():
                lines.append(f"  {c:9s} {kind:16s} " + "; ".join(
                    f"{f}: {v['our_points_3plus_views']}, {v['our_points_3plus_views_with_cam1']} vs "
                    f"{v['decoy_points_3plus_views_with_cam1']}, {v['reprojection_rms_px_ours']:.3f}"
                    for f, v in fr.items()))
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--parts", nargs="+", default=["synthetic", "residuals", "matching"],
                    choices=("synthetic", "residuals", "matching"))
    ap.add_argument("--frames", type=int, nargs="+", default=[1, 2, 3, 4])
    ap.add_argument("--estimators", nargs="+", default=list(CENTRE_ESTIMATORS), choices=CENTRE_ESTIMATORS)
    ap.add_argument("--cameras", help="pickle with key 'cameras' (self-calibrated); default: self-calibrate first")
    a = ap.parse_args(argv)
    res = {}
    if "synthetic" in a.parts:
        res["synthetic"] = synthetic()
    if {"residuals", "matching"} & set(a.parts):
        cams = B.self_calibrated_cameras(pickle_path=a.cameras)
        dense = detections(B.TEMPORAL_FRAMES, B.DETECTION, a.estimators)
        if "residuals" in a.parts:
            res["residuals"] = residuals(cams, dense)
        if "matching" in a.parts:
            res["matching"] = matching(cams, dense, detections(a.frames, {}, a.estimators), a.frames)
    print(json.dumps(res, indent=1) if a.json else report(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
