"""Benchmarks of the VFM identification (prints markdown tables; docs/identification.md quotes them).

    OMP_NUM_THREADS=1 PYTHONPATH=. python benchmarks/bench_identification.py [--quick] [--part timing|thick|noise|all]

clamped: exact clamped-tube data with and without the unmeasured-strip term.
flat   : bias of flat chord triangles (the paper taken literally) vs cylindrical interpolation.
timing : time to identify Fung and HGO on 300 markers x 8 pressure steps (clamped membrane tube from
         rig_sim), prepare (mesh + kinematics) and optimisation separately, lsq vs Nelder-Mead, median of repeats.
thick  : bias of the membrane form vs the thick-wall forms on rig_sim's exact thick-walled tube.
noise  : parameter bias and scatter over many noise seeds (0.17 mm and 0.01 mm) on the clamped data,
         without and with displacement smoothing (fixed 4 x 2, and the basis chosen by cross-validation).
coverage: how often the reported 95 % interval contains the true parameters over many noise seeds
         (0.01, 0.05, 0.17 mm): Gauss-Newton (+- 1.96 stderr) vs the parametric bootstrap
         (identification/uncertainty.py), on the paper protocol (one stretch, 8 levels 0-150 mmHg).
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from identification import identify_prepared, prepare  # noqa: E402
from rig_sim.mechanics import PAPER_PARAMETERS, simulate_test  # noqa: E402

MODELS = ("fung", "delfino", "hgo", "neohookean")
NEOHOOKEAN = {"mu": 200e3}  # no paper value; stiff enough to pass 150 mmHg without a limit point


def params_of(model):
    return NEOHOOKEAN if model == "neohookean" else PAPER_PARAMETERS[model]


CLAMPED = True
SYNTH = False  # use the tests' independent clamped-tube solver (30-90 mmHg) instead of rig_sim's


class _Synth:
    """The fields of rig_sim's SimulatedTest that the benchmark uses, from tests/ident_clamped_synth.py."""

    def __init__(self, model):
        sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
        from ident_clamped_synth import clamped_tube

        pos, p, f = clamped_tube(model, params_of(model), np.array([15.0, 30.0, 45.0, 60.0, 75.0, 90.0]) * 133.322387415)
        self.positions = self.exact_positions = pos
        self.pressure, self.axial_force, self.thickness = p, f, 1.3e-3


def simulate(model, *, clamped=None, wall="membrane"):
    clamped = CLAMPED if clamped is None else clamped
    if clamped and SYNTH and wall == "membrane":
        return _Synth(model)
    return simulate_test(model, params_of(model), clamped=clamped, wall=wall, n_markers=300)


def rel_errors(result, truth):
    return {k: result.parameters[k] / truth[k] - 1.0 for k in truth}


def fmt_err(errs):
    return ", ".join(f"{k} {v:+.2%}" for k, v in errs.items())


