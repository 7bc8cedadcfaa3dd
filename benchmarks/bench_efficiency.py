"""Efficiency of the product identifier against the project's Cramér-Rao bound (issue 24).

Truth from the simulator's tube (``rig_sim.simulate_test``: closed-form homogeneous tube for free ends, the
clamped BVP for clamped ends; its own marker layout), the seed paper's protocol (R 10 mm, H 1.3 mm, 35 mm, 300
markers, 8 levels 0-150 mmHg per axial stretch). Per seed: i.i.d. Gaussian noise on every marker coordinate at every
step, the reference included, and on the pressure and wall-force readings (0.1 % of reading, floors 3 Pa and 2 mN
in quadrature: ``MeasurementNoise``). Each seed is identified by ``identification.identify`` with each estimator
asked for; the bound is ``cramer_rao_bound`` for the same layout, steps and noise (a homogeneous tube: for clamped
ends it is the bound of the free tube with the same markers, an approximation). Efficiency per parameter =
bound^2 / RMS^2 (RMS error over the seeds, so bias counts).

Run: ``python -m benchmarks.bench_efficiency [--models fung,delfino,hgo] [--sigmas-mm 0.01,0.05,0.17]
[--walls membrane,thick] [--ends free,clamped] [--stretches 1.1 | 1.05/1.1/1.15] [--seeds 40]
[--estimators default,noise,efficient] [--diagnose] [--coverage gls,bootstrap]``. The default is a reduced quick set (Fung, Delfino and HGO at 0.17 mm,
membrane, free ends, one stretch, 40 seeds). Prints Markdown tables (docs/validation/efficiency.md).

``--part speed [--seeds 20]``: time per fit of the efficient path, Fung at 0.17 mm (300 markers x 8 loaded steps and
the reference, free membrane), in-process, against the same path with its first gap covariance (every derivative by
``prepare``: ``benchmarks._efficient_fd``) and the paper's fit, side by side on the same seeds (the order rotated
per seed); and the largest relative difference of the parameters between the two covariances.
"""

from __future__ import annotations

import argparse
import logging
import os
import time
import warnings

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from identification import efficient as efficient_module  # noqa: E402
from identification.optimize import identify  # noqa: E402  (the fit under the case's stated wall and ends)
from identification.information import TubeExperiment, cramer_rao_bound  # noqa: E402
from identification.models import get_model  # noqa: E402
from identification.tube_forward import MeasurementNoise, TubeGeometry, TubeSteps  # noqa: E402
from rig_sim.mechanics import PAPER_PARAMETERS, simulate_test  # noqa: E402

from ._efficient_fd import FiniteDifferenceGapCovariance  # noqa: E402

R, H, L = 10e-3, 1.3e-3, 35e-3
#: Unmarked strip next to each cannula of the clamped tube (the free tube is marked over its whole length).
CLAMPED_MARGIN = 4e-3

#: name -> keyword options of ``identification.identify`` (on top of model, wall, ends, thickness).
ESTIMATORS = {
    "default": dict(smoothing="auto"),                       # the CLI's defaults: the paper's fields and cost
    "noise": dict(smoothing="auto", weighting="noise"),      # the gaps weighted by their measured noise
    "efficient": dict(smoothing="auto", weighting="efficient"),  # issue 24: GLS over the full gap covariance
}


def simulate_case(model: str, *, wall: str, ends: str, stretches: tuple, n_markers: int = 300):
    """The exact simulated test of one case (seeded layout 0)."""
    clamped = ends == "clamped"
    return simulate_test(model, PAPER_PARAMETERS[model], clamped=clamped, wall=wall, stretches=stretches,
                         n_markers=n_markers, marker_margin=CLAMPED_MARGIN if clamped else 0.0, radius=R,
                         thickness=H, length=L)


