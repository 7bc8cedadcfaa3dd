"""Benchmarks of the VFM identification on exact data: the bias of each form (prints markdown tables;
docs/validation/identification.md quotes them).

    OMP_NUM_THREADS=1 python -m benchmarks.bench_ident_exact [--part flat|clamped|thick|all] [--data ...]

flat   : bias of flat chord triangles (the paper taken literally) vs cylindrical interpolation.
clamped: exact clamped-tube data with and without the unmeasured-strip term (--data clamped-synth: the tests'
         independent clamped-tube solver).
thick  : bias of the membrane form vs the thick-wall forms on rig_sim's exact thick-walled tube.

Timing: ``benchmarks.bench_ident_timing``; noise and coverage: ``benchmarks.bench_ident_noise``.
"""

from __future__ import annotations

import argparse
import logging
import sys
import warnings

import numpy as np

from benchmarks import _common
from benchmarks._common import params_of, rel_errors
from identification import identify_prepared, prepare
from rig_sim.mechanics import simulate_test

SYNTH = False  # use the independent clamped-tube solver (rig_sim/clamped_reference.py) instead of rig_sim's mechanics


def simulate(model, *, clamped, wall="membrane"):
    """:func:`benchmarks._common.simulate` with this run's ``--data`` (SYNTH)."""
    return _common.simulate(model, clamped=clamped, wall=wall, synth=SYNTH)


def fmt_err(errs):
    return ", ".join(f"{k} {v:+.2%}" for k, v in errs.items())


def flat_chord_data(data, positions):
    """The paper taken literally: flat chord triangles, Cartesian linear interpolation (for comparison only)."""
    from dataclasses import replace

    from identification.kinematics import align_steps
    from identification.virtual_fields import paper_fields

    mesh = data.mesh
    tri = mesh.triangles
    ref_local = np.column_stack([mesh.r * np.cos(mesh.theta), mesh.r * np.sin(mesh.theta), mesh.z])
    aligned, _, _ = align_steps(positions, ref_local @ mesh.axis.basis + mesh.axis.origin)
    x = (aligned - mesh.axis.origin) @ mesh.axis.basis.T  # specimen frame
    X = ref_local
    fields = paper_fields(mesh)
    er = np.column_stack([np.cos(mesh.theta), np.sin(mesh.theta), np.zeros_like(mesh.theta)])
    ez = np.array([0.0, 0.0, 1.0])
    u = np.stack([fields.values[k, :, 0:1] * er + fields.values[k, :, 2:3] * ez for k in range(2)])  # (2, n, 3)
    E0 = X[tri[:, 1]] - X[tri[:, 0]], X[tri[:, 2]] - X[tri[:, 0]]
    n0 = np.cross(E0[0], E0[1])
    area0 = 0.5 * np.linalg.norm(n0, axis=1)
    n0 /= np.linalg.norm(n0, axis=1, keepdims=True)
    c = X[tri].mean(1)
    et = np.column_stack([-c[:, 1], c[:, 0], np.zeros(len(c))])
    e1 = et - (et * n0).sum(1, keepdims=True) * n0
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(n0, e1)
    D0 = np.stack([np.stack([(E * e1).sum(1), (E * e2).sum(1)], 1) for E in E0], 2)  # (t, 2, 2)
    D0inv = np.linalg.inv(D0)
    D = np.stack([x[:, tri[:, 1]] - x[:, tri[:, 0]], x[:, tri[:, 2]] - x[:, tri[:, 0]]], -1)  # (s, t, 3, 2)
    F = D @ D0inv
    C = np.swapaxes(F, -1, -2) @ F
    du = np.stack([u[:, tri[:, 1]] - u[:, tri[:, 0]], u[:, tri[:, 2]] - u[:, tri[:, 0]]], -1) @ D0inv  # (f, t, 3, 2)
    G = np.swapaxes(F, -1, -2)[None] @ du[:, None]
    dE = 0.5 * (G + np.swapaxes(G, -1, -2))
    dV0 = area0 * data.thickness
    dens = np.stack([dE[..., 0, 0], dE[..., 1, 1], 2 * dE[..., 0, 1]], -1) * dV0[None, None, :, None]
    nda = 0.5 * np.cross(D[..., 0], D[..., 1])  # (s, t, 3)
    uc = u[:, tri].mean(2)  # (f, t, 3)
    pw = data.pressure[None] * np.einsum("stc,ftc->fs", nda, uc)
    evw = pw + data.end_work
    return replace(data, c=np.stack([C[..., 0, 0], C[..., 1, 1], C[..., 0, 1]], -1), work_density=dens, evw=evw,
                   pressure_work=pw, scale=np.sqrt(np.mean(evw**2, axis=1)))


