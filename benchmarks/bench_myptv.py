"""MyPTV's example (tests/data/myptv-example, 3 real cameras): its particles matched by vfmlab and compared with MyPTV's.

Run: ``OMP_NUM_THREADS=1 python -m benchmarks.bench_myptv [--json]`` (about a second).

1. Each camera is calibrated as ``tests/test_acq_myptv.py`` does: OpenCV from MyPTV's dot pairs (one view of the
   three-level plate; k1, k2, p1, p2), wrapped as vfmlab cameras; world = the plate's frame = MyPTV's lab frame.
   The 406 dots all three cameras see triangulate to 0.093 mm RMS from their places (the calibration's 3-D RMS).
2. MyPTV's blobs (its segmentation of the particle images, frames 0-6) are matched across the three cameras by
   vfmlab's ``match_views`` (points seen by all three cameras, as MyPTV's ``min_cam_match: 3``) and triangulated.
3. Against MyPTV's ``particles`` file: a MyPTV particle is found when one of our points lies within 3x the
   calibration's 3-D RMS; "same blobs" when one of our points uses exactly MyPTV's three blobs. The distances of the
   same-blob pairs are the two calibrations' disagreement (the matching is the same); MyPTV's blob triplets are also
   re-triangulated with our cameras, whatever we matched.
"""

from __future__ import annotations

import argparse
import json
import logging
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from acquisition.dic import MyPTVParticles, read_myptv_blobs, read_myptv_cal_points, read_myptv_particles
from reconstruction.cameras import Camera
from reconstruction.correspondence import match_views
from reconstruction.triangulation import triangulate

log = logging.getLogger(__name__)

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "myptv-example"
SIZE = (1280, 1024)
N_CAMERAS = 3
#: vfmlab's correspondence gates (px); all three views, as MyPTV's example matched them
GATES = {"epipolar_px": 2.0, "max_reprojection_px": 1.5, "min_views": 3}
#: a MyPTV particle counts as found within this many times the calibration's 3-D RMS
TOLERANCE_RMS = 3.0


def calibrate_camera(pixels: np.ndarray, target: np.ndarray, name: str) -> tuple[float, Camera]:
    """One view of the three-level dot plate (pixels (n, 2) px, target (n, 3) m) -> (RMS px, Camera): OpenCV from a
    rough K, k1, k2, p1, p2 (k3 = 0); world = the plate's frame."""
    K0 = np.array([[6000.0, 0, SIZE[0] / 2], [0, 6000.0, SIZE[1] / 2], [0, 0, 1]])
    rms, K, dist, rv, tv = cv2.calibrateCamera([target.astype(np.float32)], [pixels.astype(np.float32)], SIZE, K0,
                                               None, flags=cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_K3)
    return rms, Camera(name, K, dist.ravel()[:5], rv[0].ravel(), tv[0].ravel(), SIZE)


def calibrate_example(folder: Path = DATA) -> tuple[list[Camera], float]:
    """The three cameras from MyPTV's dot pairs, and the 3-D RMS (m) of the dots all three see against the plate."""
    pairs = [read_myptv_cal_points(folder / "Calibration" / f"cam{k}_cal_points") for k in range(1, N_CAMERAS + 1)]
    cams = [calibrate_camera(px, X, f"cam{k + 1}")[1] for k, (px, X) in enumerate(pairs)]
    by_dot = [dict(zip(map(tuple, np.round(X * 1e5).astype(int)), px)) for px, X in pairs]
    common = sorted(set.intersection(*(set(d) for d in by_dot)))
    pixels = np.stack([np.array([d[c] for c in common]) for d in by_dot])
    X = triangulate(pixels, cams, covariance=False).points
    return cams, float(np.sqrt(np.mean(np.sum((X - np.array(common) * 1e-5) ** 2, -1))))


@dataclass(frozen=True)
class FrameComparison:
    """vfmlab's matching of one frame against MyPTV's (distances in m; indices into the frame's MyPTV rows / our
    points)."""

    frame: int
    n_myptv: int
    n_ours: int
    same_blobs: np.ndarray      # (n_myptv,) bool: one of our points uses exactly MyPTV's blobs
    nearest: np.ndarray         # (n_myptv,) distance to our nearest point, m
    ours_nearest: np.ndarray    # (n_ours,) distance of each of our points to MyPTV's nearest, m
    retriangulated: np.ndarray  # (n_myptv,) MyPTV's blob triplet triangulated with our cameras, distance to its point
    myptv_z: np.ndarray         # (n_myptv,) MyPTV's z, m
    ours_points: np.ndarray     # (n_ours, 3) m
    ours_rms_px: np.ndarray     # (n_ours,) our points' reprojection RMS, px
    ours_shared: np.ndarray     # (n_ours,) int: blobs shared with the MyPTV particle sharing most (3 = same blobs)