def case_bound(model: str, sim, sigma: float, *, wall: str, stretch_per: str = "step"):
    """``cramer_rao_bound`` of the simulated layout and steps (std, % of value, per parameter in model order)."""
    steps = TubeSteps(sim.pressure[1:], sim.stretch[1:])
    exp = TubeExperiment(TubeGeometry(R, H, wall=wall), steps, sim.marker_theta, sim.marker_Z,
                         MeasurementNoise(sigma), stretch_per)
    b = cramer_rao_bound(model, PAPER_PARAMETERS[model], exp)
    return np.array([b.std_percent[p] for p in get_model(model).parameter_names])


def noisy_data(sim, sigma: float, rng: np.random.Generator):
    """Positions (every step, reference included), pressure and force readings with the measurement noise."""
    noise = MeasurementNoise(sigma)
    p, f = np.array(sim.pressure), np.array(sim.axial_force)
    sp, sf = noise.load_sigma(p[1:], f[1:])
    x = sim.exact_positions + sigma * rng.standard_normal(sim.exact_positions.shape)
    p_meas, f_meas = p.copy(), f.copy()
    p_meas[1:] += sp * rng.standard_normal(sp.shape)
    f_meas[1:] += sf * rng.standard_normal(sf.shape)
    return x, p_meas, f_meas


def run_case(model: str, sigma: float, *, wall: str = "membrane", ends: str = "free", stretches=(1.1,),
             n_seeds: int = 40, estimators=("default", "noise"), first_seed: int = 0) -> dict:
    """Errors (% of value) of every estimator over the seeds, the bound and the fit times of one case."""
    sim = simulate_case(model, wall=wall, ends=ends, stretches=tuple(stretches))
    names = get_model(model).parameter_names
    truth = np.array([PAPER_PARAMETERS[model][p] for p in names])
    bound = case_bound(model, sim, sigma, wall=wall)
    errors = {e: [] for e in estimators}
    times = {e: [] for e in estimators}
    failed = {e: 0 for e in estimators}
    for seed in range(first_seed, first_seed + n_seeds):
        x, p, f = noisy_data(sim, sigma, np.random.default_rng([20261127, seed]))
        for e in estimators:
            t0 = time.perf_counter()
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    res = identify(x, p, f, thickness=H, model=model, wall=wall, ends=ends, **ESTIMATORS[e])
                est = np.array([res.parameters[n] for n in names])
            except Exception as exc:  # noqa: BLE001 - a failed fit counts as a failure, the bench goes on
                logging.getLogger(__name__).warning("%s seed %d %s failed: %s", model, seed, e, exc)
                failed[e] += 1
                continue
            times[e].append(time.perf_counter() - t0)
            errors[e].append((est - truth) / np.abs(truth) * 100.0)
    return {"model": model, "names": names, "sigma": sigma, "wall": wall, "ends": ends, "stretches": tuple(stretches),
            "bound": bound, "errors": {e: np.array(v) for e, v in errors.items()},
            "time": {e: float(np.median(v)) if v else float("nan") for e, v in times.items()}, "failed": failed,
            "n": n_seeds}


#: (label, noise on the loaded steps' markers, on the reference markers, on the readings, identify options)
DIAGNOSIS = [
    ("all noise, paper's cost", True, True, True, dict(smoothing="auto")),
    ("exact markers, noisy readings, paper's cost", False, False, True, dict(smoothing="auto")),
    ("noisy markers, exact readings, paper's cost", True, True, False, dict(smoothing="auto")),
    ("loaded steps' markers only, paper's cost", True, False, False, dict(smoothing="auto")),
    ("reference markers only, paper's cost", False, True, False, dict(smoothing="auto")),
    ("all noise, smoothing (2, 0), paper's cost", True, True, True, dict(smoothing=(2, 0))),
    ("all noise, smoothing (4, 2), paper's cost", True, True, True, dict(smoothing=(4, 2))),
    ("all noise, weighting noise", True, True, True, dict(smoothing="auto", weighting="noise")),
    ("all noise, weighting efficient", True, True, True, dict(smoothing="auto", weighting="efficient")),
    ("exact reference, weighting efficient", True, False, True, dict(smoothing="auto", weighting="efficient")),
    ("all noise, efficient + reference_noise_correction", True, True, True,
     dict(smoothing="auto", weighting="efficient", reference_noise_correction=True)),
]


