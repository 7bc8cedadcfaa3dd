"""``vfmlab info``: a human (or JSON) summary of a session file."""

from __future__ import annotations

import click
import numpy as np
from rich.table import Table

from acquisition.markers_csv import MMHG
from vfmlab.cli._common import console, esc, fixed, num, print_json
from vfmlab.cli._sessions import cli_session


def summarise(s) -> dict:
    """Everything ``info`` shows, as plain data."""
    steps = s.steps
    markers = s.latest("markers")
    n_markers = int(markers["arrays"]["positions"].shape[1]) if markers else 0
    results = []
    for name in s.results():
        r = s.result(name)
        results.append({"name": name, "kind": r["kind"], "date": r["attrs"].get("date", ""),
                         "version": r["attrs"].get("version", "")})
    return {
        "path": str(s.path),
        "schema_version": s.schema_version,
        "status": s.status,
        "start_time": s.start_time,
        "software_version": s.software_version,
        "specimen": {"id": s.specimen.specimen_id, "radius_m": s.specimen.radius, "length_m": s.specimen.length,
                     "thickness_m": s.specimen.thickness, "notes": s.specimen.notes},
        "n_steps": s.n_steps,
        "n_active_steps": int(steps["active"].sum()),
        "n_markers": n_markers,
        "stretches": sorted(set(np.round(steps["stretch"], 6).tolist())),
        "max_pressure_Pa": float(np.nanmax(steps["pressure"])) if s.n_steps else None,
        "instruments": s.instruments,
        "load_cell_measures": s.load_cell_measures,
        "cameras": [{"name": c.name, "model": c.model, "width": c.width, "height": c.height} for c in s.cameras],
        "n_log_samples": {ch: int(len(s.log(ch)["value"])) for ch in ("pressure", "force")},
        "results": results,
    }


EPILOG = """
\b
Examples:
  vfmlab info a1.h5
  vfmlab info a1.h5 --json | jq .specimen
"""


@click.command("info", epilog=EPILOG)
@click.argument("session", type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON (SI units, unit in each key).")
def command(session, as_json):
    """Summarise SESSION: specimen, steps, instruments, status and derived results."""
    with cli_session(session) as s:
        info = summarise(s)
    if as_json:
        print_json(info)
        return
    _print_summary(info)


def _print_summary(info: dict) -> None:
    sp = info["specimen"]
    console.print(f"[bold]{esc(info['path'])}[/]  schema {esc(info['schema_version'])}  "
                  f"status [bold]{esc(info['status'])}[/]  started {esc(_date(info['start_time']))}")
    console.print(
        f"Specimen {esc(sp['id'])}: radius {fixed(sp['radius_m'] * 1e3, 3)} mm, length {fixed(sp['length_m'] * 1e3, 3)} mm, "
        f"wall thickness {fixed(sp['thickness_m'] * 1e3, 3)} mm" + (f"  ({esc(sp['notes'])})" if sp["notes"] else "")
    )
    pmax = info["max_pressure_Pa"]
    stretches = ", ".join(num(v, 4) for v in info["stretches"]) or "none"
    console.print(
        f"Steps: {info['n_steps']} ({info['n_active_steps']} active), axial stretches L/L0 {stretches}, "
        + (f"max pressure {fixed(pmax / MMHG, 1)} mmHg ({fixed(pmax / 1e3, 2)} kPa)" if pmax is not None else "no steps")
    )
    logs = ", ".join(f"{n} {ch}" for ch, n in info["n_log_samples"].items())
    console.print(f"Markers: {info['n_markers']}   instrument log: {logs} samples")
    for role, inst in info["instruments"].items():
        if inst.get("identity"):
            console.print(f"{role.replace('_', ' ').capitalize()}: {esc(inst['identity'])}")
    console.print(f"Load cell measures: {esc(info['load_cell_measures'])} force")
    if info["cameras"]:
        console.print("Cameras: " + ", ".join(f"{esc(c['name'])} ({esc(c['model'])}, {c['width']} × {c['height']} px)"
                                              for c in info["cameras"]))
    if info["results"]:
        table = Table(title="Derived results")
        for col in ("name", "kind", "date (UTC)", "vfmlab version"):
            table.add_column(col)
        for r in info["results"]:
            table.add_row(esc(r["name"]), esc(r["kind"]), esc(_date(r["date"])), esc(r["version"]))
        console.print(table)
    else:
        console.print("No derived results yet.")


def _date(iso: str) -> str:
    """``2026-11-23T16:18:19.909+00:00`` -> ``2026-11-23 16:18:19`` (ISO 8601, seconds)."""
    return str(iso)[:19].replace("T", " ") if iso else "–"
