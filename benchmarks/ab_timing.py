"""Before/after of the identification timing figures in one interleaved run: two trees, alternately.

    OMP_NUM_THREADS=1 python -m benchmarks.ab_timing <old tree> [--rounds 3] [--cold 40]

Each round runs, in a subprocess per tree (old first, then this one), from the tree's root:
``python -m benchmarks.bench_ident_timing --part timing --quick --no-nelder-mead --in-process`` (each tree's
own file, ``bench_identification`` in a tree from before the split: the same measurement as long as their timing
parts agree), and ``--cold`` cold ``prepare`` calls of the Fung bench data
(mesh and surface-state caches cleared, CPU time). Prints every figure per round and its median over the
rounds per tree, with the load average before and after: on a shared machine absolute times are upper
bounds, the ratios of one run are what count. Then, finest-grained, ``--calls`` cold ``prepare`` calls of
both trees alternated call by call in one process (the old tree's ``identification`` package, which imports
nothing but numpy and scipy, is loaded under another name): the ratio the load disturbs least.
"""
import argparse
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
#: (label, regular expression on the benchmark's output; the first group is the figure)
FIGURES = [
    ("Fung fit, prepare + optimise (ms)", r"\| Fung fit, prepare \+ optimise[^|]*\| ([\d.]+) ms"),
    ("... of which prepare, cold (ms)", r"\| \.\.\. of which prepare[^|]*\| ([\d.]+) ms"),
    ("... of which optimise (ms)", r"\| \.\.\. of which optimise[^|]*\| ([\d.]+) ms"),
    ("plain least_squares VFM / ours", r"\| plain least_squares VFM / ours[^|]*\| ([\d.]+)x"),
    ("plain VFM alone (ms)", r"Fung: ([\d.]+) ms, \d+ evaluations"),
    ("HGO fit with its multi-start, prepare + optimise (ms)", r"\| HGO fit with its multi-start[^|]*\| ([\d.]+) ms"),
    ("prepare again on the same markers (ms)", r"\| prepare again on the same markers[^|]*\| ([\d.]+) ms"),
    ("thick form, HGO, prepare + optimise (ms)", r"\| thick form, HGO, clamped data[^|]*\| ([\d.]+) ms"),
]

#: run with the tree as working directory (``python -c`` puts it first on the path, before PYTHONPATH)
COLD = """
import logging, sys, time
logging.disable(logging.CRITICAL)
import numpy as np
try:
    from benchmarks._common import cold_prepare, simulate
except ImportError:  # a tree from before benchmarks/_common.py (issue 29)
    from benchmarks.bench_identification import _cold_prepare as cold_prepare, simulate
sim = simulate("fung")
for _ in range(3):
    cold_prepare(sim)
times = []
for _ in range({n}):
    t = time.process_time()
    cold_prepare(sim)
    times.append(time.process_time() - t)
import identification
print("FROM", identification.__file__)
print("COLD", np.median(times) * 1e3, np.min(times) * 1e3)
"""


def run(tree: Path, cold: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree), OMP_NUM_THREADS="1")
    script = ("benchmarks.bench_ident_timing" if (tree / "benchmarks" / "bench_ident_timing.py").exists()
              else "benchmarks.bench_identification")  # a tree from before the split of bench_identification
    out = subprocess.run([sys.executable, "-m", script, "--part", "timing", "--quick",
                          "--no-nelder-mead", "--in-process"], env=env, cwd=tree, capture_output=True, text=True,
                         check=True).stdout
    figures = {label: float(m.group(1)) for label, rx in FIGURES if (m := re.search(rx, out))}
    # cwd: ``python -c`` puts the working directory first on the path, before PYTHONPATH
    cold_out = subprocess.run([sys.executable, "-c", COLD.format(n=cold)], env=env, cwd=tree,
                              capture_output=True, text=True, check=True).stdout
    source = Path(cold_out.split("FROM")[1].split()[0]).resolve()
    if tree.resolve() not in source.parents:
        raise RuntimeError(f"the run meant for {tree} imported {source}")
    med, low = map(float, cold_out.split("COLD")[1].split())
    figures[f"cold prepare, median of {cold} (ms)"] = med
    figures[f"cold prepare, min of {cold} (ms)"] = low
    return figures