def coverage(model: str, sigma: float, methods, *, wall: str = "membrane", ends: str = "free", stretches=(1.1,),
             n_seeds: int = 40, first_seed: int = 0) -> str:
    """Coverage of the efficient fit's 95 % intervals (``uncertainty`` each of ``methods``: "gls", "bootstrap"):
    the fraction of seeds whose interval holds the truth, per parameter; the median half-width (%), the RMS of
    (estimate - truth) / standard error, and w95, the factor on the half-width that would cover 95 % of the seeds
    (the 95th percentile of |z| / 1.96; the stderr's (estimate - truth) / stderr, the interval in log scale for the
    positive parameters: close, not equal)."""
    sim = simulate_case(model, wall=wall, ends=ends, stretches=tuple(stretches))
    names = get_model(model).parameter_names
    truth = PAPER_PARAMETERS[model]
    hits = {m: [] for m in methods}
    half = {m: [] for m in methods}
    z = {m: [] for m in methods}
    times = {m: [] for m in methods}
    for seed in range(first_seed, first_seed + n_seeds):
        x, p, f = noisy_data(sim, sigma, np.random.default_rng([20261127, seed]))
        for m in methods:
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                res = identify(x, p, f, thickness=H, model=model, wall=wall, ends=ends, smoothing="auto",
                               weighting="efficient", uncertainty=m)
            times[m].append(time.perf_counter() - t0)
            iv = res.uncertainty.interval
            hits[m].append([iv[n][0] <= truth[n] <= iv[n][1] for n in names])
            half[m].append([(iv[n][1] - iv[n][0]) / 2 / abs(truth[n]) * 100 for n in names])
            z[m].append([(res.parameters[n] - truth[n]) / res.stderr[n] for n in names])
    label = f"{model} {sigma * 1e3:g} mm {wall} {ends} {'/'.join(f'{s:g}' for s in stretches)}"
    rows = ["| case | uncertainty | " + " | ".join(f"{n} covered / half-width (%) / RMS z / w95" for n in names)
            + " | s per fit |", "|---|---|" + "---|" * len(names) + "---|"]
    for m in methods:
        h, w, zz = np.array(hits[m]), np.array(half[m]), np.array(z[m])
        # w95: the factor on the half-width that would have covered 95 % of these seeds
        cells = [f"{h[:, i].mean():.0%} / {np.median(w[:, i]):.3g} / {np.sqrt(np.mean(zz[:, i] ** 2)):.2f} / "
                 f"{np.quantile(np.abs(zz[:, i]), 0.95) / 1.96:.2f}" for i in range(len(names))]
        rows.append(f"| {label} ({len(h)} seeds) | {m} | " + " | ".join(cells) + f" | {np.median(times[m]):.2f} |")
    return "\n".join(rows)


def diagnose(model: str, sigma: float, n_seeds: int) -> str:
    """Where the information is lost: each noise source alone, and each lever, on the same seeds (free membrane
    tube, one stretch 1.1); efficiency against the bound of all noise sources."""
    sim = simulate_case(model, wall="membrane", ends="free", stretches=(1.1,))
    names = get_model(model).parameter_names
    truth = np.array([PAPER_PARAMETERS[model][p] for p in names])
    bound = case_bound(model, sim, sigma, wall="membrane")
    noise = MeasurementNoise(sigma)
    lines = [f"| variant ({model}, {sigma * 1e3:g} mm, {n_seeds} seeds) | " + " | ".join(
        f"{p} RMS % (eff.)" for p in names) + " |", "|---|" + "---|" * len(names)]
    for label, loaded, ref, loads, options in DIAGNOSIS:
        err = []
        for seed in range(n_seeds):
            rng = np.random.default_rng([20261127, seed])
            x = np.array(sim.exact_positions)
            n = sigma * rng.standard_normal(x.shape)
            x[1:] += n[1:] * loaded
            x[0] += n[0] * ref
            p, f = np.array(sim.pressure), np.array(sim.axial_force)
            sp, sf = noise.load_sigma(p[1:], f[1:])
            p[1:] += sp * rng.standard_normal(sp.shape) * loads
            f[1:] += sf * rng.standard_normal(sf.shape) * loads
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                res = identify(x, p, f, thickness=H, model=model, wall="membrane", ends="free", **options)
            err.append((np.array([res.parameters[k] for k in names]) - truth) / np.abs(truth) * 100.0)
        rms = np.sqrt(np.mean(np.array(err) ** 2, axis=0))
        lines.append(f"| {label} | " + " | ".join(f"{r:.3g} ({(b / r) ** 2:.2f})" for r, b in zip(rms, bound)) + " |")
        print(lines[-1], flush=True)
    return "\n".join(lines)


