"""Stored results of a tree on the tests' rendered scene, hashed (issue 29; companion of results_equality).

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python -m benchmarks.results_equality_rendered TREE OUTDIR

The rendered scene of rig_sim.rendered_scene (fixed seeds; 4 steps): the library's ChArUco calibration and marker
reconstruction hashed, then import-images -> reconstruct -> identify through TREE's command line, every dataset of
/entry/results hashed into OUTDIR/rendered.json. One thread: with several, OpenCV's calibration differs in its last
bits from run to run of the same tree. Compare two trees with ``python -m benchmarks.results_equality --compare``
on the two JSON files wrapped as {"rendered": ...}, or with diff.
"""
import hashlib
import json
import os
import sys
import subprocess
from pathlib import Path
repo, out = Path(sys.argv[1]).resolve(), Path(sys.argv[2]).resolve()
sys.path[:0] = [str(repo), str(repo / "tests")]
os.chdir(out)
import numpy as np
import cv2
cv2.setNumThreads(1)
try:
    from rig_sim.rendered_scene import rendered_scene
except ImportError:
    from _recon_rendered import rendered_scene
from reconstruction.pipeline import ReconstructionSettings, reconstruct_series
from reconstruction.calibration_io import cameras_to_toml
cams, calib, frames, images, (R, t) = rendered_scene(n_steps=4)
res = reconstruct_series(images, calib.cameras, ReconstructionSettings(marker_diameter=0.4e-3, specimen_radius=0.010))
H = lambda a: hashlib.sha1(np.ascontiguousarray(a).tobytes()).hexdigest()[:12]
h = {"lib/centres": H(res.centres), "lib/positions": H(res.positions)}
for c in calib.cameras:
    h["lib/cam/" + c.name] = H(np.concatenate([np.ravel(getattr(c, k)) for k in ("K", "dist", "R", "t") if hasattr(c, k)]))
for k in range(4):
    for name, img in images[k].items():
        (out / "img" / name).mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(out / "img" / name / f"{k}.png"), img)
(out / "calibration.toml").write_text(cameras_to_toml(calib.cameras, units="mm"))
(out / "loads.csv").write_text("step,pressure_kPa,axial_force_N,stretch\n0,0,0.1,1.0\n1,5,0.2,1.02\n2,10,0.3,1.04\n3,15,0.4,1.06\n")
env = dict(os.environ, PYTHONPATH=str(repo), OPENBLAS_NUM_THREADS="1")
def cli(*a):
    r = subprocess.run([sys.executable, "-m", "vfmlab", *a], env=env, capture_output=True, text=True)
    if r.returncode: print(r.stderr[-2000:]); raise SystemExit(a)
if (out / "s.h5").exists(): (out / "s.h5").unlink()
cli("import-images", "img", "--calibration", "calibration.toml", "--loads", "loads.csv", "-o", "s.h5",
    "--marker-diameter-mm", "0.4", "--thickness-mm", "1.0")
cli("reconstruct", "s.h5", "--frame", "calibration")
cli("identify", "s.h5", "--model", "fung", "--uncertainty", "gauss-newton")
import h5py
with h5py.File("s.h5", "r") as f:
    def visit(name, obj):
        if "results/" in name and isinstance(obj, h5py.Dataset):
            a = obj[()]
            h[name] = hashlib.sha1(repr(a.tolist() if a.dtype == object else a.tobytes()).encode()).hexdigest()[:12]
    f.visititems(visit)
json.dump(h, open(out / "rendered.json", "w"), indent=1, sort_keys=True)
print(len(h))