def bench_timing(repeats):
    print(f"\n## Time to identify (300 markers, 1 reference + 8 pressure steps, {'clamped' if CLAMPED else 'homogeneous'} "
          "membrane tube, exact data)\n")
    print("| model | optimiser | prepare (s) | optimise (s) | cost evaluations | max parameter error |")
    print("|---|---|---|---|---|---|")
    for model in ("fung", "hgo"):
        sim = simulate(model)
        tp = []
        for _ in range(repeats):
            t = time.perf_counter()
            data = prepare(sim.positions, sim.pressure, sim.axial_force, thickness=sim.thickness,
                           ends="clamped" if CLAMPED else "free")
            tp.append(time.perf_counter() - t)
        for opt, reps in (("lsq", repeats), ("nelder-mead", max(1, repeats // 2))):
            times = []
            for _ in range(reps):
                t = time.perf_counter()
                res = identify_prepared(data, model, optimizer=opt)
                times.append(time.perf_counter() - t)
            errs = rel_errors(res, params_of(model))
            worst = max(errs, key=lambda k: abs(errs[k]) if k != "alpha12" else 0)
            print(f"| {model} | {opt} | {np.median(tp):.3f} | {np.median(times):.3f} | {res.n_evaluations} | "
                  f"{worst} {errs[worst]:+.2e} |")
            sys.stdout.flush()


def flat_chord_data(data, positions):
    """The paper taken literally: flat chord triangles, Cartesian linear interpolation (for comparison only)."""
    from dataclasses import replace

    from identification.kinematics import align_steps
    from identification.virtual_fields import paper_fields

    mesh = data.mesh
    tri = mesh.triangles
    ref_local = np.column_stack([mesh.r * np.cos(mesh.theta), mesh.r * np.sin(mesh.theta), mesh.z])
    aligned, _, _ = align_steps(positions, ref_local @ mesh.axis.basis + mesh.axis.origin)
    x = (aligned - mesh.axis.origin) @ mesh.axis.basis.T  # specimen frame
    X = ref_local
    fields = paper_fields(mesh)
    er = np.column_stack([np.cos(mesh.theta), np.sin(mesh.theta), np.zeros_like(mesh.theta)])
    ez = np.array([0.0, 0.0, 1.0])
    u = np.stack([fields.values[k, :, 0:1] * er + fields.values[k, :, 2:3] * ez for k in range(2)])  # (2, n, 3)
    E0 = X[tri[:, 1]] - X[tri[:, 0]], X[tri[:, 2]] - X[tri[:, 0]]
    n0 = np.cross(E0[0], E0[1])
    area0 = 0.5 * np.linalg.norm(n0, axis=1)
    n0 /= np.linalg.norm(n0, axis=1, keepdims=True)
    c = X[tri].mean(1)
    et = np.column_stack([-c[:, 1], c[:, 0], np.zeros(len(c))])
    e1 = et - (et * n0).sum(1, keepdims=True) * n0
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(n0, e1)
    D0 = np.stack([np.stack([(E * e1).sum(1), (E * e2).sum(1)], 1) for E in E0], 2)  # (t, 2, 2)
    D0inv = np.linalg.inv(D0)
    D = np.stack([x[:, tri[:, 1]] - x[:, tri[:, 0]], x[:, tri[:, 2]] - x[:, tri[:, 0]]], -1)  # (s, t, 3, 2)
    F = D @ D0inv
    C = np.swapaxes(F, -1, -2) @ F
    du = np.stack([u[:, tri[:, 1]] - u[:, tri[:, 0]], u[:, tri[:, 2]] - u[:, tri[:, 0]]], -1) @ D0inv  # (f, t, 3, 2)
    G = np.swapaxes(F, -1, -2)[None] @ du[:, None]
    dE = 0.5 * (G + np.swapaxes(G, -1, -2))
    dV0 = area0 * data.thickness
    dens = np.stack([dE[..., 0, 0], dE[..., 1, 1], 2 * dE[..., 0, 1]], -1) * dV0[None, None, :, None]
    nda = 0.5 * np.cross(D[..., 0], D[..., 1])  # (s, t, 3)
    uc = u[:, tri].mean(2)  # (f, t, 3)
    pw = data.pressure[None] * np.einsum("stc,ftc->fs", nda, uc)
    evw = pw + data.end_work
    return replace(data, c=np.stack([C[..., 0, 0], C[..., 1, 1], C[..., 0, 1]], -1), work_density=dens, evw=evw,
                   pressure_work=pw, scale=np.sqrt(np.mean(evw**2, axis=1)))


def bench_flat():
    print("\n## Flat chord triangles (paper taken literally) vs cylindrical interpolation, exact homogeneous data\n")
    print("| model | markers | flat: max gap at true parameters | flat: identified | cylindrical: identified |")
    print("|---|---|---|---|---|")
    from identification import internal_virtual_work

    for model in ("fung", "delfino", "hgo"):
        for n in (100, 300, 1000):
            sim = simulate_test(model, params_of(model), clamped=False, n_markers=n)
            data = prepare(sim.positions, sim.pressure, sim.axial_force, thickness=sim.thickness, ends="free")
            flat = flat_chord_data(data, sim.positions)
            gap = (internal_virtual_work(flat, model, params_of(model)) - flat.evw) / flat.scale[:, None]
            res_flat = identify_prepared(flat, model)
            res_cyl = identify_prepared(data, model)
            print(f"| {model} | {n} | {np.abs(gap).max():.2%} | {fmt_err(rel_errors(res_flat, params_of(model)))} | "
                  f"{fmt_err(rel_errors(res_cyl, params_of(model)))} |")
            sys.stdout.flush()


def bench_clamped():
    print("\n## Exact clamped-tube data: with and without the unmeasured-strip term\n")
    print("| model | ends=\"clamped\" (strip term) | ends=\"free\" (strip ignored) |")
    print("|---|---|---|")
    for model in ("fung", "delfino", "hgo", "neohookean"):
        sim = simulate(model, clamped=True)
        row = []
        for ends in ("clamped", "free"):
            data = prepare(sim.positions, sim.pressure, sim.axial_force, thickness=sim.thickness, ends=ends)
            row.append(fmt_err(rel_errors(identify_prepared(data, model), params_of(model))))
        print(f"| {model} | " + " | ".join(row) + " |")
        sys.stdout.flush()


def bench_thick():
    print("\n## Thick wall (e0/R = 0.13): exact homogeneous thick-walled tube, markers on the outer surface\n")
    print("Relative parameter errors of each form (lsq, paper/generic start).\n")
    print("| model | membrane form | mid-wall (1 layer, pressure on lumen) | thick, 4 layers |")
    print("|---|---|---|---|")
    for model in ("fung", "delfino", "hgo", "neohookean"):
        sim = simulate(model, clamped=False, wall="thick")
        row = []
        for wall, layers in (("membrane", 1), ("thick", 1), ("thick", 4)):
            data = prepare(sim.positions, sim.pressure, sim.axial_force, thickness=sim.thickness, wall=wall,
                           ends="free", n_layers=layers)
            res = identify_prepared(data, model)
            row.append(fmt_err(rel_errors(res, params_of(model))))
        print(f"| {model} | " + " | ".join(row) + " |")
        sys.stdout.flush()


def bench_noise(n_seeds, models, smoothings=(None, (4, 2), "auto")):
    print(f"\n## Noise: bias and scatter over {n_seeds} seeds ({'clamped' if CLAMPED else 'homogeneous'} membrane tube, "
          "300 markers, lsq)\n")
    print("median relative error (robust scatter = half the 16-84 % range); 'ok' = fits whose every parameter "
          "except alpha12 is within 10 %; 'flagged' = fits that raised a warning other than a poorly identifiable "
          "alpha12/c.\n")
    print("| model | noise (mm) | smoothing | parameter | median error | robust scatter | ok | flagged |")
    print("|---|---|---|---|---|---|---|---|")
    for model in models:
        sim = simulate(model)
        truth = params_of(model)
        for noise in (0.17e-3, 0.01e-3):
            for smoothing in smoothings:
                errs = {k: [] for k in truth}
                ok = flagged = 0
                for seed in range(n_seeds):
                    rng = np.random.default_rng([seed, 7])
                    pos = sim.exact_positions + rng.normal(0.0, noise, sim.exact_positions.shape)
                    try:
                        data = prepare(pos, sim.pressure, sim.axial_force, thickness=sim.thickness,
                                       smoothing=smoothing, ends="clamped" if CLAMPED else "free")
                        res = identify_prepared(data, model)
                    except Exception as exc:  # a failed fit counts as not ok
                        logging.getLogger("bench").info("seed %d failed: %s", seed, exc)
                        for k in truth:
                            errs[k].append(np.nan)
                        flagged += 1
                        continue
                    e = rel_errors(res, truth)
                    for k in truth:
                        errs[k].append(e[k])
                    ok += all(abs(e[k]) < 0.1 for k in truth if k != "alpha12")
                    flagged += any(not (f.startswith("alpha12 is poorly") or f.startswith("c is poorly"))
                                   for f in res.flags)
                for k in truth:
                    a = np.array(errs[k])
                    a = a[np.isfinite(a)]
                    if len(a):
                        med = np.median(a)
                        spread = 0.5 * (np.percentile(a, 84) - np.percentile(a, 16))
                    else:
                        med = spread = np.nan
                    sm = ("none" if smoothing is None else smoothing if isinstance(smoothing, str)
                          else f"{smoothing[0]}x{smoothing[1]}")
                    print(f"| {model} | {noise * 1e3:.2f} | {sm} | {k} | {med:+.2%} | {spread:.2%} | "
                          f"{ok}/{n_seeds} | {flagged}/{n_seeds} |")
                sys.stdout.flush()


def _coverage_fit(sim, model, noise, seed, n_replicates):
    """One noisy fit with bootstrap uncertainty: per parameter (error, GN covers, bootstrap covers, half-width)."""
    from identification import identify

    truth = params_of(model)
    rng = np.random.default_rng([seed, 7])
    pos = sim.exact_positions + rng.normal(0.0, noise, sim.exact_positions.shape)
    res = identify(pos, sim.pressure, sim.axial_force, thickness=sim.thickness, model=model,
                   ends="clamped" if CLAMPED else "free", smoothing="auto", uncertainty="bootstrap",
                   uncertainty_options={"n_replicates": n_replicates, "seed": seed})
    gn = res.uncertainty.gauss_newton_stderr
    out = {}
    for k, v in truth.items():
        lo, hi = res.uncertainty.interval[k]
        out[k] = (res.parameters[k] / v - 1.0, abs(res.parameters[k] - v) <= 1.96 * gn[k], lo <= v <= hi,
                  max(res.parameters[k] - lo, hi - res.parameters[k]) / abs(v))
    # flags about alpha12 / HGO c (not covered here: poorly identifiable from one stretch) do not count
    failure = [f for f in res.flags if not (f.startswith(("alpha12 ", "c ")) or "is not resolved" in f)]
    return out, failure, res


def bench_coverage(n_seeds, models, n_replicates, noises=(0.17e-3, 0.05e-3, 0.01e-3), log_path=None):
    """Seeds outermost (every level advances together); one JSON line per fit in ``log_path`` so that
    an interrupted study can still be summarised (``--summarise LOG``)."""
    import json

    sims = {m: simulate(m) for m in models}
    records = []
    out = open(log_path, "a") if log_path else None
    try:
        for seed in range(n_seeds):
            for model in models:
                for noise in noises:
                    try:
                        fit, failure, _ = _coverage_fit(sims[model], model, noise, seed, n_replicates)
                    except Exception as exc:  # a failed fit is reported, not hidden
                        logging.getLogger("bench").warning("%s %.2f mm seed %d failed: %s", model, noise * 1e3,
                                                           seed, exc)
                        continue
                    rec = {"model": model, "noise_m": noise, "seed": seed, "failure": bool(failure),
                           "fit": {k: [float(v[0]), bool(v[1]), bool(v[2]), float(v[3])] for k, v in fit.items()}}
                    records.append(rec)
                    if out:
                        out.write(json.dumps(rec) + "\n")
                        out.flush()
    finally:
        if out:
            out.close()
    print_coverage(records, n_replicates)


def print_coverage(records, n_replicates):
    """The coverage table of the JSON records of ``bench_coverage``."""
    seeds = len({r["seed"] for r in records})
    print(f"\n## Coverage of the reported 95 % intervals ({'clamped' if CLAMPED else 'homogeneous'} membrane tube, "
          f"300 markers, paper protocol, --smooth auto, bootstrap with {n_replicates} replicates, up to {seeds} "
          "seeds)\n")
    print("'GN': estimate +- 1.96 Gauss-Newton stderr (before); 'bootstrap': the reported interval (after). "
          "'unflagged' = fits without a failure flag (non-convergence, bounds, poor fit, failed replicates, model "
          "error); 'resolved' = fits whose interval is within +-5 % (no 'not resolved' flag).\n")
    print("| model | noise (mm) | fits | parameter | median error | within 5 % | GN coverage | bootstrap coverage "
          "| bootstrap coverage, unflagged | median 95 % half-width | resolved |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    groups = {}
    for r in records:
        groups.setdefault((r["model"], r["noise_m"]), []).append(r)
    for (model, noise), recs in sorted(groups.items(), key=lambda kv: (kv[0][0], -kv[0][1])):
        rows = [{k: tuple(v) for k, v in r["fit"].items()} for r in recs]
        _print_coverage_rows(model, noise, rows, np.array([r["failure"] for r in recs]), len(rows))


def _print_coverage_rows(model, noise, rows, failed, n_seeds):
    for k in rows[0] if rows else ():
        if k in ("alpha12", "c"):
            continue
        err = np.array([r[k][0] for r in rows])
        gn = np.array([r[k][1] for r in rows])
        bs = np.array([r[k][2] for r in rows])
        half = np.array([r[k][3] for r in rows])
        ok = ~failed
        print(f"| {model} | {noise * 1e3:.2f} | {len(rows)} | {k} | {np.median(err):+.2%} | {np.mean(np.abs(err) < 0.05):.0%} | "
              f"{gn.mean():.0%} | {bs.mean():.0%} | {bs[ok].mean() if ok.any() else float('nan'):.0%} "
              f"({ok.sum()}/{len(rows)}) | {np.median(half):.1%} | {np.mean(half <= 0.05):.0%} |")
    sys.stdout.flush()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="fewer repeats and seeds (10 instead of 50)")
    ap.add_argument("--part", choices=["timing", "flat", "clamped", "thick", "noise", "coverage", "all"], default="all")
    ap.add_argument("--replicates", type=int, default=8, help="bootstrap replicates per fit (coverage part)")
    ap.add_argument("--log", help="coverage part: append one JSON line per fit to this file")
    ap.add_argument("--summarise", metavar="LOG", help="coverage part: only print the table of a --log file")
    ap.add_argument("--smoothing", default="none,4x2,auto", help="noise part: smoothing variants (none, AxH, auto)")
    ap.add_argument("--noise", default="0.17,0.05,0.01", help="marker noise levels in mm (coverage part)")
    ap.add_argument("--seeds", type=int, default=None, help="noise seeds (default 50, --quick 10)")
    ap.add_argument("--models", default=",".join(MODELS), help="models for the noise study")
    ap.add_argument("--data", choices=["clamped", "clamped-synth", "homogeneous"], default="clamped",
                    help="membrane tube clamped on cannulae (rig_sim, default; or the tests' independent solver, "
                         "6 pressures 15-90 mmHg) or homogeneous (timing and noise parts)")
    args = ap.parse_args(argv)
    global CLAMPED, SYNTH
    CLAMPED = args.data != "homogeneous"
    SYNTH = args.data == "clamped-synth"
    logging.basicConfig(level=logging.ERROR)
    warnings.simplefilter("ignore", RuntimeWarning)
    repeats = 3 if args.quick else 7
    seeds = args.seeds or (10 if args.quick else 50)
    print(f"# bench_identification ({'quick' if args.quick else 'full'}, {args.data} data), numpy {np.__version__}")
    if args.part in ("timing", "all"):
        bench_timing(repeats)
    if args.part in ("flat", "all"):
        bench_flat()
    if args.part in ("clamped", "all"):
        bench_clamped()
    if args.part in ("thick", "all"):
        bench_thick()
    if args.part in ("noise", "all"):
        variants = [None if v == "none" else v if v == "auto" else tuple(int(x) for x in v.split("x"))
                    for v in args.smoothing.split(",")]
        bench_noise(seeds, args.models.split(","), variants)
    if args.summarise:
        import json

        with open(args.summarise) as fh:
            print_coverage([json.loads(line) for line in fh if line.strip()], args.replicates)
    elif args.part in ("coverage", "all"):
        bench_coverage(seeds, [m for m in args.models.split(",") if m != "neohookean"], args.replicates,
                       tuple(float(v) * 1e-3 for v in args.noise.split(",")), args.log)


if __name__ == "__main__":
    main()
