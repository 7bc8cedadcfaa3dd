"""Benchmark of an unattended simulated session (instruments over ptys, rendered cameras).

    python benchmarks/bench_run.py [--speed 5] [--size 320x240] [--calibration 0]

Prints the wall time of the whole session, the time per step, the log rate and the capture
spread (time between the first and the last camera's frame of a step).
"""

from __future__ import annotations

import argparse
import io
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--speed", type=float, default=5.0, help="simulated plant speed-up")
    ap.add_argument("--size", default="320x240", help="camera resolution WxH")
    ap.add_argument("--calibration", type=int, default=0, help="calibration-board views")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        (tmp / "p.toml").write_text(PROTOCOL.format(views=args.calibration))
        rig = (ROOT / "examples" / "sim-rig.toml").read_text().replace("width = 640, height = 480",
                                                                        f"width = {w}, height = {h}")
        (tmp / "rig.toml").write_text(rig)
        out = tmp / "s.h5"
        t0 = time.monotonic()
        outcome = run_session(str(tmp / "p.toml"), str(ROOT / "examples" / "specimen.toml"), str(out),
                              rig_path=str(tmp / "rig.toml"), sim=True, yes=True, sim_speed=args.speed,
                              console=Console(file=io.StringIO()))
        wall = time.monotonic() - t0
        with open_session(out) as s:
            st = s.steps
            lg = s.log("pressure")
            n = s.n_steps
            size_mb = out.stat().st_size / 1e6
        dt = np.diff(st["t_monotonic"])
        rate = (lg["t_monotonic"].size - 1) / (lg["t_monotonic"][-1] - lg["t_monotonic"][0])
    print(f"status {outcome.status}; {n} steps, 4 cameras {w}x{h}, sim speed x{args.speed:g}, "
          f"{args.calibration} calibration views")
    print(f"session wall time          {wall:6.1f} s")
    print(f"time per step (median)     {np.median(dt):6.2f} s   (max {dt.max():.2f} s)")
    print(f"pressure log rate          {rate:6.1f} Hz")
    print(f"|p - target| max           {np.abs(st['pressure'] - st['target_pressure']).max():6.1f} Pa")
    print(f"file size                  {size_mb:6.1f} MB")


if __name__ == "__main__":
    main()
