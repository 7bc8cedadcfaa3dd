"""``vfmlab info``: a human (or JSON) summary of a session file."""

from __future__ import annotations

import click
import numpy as np
from rich.table import Table

from acquisition.markers_csv import MMHG
from vfmlab.cli._common import console, print_json
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


@click.command("info")
@click.argument("session", type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON for scripts.")
def command(session, as_json):
    """Summarise SESSION: specimen, steps, instruments, status and derived results."""
    with cli_session(session) as s:
        info = summarise(s)
    if as_json:
        print_json(info)
        return
    sp = info["specimen"]
    console.print(f"[bold]{info['path']}[/]  schema {info['schema_version']}  status [bold]{info['status']}[/]")
    console.print(
        f"Specimen {sp['id']}: R = {sp['radius_m'] * 1e3:.3f} mm, L = {sp['length_m'] * 1e3:.3f} mm, "
        f"e = {sp['thickness_m'] * 1e3:.3f} mm" + (f"  ({sp['notes']})" if sp["notes"] else "")
    )
    pmax = info["max_pressure_Pa"]
    console.print(
        f"Steps: {info['n_steps']} ({info['n_active_steps']} active), stretches {info['stretches']}, "
        + (f"max pressure {pmax / MMHG:.1f} mmHg ({pmax / 1e3:.2f} kPa)" if pmax is not None else "no steps")
    )
    console.print(f"Markers: {info['n_markers']}   log samples: {info['n_log_samples']}")
    for role, inst in info["instruments"].items():
        if inst["identity"]:
            console.print(f"{role}: {inst['identity']}")
    console.print(f"Load cell measures: {info['load_cell_measures']} force")
    if info["cameras"]:
        console.print("Cameras: " + ", ".join(f"{c['name']} ({c['model']}, {c['width']}x{c['height']})"
                                              for c in info["cameras"]))
    if info["results"]:
        table = Table(title="Derived results")
        for col in ("name", "kind", "date", "version"):
            table.add_column(col)
        for r in info["results"]:
            table.add_row(r["name"], r["kind"], str(r["date"]), str(r["version"]))
        console.print(table)
    else:
        console.print("No derived results yet.")