#: run from this tree's root; the old tree's ``identification`` package is loaded from its folder as
#: ``identification_old`` (a module spec on the folder, not a path entry)
INTERLEAVED = """
import importlib, importlib.util, logging, sys, time
from pathlib import Path
logging.disable(logging.CRITICAL)
import numpy as np
from benchmarks._common import simulate
import identification.vfm as new
folder = Path({old!r}) / "identification"
spec = importlib.util.spec_from_file_location("identification_old", folder / "__init__.py",
                                              submodule_search_locations=[str(folder)])
sys.modules["identification_old"] = importlib.util.module_from_spec(spec)
spec.loader.exec_module(sys.modules["identification_old"])
old = importlib.import_module("identification_old.vfm")
sim = simulate("fung")

def cold(vfm):
    vfm._MESH_CACHE.clear()
    vfm._STATE_CACHE.clear()
    vfm.prepare(sim.positions, sim.pressure, sim.axial_force, thickness=sim.thickness, ends="clamped")

times = {{"old": [], "new": []}}
for k in range({n} + 3):
    for name, vfm in (("old", old), ("new", new)):
        t = time.process_time()
        cold(vfm)
        if k >= 3:
            times[name].append(time.process_time() - t)
o, n = np.median(times["old"]) * 1e3, np.median(times["new"]) * 1e3
print(f"INTERLEAVED {{o}} {{n}}")
"""


def interleaved(old: Path, calls: int) -> tuple[float, float]:
    """Median CPU times (ms) of the old and new tree's cold ``prepare``, alternated call by call in one process."""
    env = dict(os.environ, PYTHONPATH=str(HERE.parent), OMP_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", INTERLEAVED.format(old=str(old), n=calls)], env=env,
                         cwd=HERE.parent, capture_output=True, text=True, check=True).stdout
    o, n = map(float, out.split("INTERLEAVED")[1].split())
    return o, n


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("old", type=Path, help="the tree to compare against (e.g. an export of main)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--cold", type=int, default=40, help="cold prepare calls per subprocess")
    ap.add_argument("--calls", type=int, default=100, help="cold prepare calls per tree, alternated in one process")
    args = ap.parse_args(argv)
    new = HERE.parent
    load0 = os.getloadavg()
    results = {"old": [], "new": []}
    for k in range(args.rounds):
        for name, tree in (("old", args.old.resolve()), ("new", new)):
            results[name].append(run(tree, args.cold))
            print(f"round {k + 1} {name}: " + "; ".join(f"{lb} {v:g}" for lb, v in results[name][-1].items()),
                  flush=True)
    o, n = interleaved(args.old.resolve(), args.calls)
    print(f"cold prepare alternated call by call ({args.calls} each): old {o:.2f} ms, new {n:.2f} ms, "
          f"new / old {n / o:.2f}")
    load1 = os.getloadavg()
    print(f"\nload average (1 min) {load0[0]:.1f} before, {load1[0]:.1f} after, on {os.cpu_count()} cores\n")
    print("| figure | old (runs) | new (runs) | new / old |")
    print("|---|---|---|---|")
    for label in (results["new"][0] if results["new"] else []):
        o = [r[label] for r in results["old"] if label in r]
        n = [r[label] for r in results["new"] if label in r]
        if not o or not n:
            continue
        fmt = lambda v: ", ".join(f"{x:g}" for x in v)  # noqa: E731
        print(f"| {label} | {np.median(o):.3g} ({fmt(o)}) | {np.median(n):.3g} ({fmt(n)}) | "
              f"{np.median(n) / np.median(o):.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
