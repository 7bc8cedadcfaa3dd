"""Dense clouds (issue 25): time and memory of ``identification.identify`` against the number of points per step.

    OMP_NUM_THREADS=1 python -m benchmarks.bench_dense [--points 300 1000 3000 10000 30000 50000] [--noise 0.17]
    OMP_NUM_THREADS=1 python -m benchmarks.bench_dense --compare 10000   # quadrature path against the full mesh
    OMP_NUM_THREADS=1 python -m benchmarks.bench_dense --defaults [--mode defaults|stated|unjudged] [--points 10000 50000] [--compare 10000]
    OMP_NUM_THREADS=1 python -m benchmarks.bench_dense --commands --points 10000 50000   # import-dic + identify

Data: the closed-form homogeneous Fung tube (``rig_sim.homogeneous_tube``, paper parameters), 24 loaded steps
(axial stretches 1.05, 1.1, 1.15 x 8 pressures 0-150 mmHg) after the stress-free reference, N points per step
placed at random on the tube, i.i.d. Gaussian noise ``--noise`` mm on every coordinate of every step.

Settings: those of ``vfmlab identify`` (``vfmlab.stages.settings.IdentifySettings`` when this was written: model
fung, membrane wall, lsq, smoothing "auto", uncertainty "bootstrap", weighting "paper"), ends "free" (the data are a
free homogeneous tube; the CLI takes the session's), the bootstrap's replicates in this process (the CLI forks them
on both cores: ``map_replicates``). Each N runs in a fresh subprocess (cold mesh and surface-state caches):

- total : wall time of the default ``identify`` (bootstrap uncertainty), and its CPU time;
- the phases of the same identification without the bootstrap (``uncertainty="gauss-newton"``), from cProfile's
  cumulative times: mesh (``build_mesh``), axes (``refit_axes``: every step's axis), outliers
  (``marker_outliers``), smoothing (choice and fit), the rest of the kinematics, virtual work (the rest of
  ``prepare``), fit (``identify_prepared``); "bootstrap" is total minus that run's wall time (profiler off);
- memory: peak resident set of the subprocess (``ru_maxrss``) and its growth during ``identify``.

The slope is the least-squares slope of log(time) against log(N) over the N >= 3000 rows (1: linear cost).
Above ``identification.dense.DENSE_POINTS`` mesh markers the balance is evaluated on the quadrature grid
(column "quadrature nodes"; 0 = the full marker mesh).

``--defaults``: ``identification.identify(positions, pressure, force, thickness=e0, model="fung")`` with nothing
else stated (``identification.DEFAULTS``: efficient weighting, its "gls" intervals, wall and ends judged by the
data, the verdict's other laws and gap noise): "total" and "cpu" that call, its phases from a profiled second
call, no bootstrap columns; ``--compare`` then compares that call.

``--commands``: what a user waits for: ``vfmlab import-dic`` of the cloud written as an NPZ table and ``vfmlab
identify`` of the session, each a fresh process (wall and CPU time, peak resident set), beside the in-process
identification's CPU time (``--defaults``) of the same data.

``--compare N``: the same data identified on the quadrature path and on the full marker mesh (the threshold
raised for the second run, in the same process): estimates, bootstrap standard errors, interval widths, CPU.
"""

from __future__ import annotations

import argparse
import cProfile
import json
import logging
import pstats
import resource
import subprocess
import sys
import time

import numpy as np

POINTS = (300, 1000, 3000, 10000, 30000, 50000)
STRETCHES = (1.05, 1.1, 1.15)
N_PRESSURES = 8
MMHG = 133.322

#: cProfile functions whose cumulative time makes a phase (file suffix, function name)
PHASES = {
    "mesh": [("mesh.py", "build_mesh")],
    "axes": [("step_axes.py", "refit_axes"), ("kinematics.py", "align_steps")],
    "outliers": [("outliers.py", "marker_outliers")],
    "smoothing": [("smoothing.py", "resolve_smoothing"), ("smoothing.py", "smooth_cylindrical"),
                  ("smoothing.py", "smooth_reference_radius"), ("dense.py", "_coefficients"),
                  ("dense.py", "_reference_radius")],
    # minus axes, outliers, smoothing
    "kinematics": [("kinematics.py", "surface_state"), ("dense.py", "dense_state"), ("dense.py", "marker_survey")],
    # minus mesh and kinematics: the virtual work (a dense cloud's moved sets skip ``prepare``: ``Reprepare.prepared``,
    # the other wall form's balance of them: ``GapCovariance.for_wall``)
    "prepare": [("vfm.py", "prepare"), ("gap_jacobian.py", "prepared"), ("efficient.py", "for_wall")],
    "fit": [("fit.py", "identify_prepared")],
}


