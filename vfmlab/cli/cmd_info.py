"""``vfmlab info``: a human (or JSON) summary of a session file.

On a damaged file, every part that can still be read is shown, the parts that cannot are listed
under "damaged", and the command exits with code 2 (decision 0007).
"""

from __future__ import annotations


import click
from rich.table import Table

from acquisition.plausibility import MMHG
from vfmlab.cli._common import CliInputError, console, err_console, esc, fixed, num, print_json
from vfmlab.cli._sessions import cli_session
from vfmlab.stages.info import summarise


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
    """Summarise SESSION: specimen, steps, instruments, status and derived results.

    On a damaged file, lists what is still readable and what is not, and exits with code 2."""
    with cli_session(session) as s:
        info = summarise(s)
    if as_json:
        print_json(info)
    else:
        _print_summary(info)
    if info["damaged"]:
        raise CliInputError(f"{session}: damaged file: {len(info['damaged'])} part(s) cannot be read "
                            f"({'; '.join(info['damaged'])}); everything else shown is readable")


def _print_summary(info: dict) -> None:
    console.print(f"[bold]{esc(info['path'])}[/]  schema {esc(info['schema_version'])}  "
                  f"status [bold]{esc(info['status'])}[/]  started {esc(_date(info['start_time']))}")
    sp = info["specimen"]
    if sp is not None:
        console.print(
            f"Specimen {esc(sp['id'])}: radius {fixed(sp['radius_m'] * 1e3, 3)} mm, length "
            f"{fixed(sp['length_m'] * 1e3, 3)} mm, wall thickness {fixed(sp['thickness_m'] * 1e3, 3)} mm"
            + (f"  ({esc(sp['notes'])})" if sp["notes"] else ""))
    pmax = info["max_pressure_Pa"]
    stretches = ", ".join(num(v, 4) for v in info["stretches"]) or "none"
    if info["n_steps"] is not None:
        console.print(
            f"Steps: {info['n_steps']} ({info['n_active_steps']} active), axial stretches L/L0 {stretches}, "
            + (f"max pressure {fixed(pmax / MMHG, 1)} mmHg ({fixed(pmax / 1e3, 2)} kPa)" if pmax is not None
               else "no pressures"))
    logs = ", ".join(f"{n if n is not None else 'unreadable'} {ch}" for ch, n in info["n_log_samples"].items())
    console.print(f"Markers: {info['n_markers']}   instrument log: {logs} samples")
    for role, inst in info["instruments"].items():
        if inst.get("identity"):
            console.print(f"{role.replace('_', ' ').capitalize()}: {esc(inst['identity'])}")
    if info["load_cell_measures"] is not None:
        console.print(f"Load cell measures: {esc(info['load_cell_measures'])} force")
    if info["cameras"]:
        console.print("Cameras: " + ", ".join(f"{esc(c['name'])} ({esc(c['model'])}, {c['width']} × {c['height']} px)"
                                              for c in info["cameras"]))
    _print_results(info["results"])
    for message in info["warnings"]:
        console.print(f"[yellow]Warning (stored in the session):[/] {esc(message)}")
    for what in info["damaged"]:
        err_console.print(f"[red]Damaged:[/] {esc(what)}")


def _print_results(results: list[dict]) -> None:
    if not results:
        console.print("No derived results yet.")
        return
    table = Table(title="Derived results")
    for col in ("name", "kind", "date (UTC)", "vfmlab version"):
        table.add_column(col)
    for r in results:
        table.add_row(esc(r["name"]), esc(r["kind"]), esc(_date(r["date"])), esc(r["version"]))
    console.print(table)


def _date(iso: str) -> str:
    """``2026-11-23T16:18:19.909+00:00`` -> ``2026-11-23 16:18:19`` (ISO 8601, seconds)."""
    return str(iso)[:19].replace("T", " ") if iso else "–"
