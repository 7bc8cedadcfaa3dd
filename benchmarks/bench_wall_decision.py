"""Is a trusted parameter right when the wall form was left to the data? (docs/validation/trust.md, "The wall
decided on the whitened gaps").

    OMP_NUM_THREADS=1 python -m benchmarks.bench_wall_decision [--seeds 30] [--walls thick,membrane]
        [--sigma-mm 0.17] [--protocol examples/paper-protocol.toml] [--first-seed 0]

Data: ``rig_sim.simulate_test`` tubes (Fung, Table-1 parameters, free ends, 300 markers, the example specimen)
under the protocol's stretches and pressure levels, the reference captured as the protocol says
(``[reference] repeats``), Gaussian noise on every marker coordinate of every capture and on the pressure and
force readings (``benchmarks.bench_protocols.noisy_data``, seeds ``[20261127, seed]``). The simulated wall is
thick (the incompressible thick-wall solution) or membrane (the membrane law: the thin-wall solution). Each
seed is identified by ``identification.identify`` with the library defaults (wall and ends judged from the data,
``reference_repeats`` from the protocol).

Per simulated wall: how often each wall form was chosen, the verdicts, "poor fit", beta/alpha11/alpha22 trusted,
trusted off by more than twice their 95 % half-width (must be 0), trusted intervals covering the truth, and the
seconds per fit.
"""

from __future__ import annotations

import argparse
import logging
import os
import time
import warnings
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from identification import identify  # noqa: E402
from rig_sim.mechanics import PAPER_PARAMETERS, simulate_test  # noqa: E402

from .bench_protocols import noisy_data, protocol_case  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
GOAL = ("beta", "alpha11", "alpha22")


def one_wall(case: dict, wall: str, sigma: float, seeds: range) -> dict:
    """Counts over the seeds for the tube simulated with ``wall``."""
    truth = PAPER_PARAMETERS["fung"]
    sim = simulate_test("fung", truth, radius=case["radius"], length=case["length"], thickness=case["thickness"],
                        stretches=case["stretches"], pressures=case["pressures"], n_markers=300, clamped=False,
                        wall=wall, marker_margin=0.0)
    out = {"chosen": {}, "verdict": {}, "poor": 0, "trusted": 0, "off": 0, "covering": 0, "failed": 0, "s": [],
           "off_cases": []}
    for seed in seeds:
        x, p, f = noisy_data(sim, sigma, np.random.default_rng([20261127, seed]), case["repeats"])
        t0 = time.perf_counter()
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                r = identify(x, p, f, thickness=case["thickness"], model="fung", reference_repeats=case["repeats"])
        except Exception as exc:  # noqa: BLE001 - counted, the bench goes on
            logging.getLogger(__name__).warning("seed %d failed: %s", seed, exc)
            out["failed"] += 1
            continue
        out["s"].append(time.perf_counter() - t0)
        key = f"{r.data.wall} wall, {r.data.ends} ends"
        out["chosen"][key] = out["chosen"].get(key, 0) + 1
        out["verdict"][r.verdict] = out["verdict"].get(r.verdict, 0) + 1
        out["poor"] += any("poor fit" in s for s in r.verdict_reasons)
        for name in GOAL:
            if r.parameter_verdicts.get(name) != "trusted":
                continue
            lo, hi = r.uncertainty.interval[name]
            v = r.parameters[name]
            half = max(v - lo, hi - v)
            out["trusted"] += 1
            out["covering"] += bool(lo <= truth[name] <= hi)
            if abs(v - truth[name]) > 2 * half:
                out["off"] += 1
                out["off_cases"].append(f"seed {seed} {name} {100 * (v / truth[name] - 1):+.1f} % "
                                        f"(+-{100 * half / abs(truth[name]):.1f} %, {key})")
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--protocol", default=str(ROOT / "examples" / "paper-protocol.toml"))
    ap.add_argument("--specimen", default=str(ROOT / "examples" / "specimen.toml"))
    ap.add_argument("--walls", default="thick,membrane")
    ap.add_argument("--seeds", type=int, default=30)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--sigma-mm", type=float, default=0.17)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    case = protocol_case(args.protocol, args.specimen)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    print(f"{Path(args.protocol).name}: stretches {case['stretches']}, reference x{case['repeats']}, Fung, free ends, "
          f"300 markers at {args.sigma_mm:g} mm, loads 0.1 %; seeds {seeds.start}-{seeds.stop - 1}; library defaults")
    print("| simulated wall | chosen (wall, ends: fits) | verdicts | poor fit | beta, alpha11, alpha22 trusted | "
          "trusted off > 2 half-widths | trusted covering | s per fit (median) |")
    print("|---|---|---|---|---|---|---|---|")
    for wall in args.walls.split(","):
        o = one_wall(case, wall, args.sigma_mm * 1e-3, seeds)
        n = len(o["s"])
        chosen = "; ".join(f"{k}: {v}" for k, v in sorted(o["chosen"].items()))
        verdicts = ", ".join(f"{k} {v}" for k, v in sorted(o["verdict"].items()))
        print(f"| {wall} | {chosen} | {verdicts} | {o['poor']}/{n} | {o['trusted']}/{3 * n} | {o['off']} | "
              f"{o['covering']}/{o['trusted']} | {np.median(o['s']) if n else float('nan'):.1f} |", flush=True)
        for c in o["off_cases"]:
            print(f"<!-- off: {wall} wall, {c} -->")
        if o["failed"]:
            print(f"<!-- {o['failed']} fits failed -->")


if __name__ == "__main__":
    main()
