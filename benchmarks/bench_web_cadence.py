"""Step cadence of ``vfmlab run --sim`` with and without the browser view open.

    python -m benchmarks.bench_web_cadence [--repeats 3] [--speed 5] [--size 640x480]

Runs a short simulated protocol (1 block x 8 pressures, no preconditioning, no calibration views)
``2 x repeats`` times, alternating (ABBA order): without the page and with ``--web`` (the server process of
``vfmlab.web``, fed by the run as ``vfmlab run --web`` does) and a poller in another process that
plays an open page, hitting every endpoint every 0.5 s (the JSON state, each camera's last image
with its detections, the strain map). Prints the median time between captured steps of each run
and the ratio with / without; the brief's bound is 1.05.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

PROTOCOL = """
[preconditioning]
pressure_cycles = 0
pressure_max_mmHg = 80
stretch_cycles = 0
stretch_max = 1.1
cycle_s = 0.2
[stability]
band_mmHg = 1.0
dwell_s = 0.1
timeout_s = 20
[test]
stretches = [1.1]
pressures_mmHg = [0, 20, 40, 60, 80, 100, 125, 150]
[calibration]
views = 0
"""


def _fetch_forever(url: str, period: float, log=None) -> None:
    """GET ``url`` every ``period`` s (or as soon as the last answer came, if slower), while the benchmark lives."""
    parent = os.getppid()
    while os.getppid() == parent:
        t0 = time.monotonic()
        try:
            with urllib.request.urlopen(url, timeout=60) as r:
                body = r.read()
            if log is not None:
                log.write(f"{json.loads(body).get('n_steps', 0)} {time.monotonic() - t0:.4f}\n")
        except OSError:
            pass  # 404 before the first step
        time.sleep(max(0.0, period - (time.monotonic() - t0)))


def poll(url: str, n_cameras: int, log_path: Path, period: float = 0.5) -> None:
    """Play an open page until killed: every endpoint every ``period`` s, each from its own thread (as a
    browser loads them side by side); each state's step count and answer time go to ``log_path``."""
    import threading

    paths = ["api/strain.png"] + [f"api/camera/{i}.png" for i in range(n_cameras)]
    for path in paths:
        threading.Thread(target=_fetch_forever, args=(url + path, period), daemon=True).start()
    with open(log_path, "a", buffering=1) as log:
        _fetch_forever(url + "api/state", period, log)


def one_run(tmp: Path, k: int, args, web: bool) -> tuple[np.ndarray, str]:
    """One simulated session: the times between its captured steps (s), and what the page saw."""
    from rich.console import Console

    from acquisition.session import open_session
    from vfmlab.operate import run_session
    from vfmlab.web.feed import web_view

    w, h = (int(v) for v in args.size.split("x"))
    (tmp / "p.toml").write_text(PROTOCOL)
    rig = (ROOT / "examples" / "sim-rig.toml").read_text().replace("width = 640, height = 480",
                                                                    f"width = {w}, height = {h}")
    (tmp / "rig.toml").write_text(rig)
    out = tmp / f"s{k}{'w' if web else ''}.h5"
    poller = None
    cpu0 = time.process_time()
    kwargs = dict(rig_path=str(tmp / "rig.toml"), sim=True, yes=True, sim_speed=args.speed,
                  console=Console(file=io.StringIO()), live_models=())
    if web:
        with web_view(out, 0, say=lambda text: None) as hooks:
            url = hooks["observer"].__self__.url
            log_path = tmp / f"poll{k}.txt"
            poller = subprocess.Popen([sys.executable, "-m", "benchmarks.bench_web_cadence", "--poll", url,
                                       "--poll-log", str(log_path)],
                                      cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)))
            try:
                run_session(str(tmp / "p.toml"), str(ROOT / "examples" / "specimen.toml"), str(out), **kwargs,
                            **hooks)
                server_cpu = _cpu_seconds(hooks["observer"].__self__.proc.pid)
            finally:
                poller.kill()
                poller.wait()
    else:
        run_session(str(tmp / "p.toml"), str(ROOT / "examples" / "specimen.toml"), str(out), **kwargs)
    run_cpu = f"; run CPU {time.process_time() - cpu0:.1f} s"
    with open_session(out) as s:
        dt = np.diff(s.steps["t_monotonic"])
    if not web:
        return dt, run_cpu
    seen = np.loadtxt(log_path, ndmin=2) if log_path.stat().st_size else np.zeros((0, 2))
    return dt, run_cpu + (f"; the page polled {len(seen)} times, saw {len(np.unique(seen[:, 0]))} distinct step counts, "
                f"state answered in {np.median(seen[:, 1]) if len(seen) else float('nan'):.3f} s (median); "
                f"server CPU {server_cpu:.1f} s at idle priority")


def _cpu_seconds(pid: int) -> float:
    """CPU time (user + system, with its reaped children) of process ``pid`` so far, s (Linux)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return sum(int(v) for v in fields[11:15]) / os.sysconf("SC_CLK_TCK")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="runs of each kind (alternated)")
    ap.add_argument("--speed", type=float, default=5.0, help="simulated plant speed-up")
    ap.add_argument("--size", default="640x480", help="camera resolution WxH (the --sim rig's default)")
    ap.add_argument("--poll", metavar="URL", help=argparse.SUPPRESS)  # the poller process
    ap.add_argument("--poll-log", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.poll:
        poll(args.poll, 4, args.poll_log)
        return
    medians: dict[bool, list[float]] = {False: [], True: []}
    ratios = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.repeats):
            for web in ((False, True) if k % 2 == 0 else (True, False)):  # ABBA: no order advantage
                dt, seen = one_run(Path(tmp), k, args, web)
                medians[web].append(float(np.median(dt)))
                print(f"run {k + 1} {'with the page   ' if web else 'without the page'}: {len(dt) + 1} steps, "
                      f"median {np.median(dt):.3f} s per step (max {dt.max():.3f} s){seen}", flush=True)
            ratios.append(medians[True][-1] / medians[False][-1])
    off, on = np.median(medians[False]), np.median(medians[True])
    print(f"\nratio with / without, per adjacent pair: {', '.join(f'{r:.3f}' for r in ratios)}; "
          f"median {np.median(ratios):.3f}")
    print(f"step cadence, median over {args.repeats} runs of the median time per step: without the page "
          f"{off:.3f} s, with the page open {on:.3f} s; ratio {on / off:.3f} (bound 1.05); "
          f"4 cameras {args.size}, sim speed x{args.speed:g}; load average {os.getloadavg()[0]:.1f} on "
          f"{os.cpu_count()} cores")


if __name__ == "__main__":
    main()
