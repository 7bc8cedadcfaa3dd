"""Benchmark of the instrument sampler against the simulated instruments over pseudo-terminals.

Measures, per channel, the achieved sample rate and the timestamp jitter (spread of the intervals between
consecutive samples around the nominal period), and checks the record is gapless (sequence numbers).

    python -m benchmarks.bench_instruments                # 30 s at 50 Hz per instrument (100 Hz combined)
    python -m benchmarks.bench_instruments --seconds 5 --rate 200 --transport socket
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from acquisition import Sampler, open_load_cell, open_pressure
from rig_sim.instruments import SimulatedRig


def run(seconds: float, rate: float, transport: str) -> dict:
    with SimulatedRig(transport=transport, rng=np.random.default_rng(0)) as rig, \
            open_pressure(rig.pressure_port) as p, open_load_cell(rig.load_cell_port) as f:
        rig.set_stretch(1.1)
        p.set_mode("control")
        p.set_setpoint(13332.2)
        s = Sampler(p, f, rate_hz=rate)
        records = {"pressure": [], "force": []}
        t0 = time.monotonic()
        with s:
            while time.monotonic() - t0 < seconds:
                time.sleep(0.25)  # drain like a session runner would
                for ch in records:
                    records[ch].append(s.drain(ch))
        elapsed = time.monotonic() - t0
        for ch in records:
            records[ch].append(s.drain(ch))
        out = {"seconds": elapsed, "rate": rate, "transport": transport, "events": len(s.drain_events())}
        for ch, recs in records.items():
            seq = np.concatenate([r.seq for r in recs])
            t = np.concatenate([r.t_monotonic for r in recs])
            tw = np.concatenate([r.t_wall for r in recs])
            dt = np.diff(t)
            out[ch] = {
                "n": int(seq.size),
                "gapless": bool(np.array_equal(seq, np.arange(seq.size))),
                "lost": int(sum(r.lost for r in recs)),
                "rate_hz": (seq.size - 1) / (t[-1] - t[0]) if seq.size > 1 else 0.0,
                "dt_mean_ms": 1e3 * float(dt.mean()),
                "jitter_std_ms": 1e3 * float(dt.std()),
                "dt_p99_ms": 1e3 * float(np.percentile(dt, 99)),
                "dt_max_ms": 1e3 * float(dt.max()),
                "wall_minus_mono_spread_ms": 1e3 * float(np.ptp(tw - t)),
            }
        return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0, help="duration of the run (default 30 s)")
    ap.add_argument("--rate", type=float, default=50.0, help="readings/s of each instrument (default 50)")
    ap.add_argument("--transport", choices=("pty", "socket"), default="pty")
    args = ap.parse_args(argv)
    res = run(args.seconds, args.rate, args.transport)
    print(f"sampler benchmark: {res['seconds']:.1f} s, nominal {res['rate']:.0f} Hz per instrument "
          f"({2 * res['rate']:.0f} Hz combined), transport {res['transport']}, fault events {res['events']}")
    print(f"{'channel':9s} {'n':>7s} {'rate Hz':>8s} {'dt mean ms':>10s} {'jitter sd ms':>12s} "
          f"{'dt p99 ms':>9s} {'dt max ms':>9s} {'gapless':>7s} {'lost':>4s}")
    combined = 0.0
    for ch in ("pressure", "force"):
        r = res[ch]
        combined += r["rate_hz"]
        print(f"{ch:9s} {r['n']:7d} {r['rate_hz']:8.2f} {r['dt_mean_ms']:10.3f} {r['jitter_std_ms']:12.3f} "
              f"{r['dt_p99_ms']:9.3f} {r['dt_max_ms']:9.3f} {str(r['gapless']):>7s} {r['lost']:4d}")
    print(f"combined rate: {combined:.2f} Hz")
    return 0


if __name__ == "__main__":
    sys.exit(main())
