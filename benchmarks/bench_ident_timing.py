"""Benchmarks of the VFM identification: what a fit costs (prints markdown tables; docs/validation/identification.md
quotes them).

    OMP_NUM_THREADS=1 python -m benchmarks.bench_ident_timing [--quick] [--part timing|starts|all]

timing : time to identify Fung and HGO on 300 markers x 8 pressure steps (clamped membrane tube from
         rig_sim), prepare (mesh + kinematics) and optimisation separately, lsq vs Nelder-Mead, membrane vs
         thick form, and a plain least_squares VFM on the same data in the same run; median of repeats.
         Then the issue-11 figures (goal column). Run it against an older tree (PYTHONPATH) for "before".
starts : how many least-squares starts are needed (is the first start's minimum the best?).

Exact-data accuracy: ``benchmarks.bench_ident_exact``; noise and coverage: ``benchmarks.bench_ident_noise``.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from benchmarks import _common
from benchmarks._common import params_of, rel_errors
from identification import identify_prepared, prepare
from rig_sim.mechanics import PAPER_PARAMETERS

CLAMPED = True
SYNTH = False  # use the independent clamped-tube solver (rig_sim/clamped_reference.py) instead of rig_sim's mechanics


def simulate(model):
    """:func:`benchmarks._common.simulate` (membrane) with this run's ``--data`` (CLAMPED, SYNTH)."""
    return _common.simulate(model, clamped=CLAMPED, synth=SYNTH)


def _median_time(fn, repeats):
    """Median CPU time (s) of ``fn()`` over ``repeats`` calls, and its last result.

    CPU time of this process (``time.process_time``), not wall time: on the shared machine the wall
    time of a single-threaded call (OMP_NUM_THREADS=1) is its CPU time plus the time other jobs held
    the core, which says nothing about this code.
    """
    times, out = [], None
    for _ in range(repeats):
        t = time.process_time()
        out = fn()
        times.append(time.process_time() - t)
    return float(np.median(times)), out


def _interleaved(fns, repeats):
    """Median CPU time (s) of each of ``fns`` called in turn ``repeats`` times (ratios from one run)."""
    times = [[] for _ in fns]
    for _ in range(repeats):
        for k, fn in enumerate(fns):
            t = time.process_time()
            fn()
            times[k].append(time.process_time() - t)
    return [float(np.median(t)) for t in times]


def _cold_prepare(sim, **options):
    """:func:`benchmarks._common.cold_prepare` with this run's ends (CLAMPED)."""
    return _common.cold_prepare(sim, clamped=CLAMPED, **options)


