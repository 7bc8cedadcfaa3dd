"""What a session file holds, as plain data (``vfmlab info``): specimen, steps, instruments, cameras, results,
stored warnings; on a damaged file every part that can still be read, the others listed under "damaged"."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from acquisition.session import DamagedSessionError
from vfmlab.stages.outputs import marker_labels

__all__ = ["stored_warnings", "summarise"]


def _part(damaged: list[str], read: Callable[[], Any], default: Any = None) -> Any:
    """``read()``, or ``default`` with the reason appended to ``damaged`` when that part of the file is damaged."""
    try:
        return read()
    except DamagedSessionError as exc:
        damaged.append(str(exc).split(": ", 1)[-1].split("; 'vfmlab info")[0])
        return default


def _specimen(s) -> dict:
    sp = s.specimen
    return {"id": sp.specimen_id, "radius_m": sp.radius, "length_m": sp.length, "thickness_m": sp.thickness,
            "notes": sp.notes}


def _steps(s) -> dict:
    steps = s.steps
    return {"n_steps": s.n_steps, "n_active_steps": int(steps["active"].sum()),
            "stretches": sorted(set(np.round(steps["stretch"][np.isfinite(steps["stretch"])], 6).tolist())),
            "max_pressure_Pa": float(np.nanmax(steps["pressure"])) if np.isfinite(steps["pressure"]).any() else None}


def _results(s, damaged: list[str]) -> tuple[list[dict], int]:
    results, n_markers = [], 0
    for name in _part(damaged, s.results, []):
        r = _part(damaged, lambda n=name: s.result(n))
        if r is None:
            results.append({"name": name, "kind": "damaged", "date": "", "version": ""})
            continue
        results.append({"name": name, "kind": r["kind"], "date": r["attrs"].get("date", ""),
                        "version": r["attrs"].get("version", "")})
        if r["kind"] == "markers":
            _part(damaged, lambda r=r: marker_labels(r, s.path))
        positions = r["arrays"].get("positions") if r["kind"] == "markers" else None
        if positions is not None and np.ndim(positions) == 3:
            n_markers = int(positions.shape[1])
    return results, n_markers


def summarise(s) -> dict:
    """Everything ``info`` shows, as plain data; unreadable parts are None and listed under "damaged"."""
    damaged: list[str] = []
    part = lambda read, default=None: _part(damaged, read, default)  # noqa: E731
    steps = part(lambda: _steps(s), {"n_steps": None, "n_active_steps": None, "stretches": [],
                                     "max_pressure_Pa": None})
    results, n_markers = _results(s, damaged)
    info = {
        "path": str(s.path),
        "schema_version": part(lambda: s.schema_version),
        "status": part(lambda: s.status),
        "start_time": part(lambda: s.start_time),
        "software_version": part(lambda: s.software_version),
        "specimen": part(lambda: _specimen(s)),
        **steps,
        "n_markers": n_markers,
        "instruments": part(lambda: s.instruments, {}),
        "load_cell_measures": part(lambda: s.load_cell_measures),
        "cameras": part(lambda: [{"name": c.name, "model": c.model, "width": c.width, "height": c.height}
                                 for c in s.cameras], []),
        "n_log_samples": {ch: part(lambda ch=ch: int(len(s.log(ch)["value"]))) for ch in ("pressure", "force")},
        "results": results,
    }
    info["warnings"] = part(lambda: stored_warnings(s), [])
    info["damaged"] = damaged
    return info


def stored_warnings(s) -> list[str]:
    """Plausibility warnings stored in the session (events of kind "warning"), oldest first."""
    return [e["message"] for e in s.events() if e["kind"] == "warning"]