def tube(n_points: int, noise_mm: float, seed: int = 0):
    """Positions (25, n_points, 3) m, pressure (25,) Pa, axial force (25,) N, thickness m of the Fung tube."""
    from rig_sim.homogeneous_tube import E0, PAPER, homogeneous, lam_t_for_pressures

    params = PAPER["fung"]
    pressures = np.linspace(0.0, 150.0, N_PRESSURES + 1)[1:] * MMHG
    lam_t, lam_z = [1.0], [1.0]
    for s in STRETCHES:
        lam_t += list(lam_t_for_pressures("fung", params, np.maximum(pressures, 1.0), s))
        lam_z += [s] * N_PRESSURES
    pos, p, f = homogeneous("fung", params, np.array(lam_t), np.array(lam_z), n=n_points, seed=seed)
    pos = pos + np.random.default_rng(seed + 1).normal(0.0, noise_mm * 1e-3, pos.shape)
    return pos, p, f, E0


def _cumulative(stats: pstats.Stats, suffix: str, name: str) -> float:
    return sum(v[3] for (fn, _, fname), v in stats.stats.items() if fname == name and fn.endswith(suffix))  # type: ignore[attr-defined]


def _phases(stats: pstats.Stats) -> dict:
    t = {k: sum(_cumulative(stats, *f) for f in fs) for k, fs in PHASES.items()}
    t["kinematics"] -= t["axes"] - _cumulative(stats, "kinematics.py", "align_steps") + t["outliers"] + t["smoothing"]
    t["prepare"] -= t["mesh"] + t["kinematics"] + t["axes"] + t["outliers"] + t["smoothing"]
    t["virtual work"] = t.pop("prepare")
    return t


def _clear_caches():
    import identification.dense as dense
    import identification.vfm as vfm

    vfm._MESH_CACHE.clear()
    vfm._STATE_CACHE.clear()
    for name in ("_REFERENCE_CACHE", "_FIT_CACHE", "_STATE_CACHE"):
        getattr(dense, name, {}).clear()


def measure(n_points: int, noise_mm: float) -> dict:
    """One row: run in a fresh process (``--one N``)."""
    from identification import identify

    pos, p, f, e0 = tube(n_points, noise_mm)
    options = {"marker_sigma": np.full(pos.shape[:2], noise_mm * 1e-3), "pressure_noise": 3.0, "force_noise": 0.002}
    kw = dict(thickness=e0, model="fung", wall="membrane", ends="free", optimizer="lsq", smoothing="auto",
              weighting="paper")
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    _clear_caches()
    t, c = time.perf_counter(), time.process_time()
    full = identify(pos, p, f, uncertainty="bootstrap", uncertainty_options=options, **kw)
    total, cpu = time.perf_counter() - t, time.process_time() - c
    rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    _clear_caches()
    t = time.perf_counter()
    gn = identify(pos, p, f, uncertainty="gauss-newton", **kw)
    main = time.perf_counter() - t
    _clear_caches()
    prof = cProfile.Profile()
    prof.enable()
    identify(pos, p, f, uncertainty="gauss-newton", **kw)
    prof.disable()
    phases = _phases(pstats.Stats(prof))
    return {"n": n_points, "steps": int(pos.shape[0] - 1), "total": total, "cpu": cpu, "main": main,
            "bootstrap": total - main, "phases": phases, "rss_mb": rss1 / 1024, "rss_growth_mb": (rss1 - rss0) / 1024,
            "triangles": int(gn.data.mesh.n_triangles), "beta": float(full.parameters["beta"]),
            "nodes": 0 if gn.data.quadrature is None else int(gn.data.quadrature.grid.n_markers),
            "beta_ci": [float(v) for v in np.asarray(full.uncertainty.interval["beta"])]
            if getattr(full, "uncertainty", None) is not None else None}


#: ``--mode``: what ``identification.identify`` is told besides the data, thickness and model.
MODES = {"defaults": {}, "stated": {"wall": "membrane", "ends": "free"},
         "unjudged": {"wall": "membrane", "ends": "free", "judged": False}}


def measure_defaults(n_points: int, noise_mm: float, mode: str = "defaults") -> dict:
    """One row of ``--defaults`` (``--one N --defaults``): ``identification.identify`` with its defaults (and
    ``MODES[mode]``: the wall and ends stated, or the fit alone without the verdict)."""
    from identification import identify

    pos, p, f, e0 = tube(n_points, noise_mm)
    kw = dict(thickness=e0, model="fung", **MODES[mode])
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    _clear_caches()
    t, c = time.perf_counter(), time.process_time()
    res = identify(pos, p, f, **kw)
    total, cpu = time.perf_counter() - t, time.process_time() - c
    rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    _clear_caches()
    prof = cProfile.Profile()
    prof.enable()
    identify(pos, p, f, **kw)
    prof.disable()
    return {"n": n_points, "steps": int(pos.shape[0] - 1), "total": total, "cpu": cpu, "main": total,
            "bootstrap": 0.0, "phases": _phases(pstats.Stats(prof)), "rss_mb": rss1 / 1024,
            "rss_growth_mb": (rss1 - rss0) / 1024, "triangles": int(res.data.mesh.n_triangles),
            "beta": float(res.parameters["beta"]), "defaults": True,
            "nodes": 0 if res.data.quadrature is None else int(res.data.quadrature.grid.n_markers),
            "setting": f"{mode}: {res.data.wall} wall, {res.data.ends} ends, {res.verdict or 'not judged'}"}


