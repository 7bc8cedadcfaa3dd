"""Benchmark of the regional (per-band) identification (prints markdown tables; docs/identification.md quotes them).

    OMP_NUM_THREADS=1 PYTHONPATH=. python benchmarks/bench_regional.py [--quick] [--seeds N]

Ground truth: rig_sim's clamped Fung tube (paper parameters, 300 markers 4 mm clear of the cannulae, 8 pressures to
150 mmHg at stretch 1.1) with a 40 % weakening of beta over a quarter of the 35 mm length centred at Z = +9 mm
(``rig_sim.regional.AxialProfile``), and the homogeneous tube. Truth per band = the band mean of beta(Z).
For every band count and marker noise (0: exact; 0.05 mm: smoothed (4, 2)) over seeds:
  max err   : largest |beta_band / truth - 1| over the bands (median over seeds)
  weak err  : |beta / truth - 1| of the band holding the zone centre (median over seeds)
  hom gap   : homogeneous fit's beta / weak-band truth - 1 (median)
  |err|/se  : median over bands and seeds of |beta - truth| / standard error (about 0.67 if the errors were right)
  cover 2se : fraction of bands whose truth lies within 2 standard errors
  found     : fraction of seeds where the weakest band found lies mostly in the weak zone (truth < 0.8 beta)
  false     : bands flagged as different on the homogeneous tube (total over seeds)
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from identification.regional import identify_regional, prepare_regional  # noqa: E402
from rig_sim.mechanics import PAPER_PARAMETERS, simulate_test  # noqa: E402
from rig_sim.regional import AxialProfile  # noqa: E402

FUNG = PAPER_PARAMETERS["fung"]
WEAK = AxialProfile(depth=0.4, center=9e-3, width=35e-3 / 4)


SMOOTH = (4, 2)


def fit(profile, n_bands, noise, seed):
    sim = simulate_test("fung", FUNG, clamped=True, stress_scale=profile, noise_std=noise, seed=seed)
    rd = prepare_regional(sim.positions, sim.pressure, sim.axial_force, thickness=sim.thickness, n_bands=n_bands,
                          smoothing=SMOOTH if noise > 0 else None)
    res = identify_regional(rd, "fung")
    z = rd.world_points(rd.edges)[:, 2]
    truth = FUNG["beta"] * (profile.band_mean(z) if profile is not None else np.ones(n_bands))
    return res, z, truth


def row(n_bands, noise, seeds):
    max_err, weak_err, hom_gap, ratio, cover, found, false = [], [], [], [], [], [], 0
    for seed in seeds:
        res, z, truth = fit(WEAK, n_bands, noise, seed)
        beta, se = res.profiles["beta"], res.stderr["beta"]
        weak = int(np.searchsorted(z, WEAK.center) - 1)
        max_err.append(np.max(np.abs(beta / truth - 1)))
        weak_err.append(abs(beta[weak] / truth[weak] - 1))
        hom_gap.append(res.homogeneous.parameters["beta"] / truth[weak] - 1)
        err_se = np.abs(beta - truth) / np.where(se > 0, se, np.nan)
        ratio.extend(err_se.tolist())
        cover.extend((err_se <= 2).tolist())
        found.append(truth[int(np.argmin(beta))] < 0.8 * FUNG["beta"])  # the weakest band lies in the zone
        hom, _, _ = fit(None, n_bands, noise, seed)
        false += int(hom.differs.sum())
    return (f"| {n_bands} | {noise * 1e3:.2f} | {len(seeds)} | {np.median(max_err):.1%} | {np.median(weak_err):.1%} | "
            f"{np.median(hom_gap):+.0%} | {np.nanmedian(ratio):.2g} | {np.mean(cover):.0%} | {np.mean(found):.0%} | "
            f"{false} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="2 and 4 bands, 2 seeds")
    ap.add_argument("--seeds", type=int, default=5, help="noise seeds per row (exact data: 1)")
    ap.add_argument("--smooth", default="4,2", help="smoothing of the noisy data: AXIAL,HARMONICS (default 4,2)")
    ap.add_argument("--noisy-only", action="store_true", help="skip the exact-data rows")
    args = ap.parse_args(argv)
    global SMOOTH
    SMOOTH = tuple(int(v) for v in args.smooth.split(","))
    logging.basicConfig(level=logging.ERROR)
    bands = (2, 4) if args.quick else (2, 3, 4, 6, 8)
    n_seeds = 2 if args.quick else args.seeds
    print(f"smoothing of noisy data: {SMOOTH}\n")
    print("| bands | noise (mm) | seeds | max err | weak err | hom gap | \\|err\\|/se | cover 2se | found | false |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    t0 = time.perf_counter()
    for noise in (0.05e-3,) if args.noisy_only else (0.0, 0.05e-3):
        for n in bands:
            print(row(n, noise, range(1 if noise == 0 else n_seeds)), flush=True)
    print(f"\n{time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
