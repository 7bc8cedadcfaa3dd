"""The Cramér-Rao bound of ``identification.information`` against a maximum-likelihood Monte-Carlo.

Truth from the simulator's closed-form homogeneous tube (``rig_sim.simulate_test(clamped=False)``: its own marker
layout, stretches and loads, independent of ``identification.tube_forward``); per seed, Gaussian noise on every
marker coordinate (0.17 mm) and on the pressure and wall-force readings (0.1 % of reading, 3 Pa and 2 mN in
quadrature); each seed fitted over all unknowns by ``identification.tube_fit.fit_tube`` (markers profiled in closed
form, scipy least_squares on the rest) from the model's generic initial guess. Reports, per parameter, the bound
(for the simulator's layout), the RMS error and standard deviation over the seeds, their ratio to the bound, the
bias, and the efficiency bound^2 / RMS^2.

Run: ``python -m benchmarks.bench_bound [--seeds 100] [--models fung,delfino,hgo] [--bound-only]`` (about 6 minutes
on one core; the bound table alone, seconds).
Prints the Markdown tables of docs/validation/bound.md.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from identification.information import TubeExperiment, cramer_rao_bound  # noqa: E402
from identification.models import get_model  # noqa: E402
from identification.tube_fit import TubeObservations, fit_tube  # noqa: E402
from identification.tube_forward import MeasurementNoise, TubeGeometry, TubeSteps, uniform_markers  # noqa: E402
from rig_sim.mechanics import PAPER_PARAMETERS, PAPER_PRESSURES, simulate_test  # noqa: E402

R, H, L = 10e-3, 1.3e-3, 35e-3


def monte_carlo(model: str, *, n_seeds: int, sigma: float, n_markers: int = 300, stretch: float = 1.1,
                wall: str = "membrane") -> dict:
    """Bound and measured scatter of one case; returns a dict of per-parameter arrays and timings."""
    truth = PAPER_PARAMETERS[model]
    sim = simulate_test(model, truth, clamped=False, wall=wall, stretches=(stretch,), n_markers=n_markers,
                        marker_margin=0.0, radius=R, thickness=H, length=L)
    noise = MeasurementNoise(sigma)
    steps = TubeSteps(sim.pressure[1:], sim.stretch[1:])
    experiment = TubeExperiment(TubeGeometry(R, H, wall=wall), steps, sim.marker_theta, sim.marker_Z, noise)
    bound = cramer_rao_bound(model, truth, experiment)
    names = get_model(model).parameter_names
    rng = np.random.default_rng(20261127)
    estimates, times, failures = [], [], 0
    p_true, f_true = sim.pressure[1:], sim.axial_force[1:]
    sp, sf = noise.load_sigma(p_true, f_true)
    for _ in range(n_seeds):
        obs = TubeObservations(sim.exact_positions + sigma * rng.standard_normal(sim.exact_positions.shape),
                               p_true + sp * rng.standard_normal(p_true.shape),
                               f_true + sf * rng.standard_normal(f_true.shape))
        t0 = time.perf_counter()
        fit = fit_tube(model, obs, experiment)
        times.append(time.perf_counter() - t0)
        failures += not fit.success
        estimates.append([fit.parameters[p] for p in names])
    est = np.array(estimates)
    values = np.array([truth[p] for p in names])
    err = (est - values) / np.abs(values) * 100.0  # % of value
    rms = np.sqrt(np.mean(err**2, axis=0))
    crb = np.array([bound.std_percent[p] for p in names])
    return {"model": model, "names": names, "bound": crb, "rms": rms, "std": err.std(axis=0, ddof=1),
            "bias": err.mean(axis=0), "within5": np.mean(np.all(np.abs(err[:, :3]) < 5.0, axis=1)) * 100.0,
            "n": n_seeds, "failures": failures, "fit_s": float(np.median(times)), "sigma": sigma, "wall": wall,
            "condition": bound.condition}


def table(case: dict) -> str:
    lines = [f"\n### {case['model']} ({case['wall']}), one stretch 1.1, 300 markers, {case['sigma'] * 1e3:g} mm, "
             f"{case['n']} seeds (median fit {case['fit_s']:.2f} s, {case['failures']} not converged)\n",
             "| parameter | bound (% of value) | RMS error (%) | std (%) | RMS / bound | std / bound | bias (%) | "
             "efficiency bound²/RMS² |", "|---|---|---|---|---|---|---|---|"]
    for i, p in enumerate(case["names"]):
        b, r, s = case["bound"][i], case["rms"][i], case["std"][i]
        lines.append(f"| {p} | {b:.3g} | {r:.3g} | {s:.3g} | {r / b:.2f} | {s / b:.2f} | {case['bias'][i]:+.2g} | "
                     f"{(b / r) ** 2:.2f} |")
    if case["model"] == "fung":
        lines.append(f"\nFits with beta, alpha11 and alpha22 all within 5 %: {case['within5']:.0f} %.")
    return "\n".join(lines)


#: (label, model, stretches, markers, sigma [m], wall, stretch_per, margin [m], exact loads, reference figures)
BOUND_CASES = [
    ("one stretch 1.1", "fung", (1.1,), 300, 0.17e-3, "membrane", "step", 0.0, False, "2.75 1.24 2.92 72"),
    ("one stretch 1.1", "delfino", (1.1,), 300, 0.17e-3, "membrane", "step", 0.0, False, "1.61 0.51"),
    ("one stretch 1.1", "hgo", (1.1,), 300, 0.17e-3, "membrane", "step", 0.0, False, "14.5 2.26 1.28 0.13"),
    ("0.05 mm", "fung", (1.1,), 300, 0.05e-3, "membrane", "step", 0.0, False, "0.88 0.40 0.97"),
    ("0.01 mm", "fung", (1.1,), 300, 0.01e-3, "membrane", "step", 0.0, False, "0.31 0.14 0.48"),
    ("3 stretches 1.05/1.1/1.15", "fung", (1.05, 1.1, 1.15), 300, 0.17e-3, "membrane", "step", 0.0, False,
     "1.04 0.63 0.89 22"),
    ("10,000 points", "fung", (1.1,), 10000, 0.17e-3, "membrane", "step", 0.0, False, "0.57 0.26 0.68"),
    ("central 27 mm marked", "fung", (1.1,), 300, 0.17e-3, "membrane", "step", 4e-3, False, "2.83 – 3.36"),
    ("one stretch per block", "fung", (1.1,), 300, 0.17e-3, "membrane", "block", 0.0, False, "2.35 – 2.50"),
    ("thick wall", "fung", (1.1,), 300, 0.17e-3, "thick", "step", 0.0, False, "2.86 – 2.98"),
    ("exact loads, one stretch per block", "fung", (1.1,), 300, 0.17e-3, "membrane", "block", 0.0, True,
     "singular (cond ~1e15)"),
]


def bound_table() -> str:
    """The bound (std, % of value) of the cases of the independent computation, with its figures beside."""
    lines = ["| case | model | bound, std % of value (parameters in model order) | condition | time (s) | "
             "independent computation |", "|---|---|---|---|---|---|"]
    for label, model, stretches, n, sigma, wall, per, margin, exact, ref in BOUND_CASES:
        theta, z = uniform_markers(n, L, margin=margin)
        noise = MeasurementNoise(sigma, 0.0, 0.0, 0.0) if exact else MeasurementNoise(sigma)
        steps = TubeSteps.from_blocks([(s, PAPER_PRESSURES) for s in stretches])
        t0 = time.perf_counter()
        b = cramer_rao_bound(model, PAPER_PARAMETERS[model], TubeExperiment(TubeGeometry(R, H, wall=wall), steps,
                                                                         theta, z, noise, per))
        dt = time.perf_counter() - t0
        shown = " ".join(f"{p} {v:.3g}" for p, v in b.std_percent.items())
        lines.append(f"| {label} | {model} | {shown}{' (singular)' if b.singular else ''} | {b.condition:.2g} | "
                     f"{dt:.2f} | {ref} |")
    return "\n".join(lines)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=100)
    parser.add_argument("--models", default="fung,delfino,hgo")
    parser.add_argument("--sigma-mm", type=float, default=0.17)
    parser.add_argument("--bound-only", action="store_true", help="only the bound table (seconds)")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    print("## The bound at the independent computation's cases (layout: uniform_markers, fixed cannula at Z = 0)\n")
    print(bound_table(), flush=True)
    if args.bound_only:
        return
    for model in args.models.split(","):
        print(table(monte_carlo(model, n_seeds=args.seeds, sigma=args.sigma_mm * 1e-3)), flush=True)
    print(f"\nTotal {time.perf_counter() - t0:.0f} s.")


if __name__ == "__main__":
    main()
