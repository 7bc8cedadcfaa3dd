"""Are two trees' identification results the same? Save the prepared data and fits of one tree, compare another's.

    cp benchmarks/ident_equality.py <old tree>/benchmarks/   (it imports the tree it is run from)
    cd <old tree> && python -m benchmarks.ident_equality save /tmp/before.pkl [--sessions 'dir/paper-seed*.h5']
    cd <new tree> && python -m benchmarks.ident_equality compare /tmp/before.pkl [--sessions ...] [--v]

Data: rig_sim's clamped Fung and HGO tubes (membrane, thick), the same with 0.03 mm noise, a 2 mm
mis-tracked marker, a near-duplicate and a missing marker (with and without smoothing="auto"), free
ends, and up to six rendered sessions (e.g. those of bench_coverage_rendered) with and without
smoothing. Compared: mesh (triangles up to order, boundary loops, drop counts, axis), valid and
outlier counts, noise estimate, EVW, scales, end and strip forces, IVW at the paper parameters and
the fitted parameters (Fung and neo-Hookean, or HGO); prints every relative difference above 1e-6
(above 1e-8 with --v) and the largest one.
"""
import argparse
import glob
import logging
import pickle
import warnings

import numpy as np

try:
    from benchmarks import _common as B
except ImportError:  # a tree from before benchmarks/_common.py (issue 29): the same functions lay in the script
    from benchmarks import bench_identification as B
from identification import identify_prepared, prepare
from identification.vfm import internal_virtual_work
import identification.vfm as vfm
logging.disable(logging.CRITICAL)

def canon(tri):
    tri = np.asarray(tri)
    k = np.argmin(tri, axis=1)
    rolled = np.stack([np.roll(t, -i) for t, i in zip(tri, k)]) if len(tri) else tri
    order = np.lexsort(rolled.T[::-1])
    return rolled[order], order

def summary(d, fits):
    tri, order = canon(d.mesh.triangles)
    out = dict(tri=tri, evw=d.evw, scale=d.scale, pw=d.pressure_work, ef=d.end_force, nv=d.n_valid_triangles,
               no=d.n_outliers, noise=d.marker_noise, sm=repr(d.smoothing), dropped=repr(sorted(d.mesh.dropped.items())),
               used=d.mesh.used, zb=d.mesh.z_bottom, zt=d.mesh.z_top, sf=d.strip_force,
               top=np.sort(np.sort(d.mesh.top_edges, 1), 0), bot=np.sort(np.sort(d.mesh.bottom_edges, 1), 0),
               axis_origin=d.mesh.axis.origin, axis_basis=d.mesh.axis.basis, axis_radius=d.mesh.axis.radius,
               axis_rms=d.mesh.axis.rms)
    for name, res, ivw in fits:
        out["fit_" + name] = np.array([res.parameters[k] for k in sorted(res.parameters)])
        out["ivw_" + name] = ivw
    return out

def cases():
    for model in ("fung", "hgo"):
        sim = B.simulate(model)
        for wall in ("membrane", "thick"):
            yield f"{model}-{wall}", sim.positions, sim.pressure, sim.axial_force, sim.thickness, dict(wall=wall), model
        rng = np.random.default_rng(3)
        noisy = sim.positions + rng.normal(0, 0.03e-3, sim.positions.shape)
        noisy[3, 17] += 2e-3  # an outlier
        noisy[:, 11] = noisy[:, 10] + 0.1e-3  # a near-duplicate
        noisy[5, 40] = np.nan
        yield f"{model}-noisy-auto", noisy, sim.pressure, sim.axial_force, sim.thickness, dict(smoothing="auto"), model
        yield f"{model}-noisy-raw", noisy, sim.pressure, sim.axial_force, sim.thickness, dict(), model
    sim = B.simulate("fung", clamped=False)
    yield "fung-free", sim.positions, sim.pressure, sim.axial_force, sim.thickness, dict(ends="free"), "fung"
    from vfmlab.pipeline import read_identification_inputs
    for path in sorted(glob.glob(ARGS.sessions))[:6] if ARGS.sessions else []:
        d = read_identification_inputs(path)
        for opt in (dict(smoothing="auto"), dict()):
            yield f"{path.split('/')[-1]}-{opt}", d["positions"], d["pressure"], d["force"], d["thickness"], opt, "fung"

#: Scale below which a difference is not relative to the value: unit vectors against their norm; the noise
#: estimate, the axis-fit RMS and the origin offsets of exact data (1e-18 m) against a nanometre (rounding below it).
FLOOR = {"axis_basis": 1.0, "axis_origin": 1e-9, "noise": 1e-9, "axis_rms": 1e-9}

ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
ap.add_argument("mode", choices=["save", "compare"])
ap.add_argument("file")
ap.add_argument("--sessions", help="glob of session files (.h5) to include (first six)")
ap.add_argument("--v", action="store_true", help="also print differences above 1e-8")
ARGS = ap.parse_args()

results = {}
for name, pos, p, f, e0, opt, model in cases():
    vfm._MESH_CACHE.clear(); vfm._STATE_CACHE.clear()
    opt = dict(opt); opt.setdefault("ends", "clamped")
    try:
        d = prepare(pos, p, f, thickness=e0, **opt)
    except Exception as exc:
        results[name] = repr(exc); continue
    fits = []
    for m in ((model,) if model == "hgo" else ("fung", "neohookean")):
        res = identify_prepared(d, m)
        fits.append((m, res, internal_virtual_work(d, m, B.params_of(m))))
    results[name] = summary(d, fits)

if ARGS.mode == "save":
    pickle.dump(results, open(ARGS.file, "wb"))
    print("saved", len(results))
else:
    base = pickle.load(open(ARGS.file, "rb"))
    worst = 0.0
    for name, b in base.items():
        n = results[name]
        if isinstance(b, str) or isinstance(n, str):
            print(name, "ERR" if b != n else "same error", b if isinstance(b, str) else "", n if isinstance(n, str) else ""); continue
        for k, bv in b.items():
            nv = n[k]
            if isinstance(bv, str):
                if bv != nv: print(name, k, "DIFF", bv, nv)
                continue
            bv, nv = np.asarray(bv, float), np.asarray(nv, float)
            if bv.shape != nv.shape:
                print(name, k, "SHAPE", bv.shape, nv.shape); continue
            rel = 0.0
            if bv.size and np.isfinite(bv).any():
                floor = FLOOR.get(k, 1e-9 * np.nanmax(np.abs(bv)))
                with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)
                    rel = np.nanmax(np.abs(nv - bv) / np.maximum(np.abs(bv), floor))
            if not np.array_equal(np.isnan(bv), np.isnan(nv)): print(name, k, "NAN pattern differs")
            worst = max(worst, rel if np.isfinite(rel) else 0)
            if rel > 1e-6 or rel > 1e-8 and ARGS.v: print(name, k, "REL", rel)
    print("worst relative difference", worst)
