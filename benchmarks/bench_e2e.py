"""Benchmark of the e2e layer: report build, ParaView export, reprocessing serial / process pool / Dask.

Run: ``OMP_NUM_THREADS=1 python -m benchmarks.bench_e2e`` (from the repository root).
Sessions are synthetic (rig_sim/synthetic_session.py): 300 markers, 2 stretches x 3 pressures + reference.
"""

from __future__ import annotations

import logging
import tempfile
import time
from pathlib import Path

from rig_sim.synthetic_session import make_session
from vfmlab.cli import main
from vfmlab.report import build_report
from vfmlab.reprocess import plan_runs, reprocess


def timed(label, fn, *args, **kwargs):
    t0, c0 = time.perf_counter(), time.process_time()
    out = fn(*args, **kwargs)
    print(f"{label:<48s} wall {time.perf_counter() - t0:6.2f} s   cpu (this process) {time.process_time() - c0:6.2f} s")
    return out


def run() -> None:
    logging.disable(logging.WARNING)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        paths = [make_session(tmp / f"s{i}.h5", n_markers=300, seed=i, specimen_id=f"tube-{i}") for i in range(4)]
        html = timed("report (300 markers, 7 steps, 2 models)", build_report, paths[0], tmp / "report")
        n_fig = len(list(html.parent.glob("fig*.png")))
        size = sum(f.stat().st_size for f in html.parent.glob("fig*.png"))
        print(f"  {n_fig} figures, {size / 1e6:.2f} MB PNG, report.html {html.stat().st_size / 1e6:.2f} MB")
        timed("export vtk (7 steps)", main, ["export", str(paths[0]), "-o", str(tmp / "vtk")])
        timed("export ply (7 steps)", main, ["export", str(paths[0]), "-o", str(tmp / "ply"), "--format", "ply"])
        runs = plan_runs(["identify"], models=["fung", "delfino"])
        timed("reprocess 4 sessions x 2 models, serial", reprocess, paths, runs)
        timed("reprocess 4 sessions x 2 models, --workers 2", reprocess, paths, runs, workers=2)
        from dask.distributed import LocalCluster

        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                          silence_logs=40) as cluster:
            timed("reprocess 4 sessions x 2 models, Dask 2 workers", reprocess, paths, runs,
                  scheduler=cluster.scheduler_address)


if __name__ == "__main__":
    run()
