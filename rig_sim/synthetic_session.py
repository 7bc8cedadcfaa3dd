"""Small synthetic sessions for the e2e tests (report, export, results, reprocess) and benchmarks/bench_e2e.py.

A tube of radius 10 mm inflated and stretched with a closed-form, slightly non-uniform deformation
(r bulges at mid-span), markers on its surface, and stored results of the documented shapes:
"calibration", "markers" and "identification" (Fung, Delfino).
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from acquisition.session import (CameraSpec, SessionWriter, SpecimenInfo, StagedSession, StepRecord, staged_session,
                                 write_result)

MMHG = 133.322387415
RADIUS, LENGTH, THICKNESS = 10e-3, 35e-3, 1.3e-3


def synthetic_tube(n_markers: int = 160, stretches=(1.05, 1.1), pressures_mmhg=(30, 80, 150), seed: int = 0):
    """Marker positions (n_steps, n_markers, 3) m and the step loads (pressure Pa, force N, stretch)."""
    rng = np.random.default_rng(seed)
    theta = rng.uniform(-np.pi, np.pi, n_markers)
    Z = rng.uniform(-13.5e-3, 13.5e-3, n_markers)
    steps = [(1.0, 0.0)] + [(s, p * MMHG) for s in stretches for p in pressures_mmhg]
    pos, pressure, force, stretch = [], [], [], []
    for lam_z, p in steps:
        lam_t = 1.0 + 0.3 * np.sqrt(p / (150 * MMHG)) * (1 + 0.05 * np.cos(np.pi * Z / LENGTH) + 0.01 * np.sin(theta))
        r = RADIUS * lam_t
        pos.append(np.stack([r * np.cos(theta), r * np.sin(theta), lam_z * Z], axis=1))
        pressure.append(p)
        h = THICKNESS / (lam_t.mean() * lam_z)
        force.append(0.5 * p * np.pi * (RADIUS * lam_t.mean()) ** 2 + 2 * np.pi * RADIUS * h * 40e3 * (lam_z - 1))
        stretch.append(lam_z)
    pos = np.array(pos) + rng.normal(0, 2e-6, (len(steps), n_markers, 3))
    return pos, np.array(pressure), np.array(force), np.array(stretch)


def make_session(path: Path, *, n_markers: int = 160, with_results: bool = True, seed: int = 0,
                 specimen_id: str = "synthetic-01") -> Path:
    """Write a complete session with synthetic steps, logs and (optionally) results; returns its path."""
    pos, pressure, force, stretch = synthetic_tube(n_markers, seed=seed)
    cams = [CameraSpec(f"cam{i}", "simulated", 64, 48) for i in range(4)]
    spec = SpecimenInfo(specimen_id, RADIUS, LENGTH, THICKNESS, "synthetic test tube")
    protocol = "[preconditioning]\ncycles = 3\n\n[[block]]\nstretch = 1.05\npressures_mmHg = [0, 30, 80, 150]\n"
    with staged_session(path) as staged:  # results inside the file: a copy of the file carries them
        with SessionWriter.create(staged.path, spec, cameras=cams, protocol_text=protocol, rig={"cameras": 4},
                                  instruments={"pressure": {"identity": "SIM-PT 1.0", "settings": {"range_kPa": 40}},
                                               "load_cell": {"identity": "SIM-LC 2.0",
                                                             "settings": {"range_N": 10}}}) as w:
            t = np.arange(50) * 0.1
            w.append_log("pressure", t, 1.7e9 + t, np.interp(t, np.linspace(0, 5, len(pressure)), pressure))
            w.append_log("force", t, 1.7e9 + t, np.interp(t, np.linspace(0, 5, len(force)), force))
            for k in range(len(pressure)):
                w.add_step(StepRecord(block=int(k > 3), stretch=float(stretch[k]), target_pressure=float(pressure[k]),
                                      pressure=float(pressure[k]) * 1.001, force=float(force[k]),
                                      t_monotonic=float(k), t_wall=1.7e9 + k),
                           images={c.name: np.full((48, 64), k, np.uint8) for c in cams})
        if with_results:
            _add_results(staged, pos, cams, len(pressure), n_markers, seed)
    return path


def _add_results(staged, pos, cams, n_steps, n_markers, seed) -> None:
    add = staged.add_result
    add("calibration",
                 {"camera_names": np.array([c.name for c in cams]), "K": np.tile(np.eye(3), (4, 1, 1)),
                  "dist": np.zeros((4, 5)), "rvec": np.zeros((4, 3)), "tvec": np.zeros((4, 3)),
                  "image_size": np.tile([64, 48], (4, 1)), "rms": np.array([0.21, 0.25, 0.19, 0.31]),
                  "rms_per_view": np.abs(np.random.default_rng(seed).normal(0.25, 0.08, (4, 6)))},
                 {"board": "charuco"}, attrs={"rms_total": 0.245, "n_observations": 2304, "n_outliers": 3,
                                              "converged": True}, units={"rms": "px"})
    rng = np.random.default_rng(seed + 1)
    visible = rng.random(pos.shape[:2]) > 0.03
    visible[0] = True
    add("markers",
                 {"positions": np.where(visible[..., None], pos, np.nan), "visible": visible,
                  "uncertainty": np.full(visible.shape, 5e-6), "marker_id": np.arange(n_markers),
                  "step_index": np.arange(n_steps)},
                 {"source": "synthetic"}, units={"positions": "m", "uncertainty": "m"})
    add_identification(staged, "fung", ["beta", "alpha11", "alpha22", "alpha12"], [5.0e3, 14.5, 7.0, 0.1],
                       n_steps=n_steps, cost=1.2e-3, seed=seed)
    add_identification(staged, "delfino", ["beta", "alpha"], [1.5e3, 4.6], n_steps=n_steps, cost=4.5e-3, seed=seed)


def add_identification(path, model, names, values, *, n_steps, cost, seed=0, wall="membrane", optimizer="lsq"):
    """Add a synthetic identification result to the session at ``path`` (or to a staged session being built)."""
    write = path.add_result if isinstance(path, StagedSession) else functools.partial(write_result, path)
    rng = np.random.default_rng(seed + len(names))
    n = len(names)
    values = np.asarray(values, float)
    a = rng.normal(size=(n, n))
    cov = a @ a.T + n * np.eye(n)
    d = np.sqrt(np.diag(cov))
    corr = cov / np.outer(d, d)
    ivw = np.abs(rng.normal(1e-4, 2e-5, (2, n_steps))) * np.arange(n_steps)
    evw = ivw * (1 + rng.normal(0, 0.03, ivw.shape))
    flags = {"alpha12": "weakly identifiable (stderr > 50 %)"} if "alpha12" in names else {}
    return write("identification",
                        {"parameters": values, "stderr": 0.04 * np.abs(values) + 1e-3, "parameter_names": np.array(names),
                         "correlation": corr, "ivw": ivw, "evw": evw, "field_names": np.array(["hoop", "axial"])},
                        {"model": model, "wall": wall, "optimizer": optimizer},
                        attrs={"model": model, "wall": wall, "cost": cost, "converged": True, "flags": flags})
