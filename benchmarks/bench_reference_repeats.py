"""Capturing the reference several times (issue 24, ``[reference] repeats``): RMS, fraction within 5 % and bound.

The cases of ``bench_efficiency`` (Fung at 0.17 mm, free membrane tube, 300 markers, 8 levels 0-150 mmHg per
stretch). Per seed the reference is captured N times, each capture with its own independent marker noise (not
sigma / sqrt(N) directly: the averaging code is what is measured), the loaded steps and readings as in
``bench_efficiency.noisy_data``. Each seed is identified by ``identification.identify`` with ``judged=False``
under the stated wall and ends and ``reference_repeats=N`` (the library entry the stage layer calls). The seeds
share their loaded steps' noise across N (the same generator stream), so the columns differ by the reference only.
The bound is ``cramer_rao_bound`` with ``MeasurementNoise(reference_repeats=N)``.

Run: ``python -m benchmarks.bench_reference_repeats [--stretches 1.1,1.05/1.1/1.15] [--repeats 1,4] [--seeds 40]
[--weightings efficient,paper] [--model fung] [--sigma-mm 0.17]``. Prints a Markdown table
(docs/validation/efficiency.md "Capturing the reference several times").
"""

from __future__ import annotations

import argparse
import logging
import os
import time
import warnings

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from benchmarks.bench_efficiency import H, R, simulate_case  # noqa: E402
from identification import identify  # noqa: E402
from identification.information import TubeExperiment, cramer_rao_bound  # noqa: E402
from identification.models import get_model  # noqa: E402
from identification.tube_forward import MeasurementNoise, TubeGeometry, TubeSteps  # noqa: E402
from rig_sim.mechanics import PAPER_PARAMETERS  # noqa: E402

#: Relative error (%) a fit counts as "within".
WITHIN = 5.0


def repeated_data(sim, sigma: float, n_repeats: int, rng_loaded: np.random.Generator,
                  rng_reference: np.random.Generator):
    """Positions (N captures of the reference, then the loaded steps), pressure and force, all with noise.

    Returns positions (N + K, n_markers, 3) m, pressure and force (N + K,) Pa and N."""
    noise = MeasurementNoise(sigma)
    exact = np.asarray(sim.exact_positions, dtype=float)
    p, f = np.array(sim.pressure), np.array(sim.axial_force)
    loaded = exact[1:] + sigma * rng_loaded.standard_normal(exact[1:].shape)
    sp, sf = noise.load_sigma(p[1:], f[1:])
    p_meas = p[1:] + sp * rng_loaded.standard_normal(sp.shape)
    f_meas = f[1:] + sf * rng_loaded.standard_normal(sf.shape)
    refs = exact[0][None] + sigma * rng_reference.standard_normal((n_repeats,) + exact[0].shape)
    x = np.concatenate([refs, loaded])
    return x, np.r_[np.full(n_repeats, p[0]), p_meas], np.r_[np.full(n_repeats, f[0]), f_meas]


def bound_percent(model: str, sim, sigma: float, n_repeats: int) -> np.ndarray:
    """The Cramér-Rao bound (std, % of value) of the case with N captures of the reference averaged."""
    steps = TubeSteps(sim.pressure[1:], sim.stretch[1:])
    exp = TubeExperiment(TubeGeometry(R, H, wall="membrane"), steps, sim.marker_theta, sim.marker_Z,
                         MeasurementNoise(sigma, reference_repeats=n_repeats))
    b = cramer_rao_bound(model, PAPER_PARAMETERS[model], exp)
    return np.array([b.std_percent[p] for p in get_model(model).parameter_names])


def run(model: str, sigma: float, stretches: tuple, repeats, weightings, n_seeds: int) -> list[dict]:
    """One row per (weighting, N): RMS and fraction within 5 % per parameter, the bound, failures."""
    sim = simulate_case(model, wall="membrane", ends="free", stretches=stretches)
    names = get_model(model).parameter_names
    truth = np.array([PAPER_PARAMETERS[model][p] for p in names])
    errors = {(w, n): [] for w in weightings for n in repeats}
    failed = {k: 0 for k in errors}
    for seed in range(n_seeds):
        for n in repeats:
            x, p, f = repeated_data(sim, sigma, n, np.random.default_rng([20261127, seed]),
                                    np.random.default_rng([20261128, seed]))
            for w in weightings:
                try:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        res = identify(x, p, f, thickness=H, model=model, wall="membrane", ends="free",
                                       smoothing="auto", weighting=w, uncertainty="gauss-newton", judged=False,
                                       reference_repeats=n)
                except Exception as exc:  # noqa: BLE001 - a failed fit is counted, the bench goes on
                    logging.getLogger(__name__).warning("seed %d %s N=%d failed: %s", seed, w, n, exc)
                    failed[(w, n)] += 1
                    continue
                errors[(w, n)].append((np.array([res.parameters[k] for k in names]) - truth) / np.abs(truth) * 100)
    rows = []
    for (w, n), err in errors.items():
        e = np.array(err).reshape(-1, len(names))
        rows.append({"weighting": w, "repeats": n, "stretches": stretches, "names": names,
                     "rms": np.sqrt(np.mean(e**2, axis=0)), "within": np.mean(np.abs(e) <= WITHIN, axis=0),
                     "bound": bound_percent(model, sim, sigma, n), "failed": failed[(w, n)], "n": len(e)})
    return rows


def table(rows: list[dict]) -> str:
    names = rows[0]["names"]
    head = ("| stretches | weighting | N | " + " | ".join(f"{p} RMS % (within 5 %)" for p in names) + " | "
            + " | ".join(f"{p} bound %" for p in names) + " | fits |")
    lines = [head, "|" + "---|" * (4 + 2 * len(names))]
    for r in rows:
        cells = " | ".join(f"{v:.3g} ({w:.2f})" for v, w in zip(r["rms"], r["within"]))
        bound = " | ".join(f"{b:.3g}" for b in r["bound"])
        lines.append(f"| {'/'.join(f'{s:g}' for s in r['stretches'])} | {r['weighting']} | {r['repeats']} | {cells} "
                     f"| {bound} | {r['n']} ({r['failed']} failed) |")
    return "\n".join(lines)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="fung")
    parser.add_argument("--sigma-mm", type=float, default=0.17)
    parser.add_argument("--stretches", default="1.1,1.05/1.1/1.15", help="cases, comma-separated; blocks by /")
    parser.add_argument("--repeats", default="1,4", help="captures of the reference, comma-separated")
    parser.add_argument("--weightings", default="efficient,paper")
    parser.add_argument("--seeds", type=int, default=40)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    t0 = time.perf_counter()
    rows: list[dict] = []
    for st in args.stretches.split(","):
        new = run(args.model, args.sigma_mm * 1e-3, tuple(float(s) for s in st.split("/")),
                  [int(n) for n in args.repeats.split(",")], args.weightings.split(","), args.seeds)
        print(table(new), flush=True)
        rows += new
    print(f"\n{args.model} {args.sigma_mm:g} mm, free membrane, {args.seeds} seeds\n")
    print(table(rows))
    print(f"\nTotal {time.perf_counter() - t0:.0f} s.")


if __name__ == "__main__":
    main()