def compare_frame(frame: int, blobs: list[np.ndarray], cams: list[Camera], myptv: MyPTVParticles) -> FrameComparison:
    """Match ``blobs`` (per camera (n_i, 2) px) with vfmlab and compare with MyPTV's particles of this frame."""
    rows = myptv.frames == frame
    theirs, their_blobs = myptv.points[rows], myptv.blobs[rows]
    cor = match_views(blobs, cams, **GATES)
    ours = cor.points
    nearest = cKDTree(ours).query(theirs)[0] if len(ours) else np.full(len(theirs), np.inf)
    ours_nearest = cKDTree(theirs).query(ours)[0] if len(theirs) else np.full(len(ours), np.inf)
    used = {tuple(o) for o in cor.observations}
    same = np.array([tuple(b) in used for b in their_blobs], dtype=bool)
    full = np.all(their_blobs >= 0, axis=1)
    pix = np.full((len(cams), len(theirs), 2), np.nan)
    for c in range(len(cams)):
        pix[c, full] = blobs[c][their_blobs[full, c]]
    retri = np.full(len(theirs), np.nan)
    retri[full] = np.linalg.norm(triangulate(pix[:, full], cams, covariance=False).points - theirs[full], axis=1)
    shared = np.array([(their_blobs == o).sum(axis=1).max(initial=0) for o in cor.observations], dtype=int)
    return FrameComparison(frame, len(theirs), len(ours), same, nearest, ours_nearest, retri, theirs[:, 2], ours,
                           cor.triangulation.reprojection_rms, shared)


def compare_example(folder: Path = DATA, frames=None) -> tuple[list[FrameComparison], float]:
    """Every frame (or ``frames``) of the example -> comparisons, and the calibration's 3-D RMS (m)."""
    cams, rms3d = calibrate_example(folder)
    blobs = [read_myptv_blobs(folder / f"blobs_cam{k}") for k in range(1, N_CAMERAS + 1)]
    myptv = read_myptv_particles(folder / "particles", N_CAMERAS)
    frames = sorted(set(np.unique(myptv.frames).tolist())) if frames is None else list(frames)
    return [compare_frame(f, [b.get(f, np.zeros((0, 2))) for b in blobs], cams, myptv) for f in frames], rms3d


def summary(comparisons: list[FrameComparison], rms3d: float) -> dict:
    """Totals over frames: counts, fractions, distances (mm) of the found and of the same-blob pairs."""
    tol = TOLERANCE_RMS * rms3d
    near = np.concatenate([c.nearest for c in comparisons])
    same = np.concatenate([c.same_blobs for c in comparisons])
    ours = np.concatenate([c.ours_nearest for c in comparisons])
    retri = np.concatenate([c.retriangulated for c in comparisons])
    found = near <= tol

    def stats(d):
        d = d[np.isfinite(d)] * 1e3
        if not len(d):
            return {"median_mm": float("nan"), "p95_mm": float("nan"), "max_mm": float("nan")}
        return {"median_mm": float(np.median(d)), "p95_mm": float(np.percentile(d, 95)), "max_mm": float(d.max())}

    return {
        "frames": [c.frame for c in comparisons], "calibration_rms_3d_mm": rms3d * 1e3, "tolerance_mm": tol * 1e3,
        "n_myptv": int(len(near)), "n_ours": int(len(ours)), "n_found": int(found.sum()),
        "fraction_found": float(found.mean()), "n_same_blobs": int(same.sum()), "fraction_same_blobs": float(same.mean()),
        "found": stats(near[found]), "same_blob_pairs": stats(near[same]), "retriangulated": stats(retri),
        "n_myptv_only": int((~found).sum()), "n_myptv_only_same_blobs": int((~found & same).sum()),
        "n_ours_only": int((ours > tol).sum()),
        "n_ours_only_same_blobs": int(sum(((c.ours_nearest > tol) & (c.ours_shared == 3)).sum() for c in comparisons)),
        "n_ours_only_sharing_blobs": int(sum(((c.ours_nearest > tol) & (c.ours_shared > 0) & (c.ours_shared < 3)).sum()
                                             for c in comparisons)),
    }