def bench_flat():
    print("\n## Flat chord triangles (paper taken literally) vs cylindrical interpolation, exact homogeneous data\n")
    print("| model | markers | flat: max gap at true parameters | flat: identified | cylindrical: identified |")
    print("|---|---|---|---|---|")
    from identification import internal_virtual_work

    for model in ("fung", "delfino", "hgo"):
        for n in (100, 300, 1000):
            sim = simulate_test(model, params_of(model), clamped=False, n_markers=n)
            data = prepare(sim.positions, sim.pressure, sim.axial_force, thickness=sim.thickness, ends="free")
            flat = flat_chord_data(data, sim.positions)
            gap = (internal_virtual_work(flat, model, params_of(model)) - flat.evw) / flat.scale[:, None]
            res_flat = identify_prepared(flat, model)
            res_cyl = identify_prepared(data, model)
            print(f"| {model} | {n} | {np.abs(gap).max():.2%} | {fmt_err(rel_errors(res_flat, params_of(model)))} | "
                  f"{fmt_err(rel_errors(res_cyl, params_of(model)))} |")
            sys.stdout.flush()


def bench_clamped():
    print("\n## Exact clamped-tube data: with and without the unmeasured-strip term\n")
    print("| model | ends=\"clamped\" (strip term) | ends=\"free\" (strip ignored) |")
    print("|---|---|---|")
    for model in ("fung", "delfino", "hgo", "neohookean"):
        sim = simulate(model, clamped=True)
        row = []
        for ends in ("clamped", "free"):
            data = prepare(sim.positions, sim.pressure, sim.axial_force, thickness=sim.thickness, ends=ends)
            row.append(fmt_err(rel_errors(identify_prepared(data, model), params_of(model))))
        print(f"| {model} | " + " | ".join(row) + " |")
        sys.stdout.flush()


def bench_thick():
    print("\n## Thick wall (e0/R = 0.13): exact homogeneous thick-walled tube, markers on the outer surface\n")
    print("Relative parameter errors of each form (lsq, paper/generic start).\n")
    print("| model | membrane form | mid-wall (1 layer, pressure on lumen) | thick, 4 layers |")
    print("|---|---|---|---|")
    for model in ("fung", "delfino", "hgo", "neohookean"):
        sim = simulate(model, clamped=False, wall="thick")
        row = []
        for wall, layers in (("membrane", 1), ("thick", 1), ("thick", 4)):
            data = prepare(sim.positions, sim.pressure, sim.axial_force, thickness=sim.thickness, wall=wall,
                           ends="free", n_layers=layers)
            res = identify_prepared(data, model)
            row.append(fmt_err(rel_errors(res, params_of(model))))
        print(f"| {model} | " + " | ".join(row) + " |")
        sys.stdout.flush()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--part", choices=["flat", "clamped", "thick", "all"], default="all")
    _common.add_data_argument(ap)
    args = ap.parse_args(argv)
    global SYNTH
    SYNTH = args.data == "clamped-synth"
    logging.basicConfig(level=logging.ERROR)
    warnings.simplefilter("ignore", RuntimeWarning)
    print(f"# bench_ident_exact ({args.data} data), numpy {np.__version__}")
    if args.part in ("flat", "all"):
        bench_flat()
    if args.part in ("clamped", "all"):
        bench_clamped()
    if args.part in ("thick", "all"):
        bench_thick()


if __name__ == "__main__":
    main()
