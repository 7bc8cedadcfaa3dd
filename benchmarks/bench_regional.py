"""Benchmark of the regional (per-band / smooth-profile) identification: prints the markdown tables that
docs/validation/identification.md ("Regional") quotes.

    OMP_NUM_THREADS=1 python -m benchmarks.bench_regional [--quick] [--seeds N] [--only bands|auto|legendre]

Ground truth: rig_sim's clamped Fung tube (paper parameters, 300 markers 4 mm clear of the cannulae, 8 pressures to
150 mmHg at stretch 1.1) with a 40 % weakening of beta over a quarter of the 35 mm length centred at Z = +9 mm
(``rig_sim.regional.AxialProfile``), a 30 % stiffness gradient over the length, and the homogeneous tube. Noisy data
(0.05 mm per coordinate) are smoothed (4, 2); their uncertainty is the parametric bootstrap
(``identification.regional_uncertainty.with_bootstrap``, 16 replicates), exact data's is Gauss-Newton.

Table "bands" (truth per band = the band mean of beta(Z)), per band count and noise, over seeds:
  max err   : largest |beta_band / truth - 1| over the bands (median over seeds)
  weak err  : |beta / truth - 1| of the band holding the zone centre (median over seeds)
  hom gap   : homogeneous fit's beta / weak-band truth - 1 (median)
  GN |e|/se, GN cover : median |beta - truth| / Gauss-Newton standard error, fraction of bands whose truth lies in
              the Gauss-Newton 95 % interval (+-1.96 se)
  BS |e|/se, BS cover : the same with the bootstrap's standard errors and 95 % intervals (|e|/se ~ 0.67 if right)
  found     : fraction of seeds where the weakest band found lies mostly in the weak zone (truth < 0.8 beta)
  false     : bands flagged as different on the homogeneous tube (total over seeds, bootstrap errors)
Table "auto": the band count ``choose_bands`` picks (n_max 6) on each truth, and the chosen fit's accuracy.
Table "legendre": smooth profiles of K Legendre coefficients of log beta (truth: beta(Z) at the 24 report points).
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from collections import Counter

import numpy as np

from identification.regional import identify_regional, prepare_regional
from identification.regional_uncertainty import choose_bands, with_bootstrap
from rig_sim.mechanics import PAPER_PARAMETERS, simulate_test
from rig_sim.regional import AxialProfile

FUNG = PAPER_PARAMETERS["fung"]
WEAK = AxialProfile(depth=0.4, center=9e-3, width=35e-3 / 4)
GRADIENT = AxialProfile(gradient=0.3 / 35e-3)
FLAT = AxialProfile()
SMOOTH = (4, 2)
N_REPLICATES = 16


def simulate(profile, noise, seed):
    return simulate_test("fung", FUNG, clamped=True, stress_scale=None if profile is FLAT else profile,
                         noise_std=noise, seed=seed)


def fit(sim, noise, **spec):
    """Regional fit (bootstrap errors on noisy data); (result, world z of the cell edges, world z of the centres)."""
    rd = prepare_regional(sim.positions, sim.pressure, sim.axial_force, thickness=sim.thickness,
                          smoothing=SMOOTH if noise > 0 else None, **spec)
    gn = identify_regional(rd, "fung")
    res = with_bootstrap(gn, rd, sim.positions, n_replicates=N_REPLICATES) if noise > 0 else gn
    return gn, res, rd.world_points(rd.edges)[:, 2], rd.world_points(rd.centres)[:, 2]


def _inside(res, truth):
    lo, hi = res.interval["beta"][:, 0], res.interval["beta"][:, 1]
    return (truth >= lo) & (truth <= hi)


def bands_row(n_bands, noise, seeds):
    max_err, weak_err, hom_gap, gn_r, gn_c, bs_r, bs_c, found, false = [], [], [], [], [], [], [], [], 0
    for seed in seeds:
        gn, res, z, _ = fit(simulate(WEAK, noise, seed), noise, n_bands=n_bands)
        truth = FUNG["beta"] * WEAK.band_mean(z)
        beta = res.profiles["beta"]
        weak = int(np.searchsorted(z, WEAK.center) - 1)
        max_err.append(np.max(np.abs(beta / truth - 1)))
        weak_err.append(abs(beta[weak] / truth[weak] - 1))
        hom_gap.append(res.homogeneous.parameters["beta"] / truth[weak] - 1)
        for r, rs, cs in ((gn, gn_r, gn_c), (res, bs_r, bs_c)):
            se = r.stderr["beta"]
            rs.extend((np.abs(beta - truth) / np.where(se > 0, se, np.nan)).tolist())
            cs.extend(_inside(r, truth).tolist())
        found.append(truth[int(np.argmin(beta))] < 0.8 * FUNG["beta"])
        _, hom, _, _ = fit(simulate(FLAT, noise, seed), noise, n_bands=n_bands)
        false += int(hom.differs.sum())
    return (f"| {n_bands} | {noise * 1e3:.2f} | {len(seeds)} | {np.median(max_err):.1%} | {np.median(weak_err):.1%} | "
            f"{np.median(hom_gap):+.0%} | {np.nanmedian(gn_r):.2g} | {np.mean(gn_c):.0%} | "
            f"{np.nanmedian(bs_r):.2g} | {np.mean(bs_c):.0%} | {np.mean(found):.0%} | {false} |")


def auto_rows(noise, seeds):
    rows = []
    for name, profile in (("homogeneous", FLAT), ("40 % weakening", WEAK), ("30 % gradient", GRADIENT)):
        counts, differs, errs, cover, t0 = Counter(), 0, [], [], time.perf_counter()
        for seed in seeds:
            sim = simulate(profile, noise, seed)
            choice = choose_bands(sim.positions, sim.pressure, sim.axial_force, thickness=sim.thickness,
                                  smoothing=SMOOTH if noise > 0 else None,
                                  bootstrap_options={"n_replicates": N_REPLICATES if noise > 0 else 5})
            counts[choice.n_bands] += 1
            _, res, z, _ = fit(sim, noise, n_bands=choice.n_bands)
            truth = FUNG["beta"] * profile.band_mean(z)
            errs.append(np.max(np.abs(res.profiles["beta"] / truth - 1)))
            cover.extend(_inside(res, truth).tolist())
            differs += int(res.differs.any()) if profile is FLAT else int(
                bool(res.differs[int(np.argmin(res.profiles["beta"]))]))
        seconds = (time.perf_counter() - t0) / len(seeds)
        what = "seeds with a band flagged" if profile is FLAT else "seeds with the weakest band flagged"
        rows.append(f"| {name} | {noise * 1e3:.2f} | {len(seeds)} | "
                    f"{', '.join(f'{k}: {v}' for k, v in sorted(counts.items()))} | {np.median(errs):.1%} | "
                    f"{np.mean(cover):.0%} | {differs} ({what}) | {seconds:.0f} s |")
    return rows


def legendre_row(profile_name, profile, k, noise, seeds):
    max_err, rms_err, cover, ratio = [], [], [], []
    for seed in seeds:
        _, res, _, zc = fit(simulate(profile, noise, seed), noise, legendre=k)
        truth = FUNG["beta"] * profile(zc)
        e = res.profiles["beta"] / truth - 1
        max_err.append(np.max(np.abs(e)))
        rms_err.append(np.sqrt(np.mean(e**2)))
        cover.extend(_inside(res, truth).tolist())
        ratio.extend((np.abs(res.profiles["beta"] - truth) / res.stderr["beta"]).tolist())
    return (f"| {profile_name} | {k} | {noise * 1e3:.2f} | {len(seeds)} | {np.median(max_err):.1%} | "
            f"{np.median(rms_err):.1%} | {np.nanmedian(ratio):.2g} | {np.mean(cover):.0%} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="2 and 4 bands, 2 seeds")
    ap.add_argument("--seeds", type=int, default=5, help="noise seeds per row (exact data: 1)")
    ap.add_argument("--only", choices=("bands", "auto", "legendre"), action="append",
                    help="tables to print (default all; repeatable)")
    ap.add_argument("--noisy-only", action="store_true", help="skip the exact-data rows")
    ap.add_argument("--bands", default="2,3,4,6,8", help="band counts of the bands table (default 2,3,4,6,8)")
    ap.add_argument("--ks", default="2,3,5,7", help="Legendre coefficient counts of the legendre table (default 2,3,5,7)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    tables = args.only or ["bands", "auto", "legendre"]
    n_seeds = 2 if args.quick else args.seeds
    noises = (0.05e-3,) if args.noisy_only else (0.0, 0.05e-3)
    t0 = time.perf_counter()
    print(f"smoothing of noisy data: {SMOOTH}; bootstrap replicates: {N_REPLICATES}\n")
    if "bands" in tables:
        print("| bands | noise (mm) | seeds | max err | weak err | hom gap | GN \\|e\\|/se | GN cover 95 % | "
              "BS \\|e\\|/se | BS cover 95 % | found | false |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|")
        for noise in noises:
            for n in (2, 4) if args.quick else [int(v) for v in args.bands.split(",")]:
                print(bands_row(n, noise, range(1 if noise == 0 else n_seeds)), flush=True)
        print()
    if "auto" in tables:
        print("| truth | noise (mm) | seeds | bands chosen (count: seeds) | max err | cover 95 % | flagged | time/seed |")
        print("|---|---|---|---|---|---|---|---|")
        for noise in noises:
            for r in auto_rows(noise, range(1 if noise == 0 else n_seeds)):
                print(r, flush=True)
        print()
    if "legendre" in tables:
        print("| truth | K | noise (mm) | seeds | max err | RMS err | \\|e\\|/se | cover 95 % |")
        print("|---|---|---|---|---|---|---|---|")
        for name, profile in (("30 % gradient", GRADIENT), ("40 % weakening", WEAK)):
            for noise in noises:
                for k in (2, 4) if args.quick else [int(v) for v in args.ks.split(",")]:
                    print(legendre_row(name, profile, k, noise, range(1 if noise == 0 else n_seeds)), flush=True)
    print(f"\n{time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