def _depth_table(comparisons: list[FrameComparison]) -> list[tuple[str, int, float]]:
    """Median distance of the same-blob pairs (mm) by MyPTV's z: the plate's dots lie at z = 0, -6, -12 mm."""
    z = np.concatenate([c.myptv_z[c.same_blobs] for c in comparisons]) * 1e3
    d = np.concatenate([c.nearest[c.same_blobs] for c in comparisons]) * 1e3
    bins = [("z < -27 mm", z < -27), ("-27 <= z < -12 mm", (z >= -27) & (z < -12)),
            ("-12 <= z <= 0 mm (the plate)", (z >= -12) & (z <= 0)), ("0 < z <= 15 mm", (z > 0) & (z <= 15)),
            ("z > 15 mm", z > 15)]
    return [(name, int(sel.sum()), float(np.median(d[sel])) if sel.any() else float("nan")) for name, sel in bins]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    args = parser.parse_args(argv)
    comparisons, rms3d = compare_example()
    s = summary(comparisons, rms3d)
    if args.json:
        print(json.dumps(s, indent=1))
        return
    tol = s["tolerance_mm"]
    print(f"calibration 3-D RMS {s['calibration_rms_3d_mm']:.3f} mm; tolerance {tol:.3f} mm; gates {GATES}")
    print("| frame | MyPTV | ours | same blobs | found | median (mm) | 95 % (mm) | MyPTV only | ours only |")
    print("|---|---|---|---|---|---|---|---|---|")
    for c in comparisons:
        f = c.nearest * 1e3 <= tol
        d = c.nearest[f] * 1e3
        print(f"| {c.frame} | {c.n_myptv} | {c.n_ours} | {c.same_blobs.sum()} | {f.sum()} | {np.median(d):.3f} | "
              f"{np.percentile(d, 95):.3f} | {(~f).sum()} | {(c.ours_nearest * 1e3 > tol).sum()} |")
    print(f"| all | {s['n_myptv']} | {s['n_ours']} | {s['n_same_blobs']} ({100 * s['fraction_same_blobs']:.1f} %) | "
          f"{s['n_found']} ({100 * s['fraction_found']:.1f} %) | {s['found']['median_mm']:.3f} | "
          f"{s['found']['p95_mm']:.3f} | {s['n_myptv_only']} | {s['n_ours_only']} |")
    print(f"same-blob pairs: median {s['same_blob_pairs']['median_mm']:.3f}, 95 % {s['same_blob_pairs']['p95_mm']:.3f}, "
          f"max {s['same_blob_pairs']['max_mm']:.3f} mm; MyPTV's triplets re-triangulated: median "
          f"{s['retriangulated']['median_mm']:.3f}, 95 % {s['retriangulated']['p95_mm']:.3f} mm")
    print(f"MyPTV only: {s['n_myptv_only']}, of which {s['n_myptv_only_same_blobs']} with our same blobs; ours only: "
          f"{s['n_ours_only']}, of which {s['n_ours_only_same_blobs']} with MyPTV's same blobs, "
          f"{s['n_ours_only_sharing_blobs']} sharing 1-2 blobs with a MyPTV particle")
    for name, n, med in _depth_table(comparisons):
        print(f"  {name}: {n} same-blob pairs, median {med:.3f} mm")
    for c in comparisons:
        for i in np.flatnonzero(c.nearest * 1e3 > tol):
            print(f"  MyPTV only: frame {c.frame}, z {c.myptv_z[i] * 1e3:.1f} mm, nearest of ours "
                  f"{c.nearest[i] * 1e3:.3f} mm, same blobs {bool(c.same_blobs[i])}")
        for i in np.flatnonzero(c.ours_nearest * 1e3 > tol):
            print(f"  ours only: frame {c.frame}, at {np.round(c.ours_points[i] * 1e3, 1)} mm, nearest MyPTV "
                  f"{c.ours_nearest[i] * 1e3:.3f} mm, blobs shared with a MyPTV particle {c.ours_shared[i]} of 3, "
                  f"reprojection RMS {c.ours_rms_px[i]:.2f} px")


if __name__ == "__main__":
    main()