def slope(rows: list[dict], key) -> float:
    sel = [r for r in rows if r["n"] >= 3000]
    if len(sel) < 2:
        return float("nan")
    n = np.log([r["n"] for r in sel])
    y = np.log([max(key(r), 1e-6) for r in sel])
    return float(np.polyfit(n, y, 1)[0])


def table(rows: list[dict]) -> str:
    names = list(rows[0]["phases"])
    head = ["N", "triangles", "quadrature nodes", "total s", "cpu s", "w/o bootstrap s", "bootstrap s"] + [f"{k} s" for k in names] + [
        "peak RSS MB", "RSS growth MB", "beta (Pa)"]
    if rows[0].get("defaults"):  # no bootstrap: the two columns say the same as "total"
        head[5:7] = ["-", "-"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [f"{r['n']:,}", f"{r['triangles']:,}", f"{r.get('nodes', 0):,}", f"{r['total']:.2f}", f"{r['cpu']:.2f}", f"{r['main']:.2f}",
                 f"{r['bootstrap']:.2f}"] + [f"{r['phases'][k]:.3f}" for k in names] + [
            f"{r['rss_mb']:.0f}", f"{r['rss_growth_mb']:.0f}", f"{r['beta']:.0f}"]
        lines.append("| " + " | ".join(cells) + " |")
    slopes = ["slope (N >= 3000)", "", "", f"{slope(rows, lambda r: r['total']):.2f}",
              f"{slope(rows, lambda r: r['cpu']):.2f}", f"{slope(rows, lambda r: r['main']):.2f}",
              f"{slope(rows, lambda r: r['bootstrap']):.2f}"] + [
        f"{slope(rows, lambda r, k=k: r['phases'][k]):.2f}" for k in names] + [
        f"{slope(rows, lambda r: r['rss_mb']):.2f}", f"{slope(rows, lambda r: max(r['rss_growth_mb'], 1)):.2f}", ""]
    lines.append("| " + " | ".join(slopes) + " |")
    return "\n".join(lines)


def compare(n_points: int, noise_mm: float, defaults: bool = False) -> str:
    """The quadrature path against the full marker mesh on the same data, in this process (a markdown table)."""
    import identification.dense as dense
    from identification import identify

    pos, p, f, e0 = tube(n_points, noise_mm)
    options = {"marker_sigma": np.full(pos.shape[:2], noise_mm * 1e-3), "pressure_noise": 3.0, "force_noise": 0.002}
    kw = dict(thickness=e0, model="fung", wall="membrane", ends="free", optimizer="lsq", smoothing="auto",
              weighting="paper", uncertainty="bootstrap", uncertainty_options=options)
    if defaults:
        kw = dict(thickness=e0, model="fung")
    rows, threshold = {}, dense.DENSE_POINTS
    for path, limit in (("quadrature", threshold), ("full mesh", 10**12)):
        dense.DENSE_POINTS = limit
        _clear_caches()
        c = time.process_time()
        rows[path] = (identify(pos, p, f, **kw), time.process_time() - c)
    dense.DENSE_POINTS = threshold
    (q, cq), (m, cm) = rows["quadrature"], rows["full mesh"]
    lines = [f"N = {n_points:,} points x {pos.shape[0] - 1} loaded steps, noise {noise_mm} mm; CPU s: quadrature "
             f"{cq:.2f}, full mesh {cm:.2f}; "
             f"{q.data.quadrature.describe() if q.data.quadrature is not None else 'full mesh both'}"
             + ("".join(f"; {name}: {r.data.wall} wall, {r.data.ends} ends, {r.verdict}, intervals "
                        f"{r.uncertainty.method}" for name, r in (("quadrature", q), ("full mesh", m)))
                if defaults else ""), "",
             "| parameter | full mesh | quadrature | difference / SE | SE full | SE quadrature | 95 % width full | "
             "95 % width quadrature |", "|---|---|---|---|---|---|---|---|"]
    for k in m.parameters:
        wm = np.diff(m.uncertainty.interval[k])[0]
        wq = np.diff(q.uncertainty.interval[k])[0]
        lines.append(f"| {k} | {m.parameters[k]:.5g} | {q.parameters[k]:.5g} | "
                     f"{(q.parameters[k] - m.parameters[k]) / m.stderr[k]:+.3f} | {m.stderr[k]:.3g} | "
                     f"{q.stderr[k]:.3g} | {wm:.3g} | {wq:.3g} |")
    return "\n".join(lines)


def commands(points, noise_mm: float, workdir: str | None = None) -> str:
    """What a user waits for, from a DIC table to the judged result: ``vfmlab import-dic`` of the cloud (an NPZ
    table, mm) and ``vfmlab identify`` of the session (the command's defaults), each a fresh process; wall time,
    CPU time of the child and the peak resident set of the largest child so far (a markdown table)."""
    import tempfile
    from pathlib import Path

    lines = ["| N x 24 steps | import-dic wall s | import-dic CPU s | identify wall s | identify CPU s | "
             "peak RSS MB | identification in-process CPU s (of identify) |", "|---|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        for n in points:
            pos, p, f, e0 = tube(n, noise_mm)
            s, m = pos.shape[:2]
            table_path, loads_path, session = Path(tmp, f"p{n}.npz"), Path(tmp, f"l{n}.csv"), Path(tmp, f"s{n}.h5")
            np.savez(table_path, point=np.tile(np.arange(m), s), frame=np.repeat(np.arange(s), m),
                     X=pos[..., 0].ravel() * 1e3, Y=pos[..., 1].ravel() * 1e3, Z=pos[..., 2].ravel() * 1e3)
            loads_path.write_text("step,pressure_Pa,axial_force_N,stretch\n"
                                  + "".join(f"{k},{p[k]:.9g},{f[k]:.9g},1\n" for k in range(s)))
            cells = []
            for argv in (["import-dic", str(table_path), "--format", "table", "--columns",
                          "id=point,step=frame,x=X,y=Y,z=Z", "--loads", str(loads_path), "--thickness-mm",
                          f"{e0 * 1e3:g}", "-o", str(session)], ["identify", str(session)]):
                c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
                t = time.perf_counter()
                subprocess.run([sys.executable, "-m", "vfmlab", *argv], check=True, capture_output=True)
                c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
                cells += [time.perf_counter() - t, (c1.ru_utime + c1.ru_stime) - (c0.ru_utime + c0.ru_stime)]
            out = subprocess.run([sys.executable, "-m", "benchmarks.bench_dense", "--one", str(n), "--noise",
                                  str(noise_mm), "--defaults"], capture_output=True, text=True, check=True)
            inner = json.loads(out.stdout.strip().splitlines()[-1])["cpu"]
            rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
            lines.append(f"| {n:,} | " + " | ".join(f"{v:.2f}" for v in cells) + f" | {rss:.0f} | {inner:.2f} |")
            sys.stderr.write(lines[-1] + "\n")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--points", type=int, nargs="+", default=list(POINTS))
    ap.add_argument("--noise", type=float, default=0.17, help="marker noise (mm, each coordinate)")
    ap.add_argument("--one", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--json", help="also write the rows to this file")
    ap.add_argument("--compare", type=int, metavar="N", help="quadrature path against the full mesh at N points")
    ap.add_argument("--defaults", action="store_true", help="identification.identify with its defaults (module doc)")
    ap.add_argument("--commands", action="store_true", help="import-dic and identify as a user runs them")
    ap.add_argument("--mode", choices=list(MODES), default="defaults",
                    help="with --defaults: wall and ends judged (defaults), stated, or the fit alone (unjudged)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    if args.commands:
        sys.stdout.write(commands(args.points, args.noise) + "\n")
        return 0
    if args.compare:
        sys.stdout.write(compare(args.compare, args.noise, args.defaults) + "\n")
        return 0
    if args.one:
        row = measure_defaults(args.one, args.noise, args.mode) if args.defaults else measure(args.one, args.noise)
        sys.stdout.write(json.dumps(row) + "\n")
        return 0
    rows = []
    for n in args.points:
        out = subprocess.run([sys.executable, "-m", "benchmarks.bench_dense", "--one", str(n), "--noise",
                              str(args.noise)] + (["--defaults", "--mode", args.mode] if args.defaults else []),
                             capture_output=True,
                             text=True, check=True)
        rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
        sys.stderr.write(f"N={n}: {rows[-1]['total']:.2f} s\n")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    said = ("identification.identify defaults (" + "; ".join(f"{r['n']:,}: {r['setting']}" for r in rows) + ")"
            if args.defaults else "smoothing auto, bootstrap")
    sys.stdout.write(f"{rows[0]['steps']} loaded steps, noise {args.noise} mm, fung, {said}\n\n")
    sys.stdout.write(table(rows) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