def summary(case: dict, estimator: str) -> dict:
    """RMS, bias and efficiency per parameter of one estimator in one case."""
    err = case["errors"][estimator]
    rms = np.sqrt(np.mean(err**2, axis=0))
    return {"rms": rms, "bias": err.mean(axis=0), "eff": (case["bound"] / rms) ** 2}


def table(cases: list[dict], estimators) -> str:
    """One Markdown row per case and parameter: the bound, then RMS and efficiency of each estimator."""
    head = "| case | parameter | bound (%) | " + " | ".join(f"{e} RMS (%) | {e} eff." for e in estimators) + " |"
    lines = [head, "|" + "---|" * (3 + 2 * len(estimators))]
    for c in cases:
        label = (f"{c['model']} {c['sigma'] * 1e3:g} mm {c['wall']} {c['ends']} "
                 f"{'/'.join(f'{s:g}' for s in c['stretches'])}")
        sums = {e: summary(c, e) for e in estimators}
        for i, p in enumerate(c["names"]):
            cells = " | ".join(f"{sums[e]['rms'][i]:.3g} | {sums[e]['eff'][i]:.2f}" for e in estimators)
            lines.append(f"| {label} | {p} | {c['bound'][i]:.3g} | {cells} |")
        info = "; ".join(f"{e}: median {c['time'][e] * 1e3:.0f} ms, {c['failed'][e]} failed" for e in estimators)
        lines.append(f"| {label} | ({c['n']} seeds; {info}) | | " + " | ".join(" | " for _ in estimators) + " |")
    return "\n".join(lines)


#: ``--part speed``: label -> (identify options, the gap covariance of the efficient path or None)
SPEED_VARIANTS = {
    "paper's fit": (dict(smoothing="auto"), None),
    "efficient, every derivative by prepare (before)": (dict(smoothing="auto", weighting="efficient"),
                                                        FiniteDifferenceGapCovariance),
    "efficient": (dict(smoothing="auto", weighting="efficient"), efficient_module.GapCovariance),
}


def _timed_fit(x, p, f, options, covariance):
    """Seconds and parameters of one fit of the free membrane Fung case with the given gap covariance class."""
    product = efficient_module.GapCovariance
    if covariance is not None:
        efficient_module.GapCovariance = covariance
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t0 = time.perf_counter()
            res = identify(x, p, f, thickness=H, model="fung", wall="membrane", ends="free", **options)
            return time.perf_counter() - t0, np.array(list(res.parameters.values()))
    finally:
        efficient_module.GapCovariance = product


