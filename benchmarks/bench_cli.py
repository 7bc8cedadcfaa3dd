"""Start-up and whole-command wall time of the ``vfmlab`` command line (issue 11: ``vfmlab identify`` <= 0.5 s).

    python -m benchmarks.bench_cli [--session S.h5] [--work DIR] [--repeats 5]
                                                [--compare-root OTHER_CHECKOUT] [--compare-python PYTHON]
                                                [--commands-only]

Prints, as markdown, the median wall time (s) over ``--repeats`` fresh processes of ``vfmlab --help``,
``vfmlab info S``, ``vfmlab identify S --uncertainty gauss-newton``, ``vfmlab identify S --weighting paper
--uncertainty bootstrap`` (the defaults before issue 24) and ``vfmlab identify S`` (defaults: the efficient
weighting with its generalised least-squares intervals), the CPU of one bootstrap re-identification (in one process, serial: the
replicates of ``identification.uncertainty.bootstrap`` with the command's settings, min over repeats of the
mean of 16), then the import-time breakdown of ``identify`` (``python -X importtime``, self
time summed by top-level package) and the modules it must not import (drivers, pyserial, matplotlib...).

``S`` is a rendered session with marker tracks. Without ``--session`` one is made once in ``--work``
(``vfmlab run examples/paper-protocol.toml --sim --sim-seed 0``, ``calibrate``, ``reconstruct``: about a
minute) and reused by later runs. Every timed ``identify`` runs on its own copy of ``S`` (it appends a
result); the copies are made first and left alone for a few seconds, as a session on disk is.

``--compare-root`` times a second source tree (e.g. ``git worktree add /tmp/before main``) in the same run,
interleaved command by command (ratios are what count on a loaded machine), and prints the largest
relative difference between the two trees' stored identification results (parameters, standard
errors, intervals, virtual works, residuals). ``--compare-python`` runs the compared tree (this one if no
``--compare-root``) on another interpreter, e.g. a scratch venv with another scipy release.
``--commands-only`` stops after the command timings.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path
from typing import NamedTuple

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: modules ``vfmlab identify`` has no use for (instrument drivers, serial ports, plotting, images, meshes)
MUST_NOT_IMPORT = ("acquisition.mark10", "acquisition.mensor", "acquisition.sampler", "acquisition.serial_link",
                   "serial", "matplotlib", "trimesh", "cv2", "rig_sim", "reconstruction", "vfmlab.report")
#: seconds a copied session is left alone before it is timed (acquisition.session.QUIET_BEFORE_WALK)
SETTLE = 2.6
COMMANDS = {
    "--help": ["--help"],
    "info S": ["info", "{s}"],
    "identify S --uncertainty gauss-newton": ["identify", "{s}", "--uncertainty", "gauss-newton"],
    "identify S --weighting paper --uncertainty bootstrap": ["identify", "{s}", "--weighting", "paper",
                                                             "--uncertainty", "bootstrap"],
    "identify S (defaults)": ["identify", "{s}"],
}


def _env(root: Path) -> dict:
    return dict(os.environ, PYTHONPATH=str(root), OMP_NUM_THREADS=os.environ.get("OMP_NUM_THREADS", "1"))


def _vfmlab(root: Path, args: list[str], **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "vfmlab", *args], env=_env(root), cwd=root, **kwargs)


#: ``python -m vfmlab ARGS`` that also reports the CPU time of its own process (not of its children) on exit
_REPORTING = ("import atexit, os, runpy, sys, time\n"
              "atexit.register(lambda: os.write(2, f'\\nmain-process-cpu {time.process_time()}\\n'.encode()))\n"
              "sys.argv = ['vfmlab'] + sys.argv[1:]\n"
              "runpy.run_module('vfmlab', run_name='__main__')\n")


class Tree(NamedTuple):
    """A timed configuration: a source tree of vfmlab and the interpreter (environment) that runs it."""

    root: Path
    python: str


def _timed(tree: Tree, args: list[str]) -> tuple[float, float, float]:
    """(wall, CPU of the command and its children, CPU of the command's own process) in s."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    run = subprocess.run([tree.python, "-c", _REPORTING, *args], env=_env(tree.root), cwd=tree.root, check=True,
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    own = [float(line.split()[1]) for line in run.stderr.splitlines() if line.startswith("main-process-cpu ")]
    return wall, after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, own[-1]


def make_session(work: Path) -> Path:
    """A rendered session with marker tracks in ``work`` (made once: run, calibrate, reconstruct)."""
    session = work / "rendered-seed0.h5"
    if session.exists():
        return session
    partial = work / "rendered-seed0.partial.h5"
    partial.unlink(missing_ok=True)
    print(f"making a rendered session in {work} (about a minute)...", file=sys.stderr)
    for args in (["run", "examples/paper-protocol.toml", "--specimen", "examples/specimen.toml", "--out", str(partial),
                  "--sim", "--sim-seed", "0", "--yes", "--json"], ["calibrate", str(partial)],
                 ["reconstruct", str(partial)]):
        _vfmlab(ROOT, args, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    partial.rename(session)
    results = partial.with_name(partial.name + ".results")  # the derived results beside the file (issue 28)
    if results.exists():
        results.rename(session.with_name(session.name + ".results"))
    return session


def _copies(session: Path, tmp: Path, trees: list[Tree], repeats: int) -> dict:
    """(tree index, command, repeat) -> its own copy of the session, for the commands that write."""
    out = {}
    for r in range(len(trees)):
        for label, args in COMMANDS.items():
            if args[0] != "identify":
                continue
            for k in range(repeats):
                out[r, label, k] = tmp / f"r{r}-{len(out)}.h5"
                shutil.copyfile(session, out[r, label, k])
                beside = session.with_name(session.name + ".results")  # results beside the file (issue 28)
                if beside.exists():
                    shutil.copytree(beside, out[r, label, k].with_name(out[r, label, k].name + ".results"))
    time.sleep(SETTLE)
    return out


def time_commands(session: Path, trees: list[Tree], repeats: int, tmp: Path) -> tuple[dict, dict]:
    """Median (wall, CPU, main-process CPU) times ``{(tree index, command): (s, s, s)}`` and the copies
    identified by each tree. CPU = user + system of the command and its children (the damaged-file
    walk, bootstrap workers); main-process CPU = the command's own process alone, what its wall time
    is on an idle machine when the children run on the other core (a load-independent figure), up to
    its ``atexit`` handlers: the interpreter's teardown after them shows in the other two only."""
    copies = _copies(session, tmp, trees, repeats)
    times = defaultdict(list)
    for k in range(repeats):
        for label, args in COMMANDS.items():
            for r, tree in enumerate(trees):  # interleaved: the same load for every tree
                target = copies.get((r, label, k), session)
                times[r, label].append(_timed(tree, [a.format(s=target) for a in args]))
    return {key: tuple(np.median(np.array(v), axis=0)) for key, v in times.items()}, copies


#: In-process CPU of the bootstrap the ``identify`` command runs, its replicates serial (``map``).
_REPLICATE_CPU = """
import sys, time
import numpy as np
from vfmlab.pipeline import FORCE_NOISE, PRESSURE_NOISE, read_identification_inputs, resolve_ends
from identification.optimize import identify
from identification.uncertainty import bootstrap
d = read_identification_inputs(sys.argv[1])
ends = resolve_ends(d["session_ends"], None)[0] or "clamped"
result = identify(d["positions"], d["pressure"], d["force"], thickness=d["thickness"], ends=ends, smoothing="auto",
                  uncertainty="gauss-newton")
positions = d["positions"] if result.steps is None else d["positions"][list(result.steps)]
sigma = None if d["uncertainty"] is None or result.steps is None else d["uncertainty"][list(result.steps)]
times = []
for _ in range(int(sys.argv[2]) + 1):  # the first run warms the caches of the process
    t0 = time.process_time()
    bootstrap(result.data, result, positions, marker_sigma=sigma, pressure_noise=PRESSURE_NOISE,
              force_noise=FORCE_NOISE, n_replicates=16)
    times.append((time.process_time() - t0) / 16)
print(min(times[1:]))
"""


def replicate_cpu(tree: Tree, session: Path, repeats: int) -> float:
    """CPU (s) of one bootstrap replicate of ``identify``'s defaults on ``session``, serial, in ``root``'s code
    (including its share of the re-simulation: the bootstrap's CPU over its 16 replicates)."""
    run = subprocess.run([tree.python, "-c", _REPLICATE_CPU, str(session), str(repeats)], env=_env(tree.root),
                         cwd=tree.root, check=True, capture_output=True, text=True)
    return float(run.stdout.split()[-1])


def import_breakdown(tree: Tree, session: Path, tmp: Path) -> tuple[dict, list[str], float]:
    """Self import time (s) of ``identify --uncertainty gauss-newton`` by top-level package, the
    modules of ``MUST_NOT_IMPORT`` it imported, and the total."""
    target = tmp / f"imports-{abs(hash(tree))}.h5"
    shutil.copyfile(session, target)
    beside = session.with_name(session.name + ".results")
    if beside.exists():
        shutil.copytree(beside, target.with_name(target.name + ".results"))
    args = [tree.python, "-X", "importtime", "-m", "vfmlab", "identify", str(target), "--uncertainty",
            "gauss-newton"]
    err = subprocess.run(args, env=_env(tree.root), cwd=tree.root, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                         text=True, check=True).stderr
    by_package, loaded = defaultdict(float), set()
    for line in err.splitlines():
        if not line.startswith("import time:") or "|" not in line or "self" in line:
            continue
        self_us, name = _fields(line)
        loaded.add(name)
        by_package[name.split(".")[0]] += self_us * 1e-6
    bad = sorted(m for m in loaded if any(m == b or m.startswith(b + ".") for b in MUST_NOT_IMPORT))
    return dict(by_package), bad, float(sum(by_package.values()))


def _fields(line: str) -> tuple[float, str]:
    """(self time µs, module) of one ``-X importtime`` line."""
    parts = line.replace("import time:", "").split("|")
    return float(parts[0]), parts[2].strip()


def max_relative_difference(a: Path, b: Path) -> float:
    """Largest relative difference between the newest identification results of two session copies."""
    from acquisition.session import open_session

    arrays = []
    for path in (a, b):
        with open_session(path) as s:
            arrays.append(s.latest("identification")["arrays"])
    worst = 0.0
    for key in ("parameters", "stderr", "interval_low", "interval_high", "bootstrap_bias", "ivw", "evw",
                "residuals", "correlation"):
        if key in arrays[0] or key in arrays[1]:
            x, y = np.asarray(arrays[0][key], float), np.asarray(arrays[1][key], float)
            scale = np.maximum(np.abs(x), np.abs(y))
            rel = np.where(scale > 0, np.abs(x - y) / np.where(scale > 0, scale, 1.0), 0.0)
            worst = max(worst, float(np.nanmax(rel)) if rel.size else 0.0)
    return worst


def in_process(session: Path, repeats: int) -> str:
    """Median wall time of ``identification.identify`` on the session's inputs, in this process, with the defaults
    and with the defaults before issue 24 (``weighting="paper", uncertainty="bootstrap"``), alternated."""
    from identification import identify
    from vfmlab.pipeline import read_identification_inputs

    d = read_identification_inputs(session)
    args = (d["positions"], d["pressure"], d["force"])
    variants = {"defaults": {}, 'weighting="paper", uncertainty="bootstrap"': dict(weighting="paper",
                                                                                   uncertainty="bootstrap")}
    times: dict = defaultdict(list)
    for k in range(repeats + 1):  # the first round warms the caches of the process
        for label, kw in variants.items():
            t0 = time.perf_counter()
            identify(*args, thickness=d["thickness"], **kw)
            if k:
                times[label].append(time.perf_counter() - t0)
    return ("\nIn-process `identification.identify(positions, pressure, force, thickness=...)` (median of "
            f"{repeats}, load average {os.getloadavg()[0]:.1f}): "
            + ", ".join(f"{label} {np.median(v):.3f} s" for label, v in times.items()))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--session", type=Path, help="a rendered session with marker tracks (copied, never changed)")
    parser.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "vfmlab-bench-cli",
                        help="folder where the rendered session is made once (without --session)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--synthetic", type=int, metavar="N_MARKERS",
                        help="time a rig_sim.synthetic_session session of N markers (made in --work) instead")
    parser.add_argument("--compare-root", type=Path, help="another source tree of vfmlab, timed alongside")
    parser.add_argument("--compare-python", help="the interpreter of the compared tree (default: this one); with no "
                                                 "--compare-root, this tree on that interpreter (e.g. a venv with "
                                                 "another scipy release)")
    parser.add_argument("--commands-only", action="store_true",
                        help="only the command timings and the stored-result comparison")
    args = parser.parse_args(argv)
    if args.synthetic:
        from rig_sim.synthetic_session import make_session as make_synthetic

        args.work.mkdir(parents=True, exist_ok=True)
        session = args.work / f"synthetic-{args.synthetic}.h5"
        if not session.exists():
            make_synthetic(session, n_markers=args.synthetic)
    elif args.session is None:
        args.work.mkdir(parents=True, exist_ok=True)
        session = make_session(args.work)
    else:
        session = args.session
    trees = [Tree(ROOT, sys.executable)]
    names = ["this tree"]
    if args.compare_root or args.compare_python:
        trees.append(Tree(args.compare_root.resolve() if args.compare_root else ROOT,
                          args.compare_python or sys.executable))
        names.append(" on ".join(str(v) for v in (args.compare_root, args.compare_python) if v))
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        medians, copies = time_commands(session, trees, args.repeats, tmp)
        print(f"Median of {args.repeats} fresh processes, session {session.name}, load average "
              f"{os.getloadavg()[0]:.1f}: wall / CPU of the command and its children / CPU of its main process (s)\n")
        print("| command | " + " | ".join(names) + " |")
        print("|---|" + "---|" * len(trees))
        for label in COMMANDS:
            print(f"| `vfmlab {label}` | " + " | ".join(" / ".join(f"{t:.3f}" for t in medians[r, label])
                                                     for r in range(len(trees))) + " |")
        if len(trees) == 2:
            label = "identify S --weighting paper --uncertainty bootstrap"  # the same command in both trees
            diff = max_relative_difference(copies[0, label, 0], copies[1, label, 0])
            print(f"\nLargest relative difference of the stored identification results between the trees ({label}): "
                  f"{diff:.1e}")
        print(in_process(session, args.repeats))
        if args.commands_only:
            return
        per = [replicate_cpu(tree, session, args.repeats) for tree in trees]
        print("\nCPU of one bootstrap re-identification (in-process, serial, min over repeats of the mean of 16): "
              + ", ".join(f"{names[r]} {per[r] * 1e3:.1f} ms" for r in range(len(trees))))
        for r, tree in enumerate(trees):
            by_package, bad, total = import_breakdown(tree, session, tmp)
            print(f"\nImports of `vfmlab identify` ({names[r]}): {total:.3f} s of self time (-X importtime)\n")
            print("| package | s |\n|---|---|")
            for name, t in sorted(by_package.items(), key=lambda kv: -kv[1])[:10]:
                print(f"| {name} | {t:.3f} |")
            print(f"\nmodules it should not import: {', '.join(bad) if bad else 'none'}")


if __name__ == "__main__":
    main()
