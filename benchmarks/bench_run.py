"""Benchmark of an unattended simulated session (instruments over ptys, rendered cameras).

    python -m benchmarks.bench_run [--speed 5] [--size 320x240] [--calibration 0] [--live fung]

Prints the wall time of the whole session, the time per step, the log rate and the capture
spread (time between the first and the last camera's frame of a step). With ``--live MODELS``
the session is run twice in one invocation, without and with results while the test runs
(vfmlab.live_results, true cameras of the simulated ring), and the step cadence of both is
printed: the capture loop must not wait for the background reconstruction/identification.
Use ``--size 816x680`` (or larger) with ``--live``: markers must be a few pixels wide.
"""

from __future__ import annotations

import argparse
import io
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from rich.console import Console

from acquisition.session import open_session
from vfmlab.operate import run_session

ROOT = Path(__file__).resolve().parents[1]

PROTOCOL = """
[preconditioning]
pressure_cycles = 8
pressure_max_mmHg = 80
stretch_cycles = 8
stretch_max = 1.4
cycle_s = 0.2
[stability]
band_mmHg = 1.0
dwell_s = 0.1
timeout_s = 20
[test]
stretches = [1.1, 1.2]
pressures_mmHg = [0, 20, 40, 60, 80, 100, 125, 150]
[calibration]
views = {views}
"""


def _session(tmp: Path, args, w: int, h: int, live: tuple[str, ...]) -> dict:
    """One simulated session; its figures."""
    (tmp / "p.toml").write_text(PROTOCOL.format(views=args.calibration))
    rig = (ROOT / "examples" / "sim-rig.toml").read_text().replace("width = 640, height = 480",
                                                                    f"width = {w}, height = {h}")
    (tmp / "rig.toml").write_text(rig)
    out = tmp / f"s{len(live)}.h5"
    options = None
    if live:
        from rig_sim import camera_ring

        options = {"cameras": camera_ring(4, image_size=(w, h), seed=0)}
    t0 = time.monotonic()
    outcome = run_session(str(tmp / "p.toml"), str(ROOT / "examples" / "specimen.toml"), str(out),
                          rig_path=str(tmp / "rig.toml"), sim=True, yes=True, sim_speed=args.speed,
                          console=Console(file=io.StringIO()), live_models=live, live_options=options)
    wall = time.monotonic() - t0
    with open_session(out) as s:
        st = s.steps
        lg = s.log("pressure")
        fig = {"status": outcome.status, "n": s.n_steps, "size_mb": out.stat().st_size / 1e6, "wall": wall,
               "dt": np.diff(st["t_monotonic"]), "p_err": np.abs(st["pressure"] - st["target_pressure"]).max(),
               "rate": (lg["t_monotonic"].size - 1) / (lg["t_monotonic"][-1] - lg["t_monotonic"][0]),
               "live": {}}
        for name in s.results("identification"):
            r = s.result(name)
            fig["live"][r["attrs"]["model"]] = dict(zip(r["arrays"]["parameter_names"], r["arrays"]["parameters"]))
    return fig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--speed", type=float, default=5.0, help="simulated plant speed-up")
    ap.add_argument("--size", default="320x240", help="camera resolution WxH")
    ap.add_argument("--calibration", type=int, default=0, help="calibration-board views")
    ap.add_argument("--live", default="", help="models identified while the test runs, e.g. fung (runs twice)")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    live = tuple(m for m in args.live.split(",") if m)
    with tempfile.TemporaryDirectory() as tmp:
        runs = [("without live results", ())] + ([(f"with live results ({', '.join(live)})", live)] if live else [])
        figs = [(label, _session(Path(tmp), args, w, h, models)) for label, models in runs]
    for label, f in figs:
        dt = f["dt"]
        print(f"\n{label}: status {f['status']}; {f['n']} steps, 4 cameras {w}x{h}, sim speed x{args.speed:g}, "
              f"{args.calibration} calibration views")
        print(f"session wall time          {f['wall']:6.1f} s")
        print(f"time per step (median)     {np.median(dt):6.2f} s   (max {dt.max():.2f} s)")
        print(f"pressure log rate          {f['rate']:6.1f} Hz")
        print(f"|p - target| max           {f['p_err']:6.1f} Pa")
        print(f"file size                  {f['size_mb']:6.1f} MB")
        for model, params in f["live"].items():
            print(f"live {model}: " + ", ".join(f"{k} {v:.4g}" for k, v in params.items()) + " (SI)")
    if live:
        ratio = np.median(figs[1][1]["dt"]) / np.median(figs[0][1]["dt"])
        print(f"\nstep cadence with / without live results (median time per step): {ratio:.2f}; "
              f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