def plain_vfm(positions, pressure, axial_force, thickness):
    """A plain VFM with ``scipy.optimize.least_squares`` (the reference the issue compares against).

    What a straightforward implementation of the paper does, preprocessing included: principal axis by
    SVD, Delaunay triangles on the unrolled reference surface, flat-triangle kinematics, the paper's two
    virtual fields, the Fung stress in closed form, ``least_squares`` with its default finite-difference
    Jacobian from the paper's initial guess (log scale for the positive parameters). Fung only.
    """
    from scipy.optimize import least_squares
    from scipy.spatial import Delaunay

    X = positions[0]
    centre = X.mean(0)
    _, _, vt = np.linalg.svd(X - centre, full_matrices=False)
    d = vt[0] if abs(vt[0][2]) > 0.5 else vt[np.argmax(np.abs(vt[:, 2]))]
    d = d * np.sign(d[2])
    ex = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
    ex /= np.linalg.norm(ex)
    basis = np.stack([ex, np.cross(d, ex), d])
    loc = (positions - centre) @ basis.T  # (s, n, 3) specimen frame
    R0 = np.hypot(loc[0, :, 0], loc[0, :, 1])
    th0, z0 = np.arctan2(loc[0, :, 1], loc[0, :, 0]), loc[0, :, 2]
    tri = Delaunay(np.column_stack([R0.mean() * th0, z0])).simplices
    tri = tri[np.ptp(th0[tri], axis=1) < np.pi]  # drop the triangles across the seam
    zeta = np.clip((z0 - z0.min()) / np.ptp(z0), 0.0, 1.0)
    er = np.column_stack([np.cos(th0), np.sin(th0), np.zeros_like(th0)])
    u = np.stack([np.sin(np.pi * zeta)[:, None] * er, zeta[:, None] * np.array([0.0, 0.0, 1.0])])  # (2, n, 3)
    E0 = np.stack([loc[0, tri[:, 1]] - loc[0, tri[:, 0]], loc[0, tri[:, 2]] - loc[0, tri[:, 0]]], -1)  # (t, 3, 2)
    n0 = np.cross(E0[..., 0], E0[..., 1])
    area0 = 0.5 * np.linalg.norm(n0, axis=1)
    n0 /= 2.0 * area0[:, None]
    c0 = loc[0][tri].mean(1)
    e1 = np.column_stack([-c0[:, 1], c0[:, 0], np.zeros(len(c0))])
    e1 -= (e1 * n0).sum(1, keepdims=True) * n0
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    frame = np.stack([e1, np.cross(n0, e1)], 1)  # (t, 2, 3)
    D0inv = np.linalg.inv(frame @ E0)
    D = np.stack([loc[:, tri[:, 1]] - loc[:, tri[:, 0]], loc[:, tri[:, 2]] - loc[:, tri[:, 0]]], -1)  # (s, t, 3, 2)
    F = D @ D0inv
    E = 0.5 * (np.swapaxes(F, -1, -2) @ F - np.eye(2))
    du = np.stack([u[:, tri[:, 1]] - u[:, tri[:, 0]], u[:, tri[:, 2]] - u[:, tri[:, 0]]], -1) @ D0inv  # (f, t, 3, 2)
    G = np.swapaxes(F, -1, -2)[None] @ du[:, None]
    dE = 0.5 * (G + np.swapaxes(G, -1, -2)) * (area0 * thickness)[None, None, :, None, None]
    nda = 0.5 * np.cross(D[..., 0], D[..., 1])
    evw = pressure[None] * np.einsum("stc,ftc->fs", nda, u[:, tri].mean(2))
    evw[1] += axial_force
    scale = np.sqrt(np.mean(evw**2, axis=1, keepdims=True))
    e11, e22 = E[..., 0, 0], E[..., 1, 1]

    def residual(x):
        beta, a11, a22, a12 = np.exp(x[0]), np.exp(x[1]), np.exp(x[2]), x[3]
        g = 0.5 * beta * np.exp(a11 * e11**2 + a22 * e22**2 + a12 * e11 * e22)
        ivw = np.einsum("st,fst->fs", g * (2 * a11 * e11 + a12 * e22), dE[..., 0, 0]) + \
            np.einsum("st,fst->fs", g * (2 * a22 * e22 + a12 * e11), dE[..., 1, 1])
        return ((ivw - evw) / scale).ravel()

    x0 = np.array([np.log(29e3), np.log(2.5), np.log(0.5), 0.17])
    sol = least_squares(residual, x0, method="trf", xtol=1e-10, ftol=1e-10, gtol=1e-10, max_nfev=2000)
    return dict(zip(("beta", "alpha11", "alpha22", "alpha12"), [*np.exp(sol.x[:3]), sol.x[3]])), sol.nfev


