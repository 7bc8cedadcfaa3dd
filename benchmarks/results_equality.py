"""Stored results of two trees, compared bit for bit (issue 29: "stored results bit-identical").

    python -m benchmarks.results_equality TREE OUTDIR [--demo]

Runs TREE's code (PYTHONPATH=TREE) on the closed-form session of rig_sim.synthetic_session (tests' e2e data):
identify Fung, Delfino, HGO (free ends, Gauss-Newton errors) and Fung thick/clamped with the bootstrap, then
hashes every dataset and attribute under /entry/results (time stamps, versions and host names left out) into
OUTDIR/hashes.json. Run it for two trees and compare the JSON files (``python -m benchmarks.results_equality
--compare A/hashes.json B/hashes.json``). ``--demo`` adds a demo session; the demo is not deterministic (its
instruments are read in real time), so its hashes differ between runs of one tree.
"""
import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path
if sys.argv[1] == "--compare":
    a, b = (json.load(open(p)) for p in sys.argv[2:4])
    for part in a:
        diff = sorted(k for k in set(a[part]) | set(b.get(part, {})) if a[part].get(k) != b.get(part, {}).get(k))
        print(f"{part}: {len(a[part])} items, {len(diff)} differ", *diff[:20], sep="\n  ")
    raise SystemExit(0)
repo, out = Path(sys.argv[1]).resolve(), Path(sys.argv[2]).resolve()
out.mkdir(parents=True, exist_ok=True)
env = dict(os.environ, PYTHONPATH=str(repo), OPENBLAS_NUM_THREADS="1")
py = sys.executable
def run(*args, check=True):
    r = subprocess.run([py, "-m", "vfmlab", *args], cwd=out, env=env, capture_output=True, text=True)
    if check and r.returncode:
        print(r.stdout[-2000:], r.stderr[-3000:]); raise SystemExit(f"failed: {args}")
    return r
SKIP = ("time", "created", "date", "duration", "elapsed", "host", "version", "seconds", "pid", "uuid", "_s")
def dump(path):
    import h5py
    h = {}
    with h5py.File(path, "r") as f:
        def visit(name, obj):
            if "results/" not in name:
                return
            if isinstance(obj, h5py.Dataset):
                a = obj[()]
                h[name] = hashlib.sha1(repr(a.tolist() if getattr(a, "dtype", None) == object else a).encode() if not hasattr(a, "tobytes") or getattr(a, "dtype", None) == object else a.tobytes()).hexdigest()[:12]
            for k, v in obj.attrs.items():
                if any(s in k.lower() for s in SKIP):
                    continue
                h[name + "@" + k] = hashlib.sha1(repr(v).encode() if not hasattr(v, "tobytes") else v.tobytes()).hexdigest()[:12]
        f.visititems(visit)
    return h
code = f"import sys,importlib,importlib.util,pathlib; sys.path.insert(0, {str(repo / 'tests')!r}); m = importlib.import_module('rig_sim.synthetic_session') if importlib.util.find_spec('rig_sim.synthetic_session') else importlib.import_module('_e2e_data'); m.make_session(pathlib.Path('cf.h5'), with_results=True)"
if (out / "cf.h5").exists(): (out / "cf.h5").unlink()
subprocess.run([py, "-c", code], cwd=out, env=env, check=True)
for m in ("fung", "delfino", "hgo"):
    run("identify", "cf.h5", "--model", m, "--ends", "free", "--uncertainty", "gauss-newton")
run("identify", "cf.h5", "--model", "fung", "--wall", "thick", "--ends", "clamped")
res = {"closed_form": dump(out / "cf.h5")}
if "--demo" in sys.argv:
    import shutil; shutil.rmtree(out / "demo", ignore_errors=True)
    run("demo", "-o", str(out / "demo"), "--cameras", "4", "--markers", "120", "--models", "fung,hgo", "--resolution", "800x640")
    s = sorted((out / "demo").rglob("*.h5"))
    res["demo"] = dump(s[0])
json.dump(res, open(out / "hashes.json", "w"), indent=1, sort_keys=True)
print({k: len(v) for k, v in res.items()})
