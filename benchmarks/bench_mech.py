"""Figures of the simulator's exact mechanics: thick-wall vs membrane bias, clamped-BVP cost and accuracy.

Run: ``python -m benchmarks.bench_mech`` (about a minute on one core). Prints Markdown tables used in
docs/validation/mechanics.md.
"""

from __future__ import annotations

import time

import numpy as np

from rig_sim.mechanics import (
    MMHG,
    PAPER_PARAMETERS,
    MechanicsError,
    PAPER_PRESSURES,
    inflate_membrane,
    inflate_thick,
    membrane_pressure,
    membrane_wall_force,
    midwall_membrane_state,
    simulate_test,
    solve_clamped,
)

R, H, L = 10e-3, 1.3e-3, 35e-3


def thick_vs_membrane() -> None:
    print("\n## Thick wall (truth) vs membrane forms, same outer-surface kinematics, 150 mmHg and 75 mmHg\n")
    print("| model | lam_z | p (mmHg) | lam_outer | p_membrane/p | N_membrane/N | p_midwall/p | N_midwall/N | "
          "N_membrane(p)/N(p) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for model, par in PAPER_PARAMETERS.items():
        for lz in (1.1, 1.2):
            p = np.array([75.0, 150.0]) * MMHG
            th = inflate_thick(model, par, p, lz, radius=R, thickness=H)
            pm = membrane_pressure(model, par, th.lam_outer, lz, radius=R, thickness=H)
            nm = membrane_wall_force(model, par, th.lam_outer, lz, radius=R, thickness=H)
            mw = midwall_membrane_state(model, par, th.lam_outer, lz, radius=R, thickness=H)
            me = inflate_membrane(model, par, p, lz, radius=R, thickness=H)
            for k in range(2):
                print(f"| {model} | {lz} | {p[k] / MMHG:.0f} | {th.lam_outer[k]:.4f} | {pm[k] / p[k]:.3f} | "
                      f"{nm[k] / th.wall_force[k]:.3f} | {mw.pressure[k] / p[k]:.3f} | "
                      f"{mw.wall_force[k] / th.wall_force[k]:.3f} | {me.wall_force[k] / th.wall_force[k]:.3f} |")


def clamped_cost() -> None:
    print("\n## Clamped-end BVP: 8 pressures 0..150 mmHg, tol 1e-8, one core\n")
    print("| model | stretch | time (s) | final mesh nodes | N at cannula, 150 mmHg (N) | N homogeneous (N) | "
          "min dz/dZ | max r change vs tol=1e-9 (m) |")
    print("|---|---|---|---|---|---|---|---|")
    Z = np.linspace(-L / 2, L / 2, 201)
    for model, par in PAPER_PARAMETERS.items():
        for lam in (1.1, 1.2):
            t = time.perf_counter()
            sols = solve_clamped(model, par, PAPER_PRESSURES, lam, radius=R, thickness=H, length=L)
            dt = time.perf_counter() - t
            try:
                fine = solve_clamped(model, par, PAPER_PRESSURES, lam, radius=R, thickness=H, length=L, tol=1e-9)
                err = f"{max(np.max(np.abs(a.evaluate(Z)[0] - b.evaluate(Z)[0])) for a, b in zip(sols, fine)):.1e}"
            except MechanicsError as exc:
                err = f"n/a ({exc})"
            hom = inflate_membrane(model, par, PAPER_PRESSURES[-1], lam, radius=R, thickness=H)
            print(f"| {model} | {lam} | {dt:.2f} | {sols[-1].Z.size} | {sols[-1].end_wall_force:.3f} | "
                  f"{hom.wall_force[0]:.3f} | {min(s.min_dzdZ for s in sols):.3f} | {err} |")


def simulate_cost() -> None:
    print("\n## simulate_test, 300 markers, stretches (1.1, 1.2), 17 steps\n")
    print("| model | clamped | time (s) |")
    print("|---|---|---|")
    for model, par in PAPER_PARAMETERS.items():
        for clamped in (False, True):
            t = time.perf_counter()
            simulate_test(model, par, stretches=(1.1, 1.2), clamped=clamped)
            print(f"| {model} | {clamped} | {time.perf_counter() - t:.2f} |")


if __name__ == "__main__":
    thick_vs_membrane()
    clamped_cost()
    simulate_cost()