def bench_timing(repeats, nelder_mead=True, skip_slow=False):
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"\n## Time to identify (300 markers, 1 reference + 8 pressure steps, {'clamped' if CLAMPED else 'homogeneous'} "
          f"membrane tube, exact data; median CPU time of {repeats}; load average {load:.1f} on {os.cpu_count()} cores)\n")
    totals = _timing_table(repeats, nelder_mead)
    sim = simulate("fung")
    data = _cold_prepare(sim)

    def ours():
        identify_prepared(_cold_prepare(sim), "fung")

    def plain():
        plain_vfm(sim.positions, sim.pressure, sim.axial_force, sim.thickness)

    t_ours, t_plain, t_prep, t_warm, t_opt = _interleaved(
        [ours, plain, lambda: _cold_prepare(sim),
         lambda: prepare(sim.positions, sim.pressure, sim.axial_force, thickness=sim.thickness,
                         ends="clamped" if CLAMPED else "free"),
         lambda: identify_prepared(data, "fung")], max(3 * repeats, 9))
    plain_params, nfev = plain_vfm(sim.positions, sim.pressure, sim.axial_force, sim.thickness)
    errs = rel_errors(type("R", (), {"parameters": plain_params})(), params_of("fung"))
    print(f"\nPlain least_squares VFM (flat triangles, finite-difference Jacobian, preprocessing included), Fung: "
          f"{t_plain * 1e3:.1f} ms, {nfev} evaluations, alpha11 {errs['alpha11']:+.1%}, alpha22 {errs['alpha22']:+.1%}; "
          f"ours in the same loop: {t_ours * 1e3:.1f} ms (prepare {t_prep * 1e3:.1f} ms cold, {t_warm * 1e3:.1f} ms "
          f"with the mesh cached; optimise {t_opt * 1e3:.1f} ms).\n")
    command = [] if skip_slow else _command_times(sim, max(3, repeats // 2))
    fe_time, fe_note = (None, "not run (--in-process)") if skip_slow else _fe_thick_time(repeats)
    print("| figure | measured | goal | issue 11 (before, quiet machine, homogeneous data) |")
    print("|---|---|---|---|")
    fung, hgo = totals[("fung", "membrane", "lsq")], totals[("hgo", "membrane", "lsq")]
    hgo_prep, hgo_opt = PARTS[("hgo", "membrane", "lsq")]
    rows = [
        ("Fung fit, prepare + optimise (one call, caches cleared)", f"{t_ours * 1e3:.1f} ms", "<= 10 ms", "48 + 65 ms"),
        ("... of which prepare (axis fits, mesh, kinematics, fields)", f"{t_prep * 1e3:.1f} ms", "<= 5 ms", "48 ms"),
        ("... of which optimise (prepared data)", f"{t_opt * 1e3:.1f} ms", "", "65 ms"),
        ("plain least_squares VFM / ours (Fung, same data, same loop)", f"{t_plain / t_ours:.2f}x", ">= 1.5x", "0.45x"),
        ("HGO fit with its multi-start, prepare + optimise",
         f"{hgo * 1e3:.1f} ms ({hgo_prep * 1e3:.1f} + {hgo_opt * 1e3:.1f})", "<= 30 ms", "80-130 ms"),
        ("thick (4 layers) / membrane, Fung", f"{totals[('fung', 'thick', 'lsq')] / fung:.2f}x", "<= 2x", "~4x"),
        ("thick (4 layers) / membrane, HGO", f"{totals[('hgo', 'thick', 'lsq')] / hgo:.2f}x", "<= 2x", "~4x"),
        ("thick form, HGO, clamped data, prepare + optimise", f"{totals[('hgo', 'thick', 'lsq')] * 1e3:.0f} ms",
         "<= 100 ms", "3.2 s (FE data)"),
        ("thick form, HGO, clamped FE data (felupe), prepare + optimise",
         "n/a" if fe_time is None else f"{fe_time * 1e3:.0f} ms ({fe_note})", "<= 100 ms", "3.2 s"),
        ("prepare again on the same markers (reprocessing: mesh and step kinematics cached)", f"{t_warm * 1e3:.1f} ms", "", ""),
    ] + [(f"`vfmlab {label}`, CPU time of the whole command", f"{t:.2f} s", "<= 0.5 s" if "identify" in label else "",
          "1.4 s" if "bootstrap" in label else "") for label, t in command]
    for row in rows:
        print("| " + " | ".join(row) + " |")
    sys.stdout.flush()


#: (prepare, optimise) median CPU times (s) of ``_timing_table``'s rows, by (model, wall, optimiser)
PARTS: dict = {}


def _timing_table(repeats, nelder_mead):
    """Prepare and optimise times per model, wall form and optimiser: {(model, wall, optimiser): total s}."""
    print("| model | wall | optimiser | prepare (ms) | optimise (ms) | total (ms) | cost evaluations | max parameter error |")
    print("|---|---|---|---|---|---|---|---|")
    totals = {}
    for model in ("fung", "hgo"):
        sim = simulate(model)
        for wall in ("membrane", "thick"):
            tp, data = _median_time(lambda: _cold_prepare(sim, wall=wall), repeats)
            for opt in (("lsq", "nelder-mead") if wall == "membrane" and nelder_mead else ("lsq",)):
                reps = repeats if opt == "lsq" else 1
                to, res = _median_time(lambda: identify_prepared(data, model, optimizer=opt), reps)
                errs = rel_errors(res, params_of(model))
                worst = max(errs, key=lambda k: abs(errs[k]) if k not in ("alpha12", "c") else 0)
                totals[(model, wall, opt)] = tp + to
                PARTS[(model, wall, opt)] = (tp, to)
                print(f"| {model} | {wall} | {opt} | {tp * 1e3:.1f} | {to * 1e3:.1f} | {(tp + to) * 1e3:.1f} | "
                      f"{res.n_evaluations} | {worst} {errs[worst]:+.2e} |")
                sys.stdout.flush()
    return totals


def _fe_thick_time(repeats):
    """CPU time (s) of the thick-form HGO fit (cold prepare + optimise) on the clamped finite-element tube
    of ``tests/test_ident_fe_tube.py`` (felupe, 24 x 3 elements, 200 markers), and its largest error
    in k1, k2, phi; (None, reason) without felupe."""
    try:
        from rig_sim.fe_tube import fe_markers, solve_fe_tube
        from rig_sim.mechanics import MMHG

        fe = solve_fe_tube("hgo", PAPER_PARAMETERS["hgo"], pressures=tuple(np.array([30.0, 60.0, 90.0, 120.0, 150.0])
                                                                            * MMHG),
                           stretch=1.1, clamped=True, n_axial=24, n_radial=3)
    except ImportError as exc:
        return None, f"not run: {exc}"
    pos = fe_markers(fe, 200, seed=1)

    class _FE:
        positions, pressure, axial_force, thickness = pos, fe.pressure, fe.wall_force, fe.thickness

    def fit():
        return identify_prepared(_cold_prepare(_FE, wall="thick"), "hgo")

    t, res = _median_time(fit, repeats)
    errs = rel_errors(res, {k: PAPER_PARAMETERS["hgo"][k] for k in ("k1", "k2", "phi")})
    worst = max(errs, key=lambda k: abs(errs[k]))
    return t, f"{res.n_evaluations} evaluations; {worst} {errs[worst]:+.2%}"


def _command_times(sim, repeats):
    """Median CPU time (s, user + system of the child) of ``vfmlab identify`` on a 300-marker session."""
    import resource
    import subprocess
    import tempfile

    from acquisition.session import SessionWriter, SpecimenInfo, StepRecord, write_result

    runs = [("--help", ["--help"]),
            ("identify --json (default: bootstrap uncertainty)", ["identify", "{s}", "--json", "--ends", "clamped"]),
            ("identify --json --uncertainty gauss-newton",
             ["identify", "{s}", "--json", "--ends", "clamped", "--uncertainty", "gauss-newton"])]
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "s.h5"
        pos, p, f = sim.positions, sim.pressure, sim.axial_force
        with SessionWriter.create(path, SpecimenInfo("A1", radius=10e-3, length=35e-3, thickness=sim.thickness),
                                  load_cell_measures="wall") as w:
            for i in range(len(p)):
                w.add_step(StepRecord(0, 1.1, float(p[i]), float(p[i]), float(f[i]), float(i), 1.7e9 + i))
        write_result(path, "markers", {"positions": pos, "visible": np.ones(pos.shape[:2], bool),
                                       "marker_id": np.arange(pos.shape[1]), "step_index": np.arange(len(p))},
                     {"method": "synthetic"})
        env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=str(Path(__file__).resolve().parents[1]))
        for label, args in runs:
            times = []
            for _ in range(repeats):
                before = resource.getrusage(resource.RUSAGE_CHILDREN)
                subprocess.run([sys.executable, "-m", "vfmlab"] + [a.format(s=path) for a in args],
                               env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                after = resource.getrusage(resource.RUSAGE_CHILDREN)
                times.append(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
            out.append((label, float(np.median(times))))
    return out


def bench_starts(n_seeds):
    """How many starts the least-squares fit needs: is the first start's minimum the best one?"""
    from identification.models import get_model
    from identification.fit import _default_starts

    print(f"\n## Starts needed (lsq; {'clamped' if CLAMPED else 'homogeneous'} membrane tube; exact data and "
          f"{n_seeds} noise seeds at 0.01 mm)\n")
    print("| model | data sets | first start's cost is the best (within 1e-6) | largest relative excess of the first start |")
    print("|---|---|---|---|")
    for model in ("fung", "delfino", "hgo"):
        sim = simulate(model)
        starts = _default_starts(get_model(model), None, 4)
        best_first, excess = 0, 0.0
        for seed in range(n_seeds + 1):
            noise = 0.0 if seed == 0 else 0.01e-3
            pos = sim.exact_positions + np.random.default_rng([seed, 11]).normal(0.0, noise, sim.exact_positions.shape)
            data = prepare(pos, sim.pressure, sim.axial_force, thickness=sim.thickness,
                           ends="clamped" if CLAMPED else "free")
            costs = [identify_prepared(data, model, initial=s, n_starts=1).cost for s in starts]
            best_first += costs[0] <= min(costs) * (1 + 1e-6)
            excess = max(excess, costs[0] / min(costs) - 1.0)
        print(f"| {model} | {n_seeds + 1} | {best_first}/{n_seeds + 1} | {excess:.1e} |")
        sys.stdout.flush()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="fewer repeats (3 instead of 7) and noise seeds of the "
                    "starts part (3 instead of 10)")
    ap.add_argument("--part", choices=["timing", "starts", "all"], default="all")
    ap.add_argument("--no-nelder-mead", action="store_true",
                    help="timing part: leave out the Nelder-Mead fits (20,000 evaluations each)")
    ap.add_argument("--in-process", action="store_true",
                    help="timing part: leave out the whole-command runs and the finite-element thick fit")
    _common.add_data_argument(ap)
    args = ap.parse_args(argv)
    global CLAMPED, SYNTH
    CLAMPED = args.data != "homogeneous"
    SYNTH = args.data == "clamped-synth"
    logging.basicConfig(level=logging.ERROR)
    warnings.simplefilter("ignore", RuntimeWarning)
    repeats = 3 if args.quick else 7
    print(f"# bench_ident_timing ({'quick' if args.quick else 'full'}, {args.data} data), numpy {np.__version__}")
    if args.part in ("timing", "all"):
        bench_timing(repeats, nelder_mead=not args.no_nelder_mead, skip_slow=args.in_process)
    if args.part in ("starts", "all"):
        bench_starts(3 if args.quick else 10)


if __name__ == "__main__":
    main()