def speed(n_seeds: int, first_seed: int = 0) -> str:
    """Median time per fit of each of ``SPEED_VARIANTS`` on the same seeds (Fung, 0.17 mm, free membrane, one
    stretch), and the largest relative parameter difference of the efficient path before and after."""
    sim = simulate_case("fung", wall="membrane", ends="free", stretches=(1.1,))
    names = list(SPEED_VARIANTS)
    times = {k: [] for k in names}
    params = {k: [] for k in names}
    for i, seed in enumerate(range(first_seed, first_seed + n_seeds)):
        x, p, f = noisy_data(sim, 0.17e-3, np.random.default_rng([20261127, seed]))
        for k in names[i % len(names):] + names[:i % len(names)]:
            t, est = _timed_fit(x, p, f, *SPEED_VARIANTS[k])
            times[k].append(t)
            params[k].append(est)
    before, after = np.array(params[names[1]]), np.array(params[names[2]])
    rel = np.max(np.abs(after - before) / np.maximum(np.abs(before), 1e-300), axis=0)
    lines = ["| fit (Fung 0.17 mm, 300 markers x 8 steps + reference) | median ms per fit | x the paper's fit |",
             "|---|---|---|"]
    paper = float(np.median(times[names[0]]))
    lines += [f"| {k} | {np.median(v) * 1e3:.0f} | {np.median(v) / paper:.1f} |" for k, v in times.items()]
    lines.append(f"\n{n_seeds} seeds; per-seed ratio before / after: median "
                 f"{np.median(np.array(times[names[1]]) / np.array(times[names[2]])):.2f}; largest relative parameter "
                 "difference after vs before: " + ", ".join(
                     f"{n} {r:.1e}" for n, r in zip(get_model("fung").parameter_names, rel)))
    return "\n".join(lines)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", default="fung,delfino,hgo")
    parser.add_argument("--sigmas-mm", default="0.17")
    parser.add_argument("--walls", default="membrane")
    parser.add_argument("--ends", default="free")
    parser.add_argument("--stretches", default="1.1", help="one block per stretch, e.g. 1.05/1.1/1.15; "
                        "several cases comma-separated")
    parser.add_argument("--seeds", type=int, default=40)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--estimators", default="default,noise,efficient")
    parser.add_argument("--diagnose", action="store_true", help="where the information is lost: each noise source "
                        "alone and each lever, first model and sigma, free membrane, one stretch")
    parser.add_argument("--coverage", default=None, help="coverage of the efficient fit's 95 %% intervals with "
                        "these uncertainty methods (gls,bootstrap), each case of the other options")
    parser.add_argument("--part", choices=("efficiency", "speed"), default="efficiency",
                        help="speed: time per fit of the efficient path before and after (Fung 0.17 mm; --seeds)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    if args.part == "speed":
        print(speed(args.seeds, args.first_seed))
        return
    if args.coverage:
        for model in args.models.split(","):
            for sigma in (float(s) * 1e-3 for s in args.sigmas_mm.split(",")):
                for wall in args.walls.split(","):
                    for ends in args.ends.split(","):
                        for st in args.stretches.split(","):
                            print(coverage(model, sigma, args.coverage.split(","), wall=wall, ends=ends,
                                           stretches=tuple(float(s) for s in st.split("/")), n_seeds=args.seeds,
                                           first_seed=args.first_seed), flush=True)
        return
    if args.diagnose:
        print(diagnose(args.models.split(",")[0], float(args.sigmas_mm.split(",")[0]) * 1e-3, args.seeds))
        return
    estimators = tuple(args.estimators.split(","))
    t0 = time.perf_counter()
    cases = []
    for model in args.models.split(","):
        for sigma in (float(s) * 1e-3 for s in args.sigmas_mm.split(",")):
            for wall in args.walls.split(","):
                for ends in args.ends.split(","):
                    for st in args.stretches.split(","):
                        if wall == "thick" and ends == "clamped":
                            continue  # rig_sim has no clamped thick wall
                        cases.append(run_case(model, sigma, wall=wall, ends=ends,
                                              stretches=tuple(float(s) for s in st.split("/")), n_seeds=args.seeds,
                                              estimators=estimators, first_seed=args.first_seed))
                        print(table(cases[-1:], estimators), flush=True)
    print("\n" + table(cases, estimators))
    print(f"\nTotal {time.perf_counter() - t0:.0f} s.")


if __name__ == "__main__":
    main()
