"""``vfmlab results``: list the derived results of a session and compare two of them."""

from __future__ import annotations

import json

import click
from rich.table import Table

from acquisition.session import SessionError
from vfmlab.cli._common import CliError, console, print_json
from vfmlab.cli._sessions import cli_session


def _settings_text(settings: dict, limit: int = 60) -> str:
    text = ", ".join(f"{k}={json.dumps(v)}" for k, v in sorted(settings.items()))
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _num(value) -> str:
    if value is None:
        return "–"
    try:
        value = float(value)
    except (TypeError, ValueError):
        return str(value)
    return "–" if value != value else f"{value:.4g}"


@click.command("results")
@click.argument("session", type=click.Path(dir_okay=False))
@click.option("--kind", help="Only results of this kind (calibration, markers, identification, ...).")
@click.option("--compare", nargs=2, metavar="A B", help="Compare two results by name, e.g. identification_001 identification_002.")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable JSON on stdout.")
def command(session, kind, compare, as_json):
    """List the results stored in SESSION (name, kind, date, version, settings; identified parameters),
    or compare two of them (settings diff and differences of their parameters)."""
    from vfmlab.results import compare_results, list_results

    with cli_session(session) as s:
        try:
            if compare:
                data = compare_results(s, *compare)
            else:
                data = list_results(s, kind)
        except SessionError as exc:
            raise CliError(str(exc)) from None
    if as_json:
        print_json(data)
        return
    if compare:
        _print_comparison(data)
        return
    if not data:
        console.print(f"{session}: no results{' of kind ' + kind if kind else ''} yet.")
        return
    table = Table(title=f"Results in {session}")
    table.add_column("name", no_wrap=True)
    for col in ("date (UTC)", "version", "settings", "summary"):
        table.add_column(col, overflow="fold")
    for row in data:
        if row["kind"] == "identification":
            summary = (f"{row['model']} ({row['wall']}) cost {_num(row['cost'])}"
                       f"{'' if row['converged'] else ' NOT CONVERGED'}: "
                       + ", ".join(f"{n}={_num(p['value'])}±{_num(p['stderr'])}" for n, p in row["parameters"].items()))
        elif row["kind"] == "markers" and "n_markers" in row:
            summary = f"{row['n_markers']} markers × {row['n_steps']} steps, {row['completeness'] * 100:.1f} % seen"
        elif row["kind"] == "calibration" and "rms_px" in row:
            summary = f"{len(row['rms_px'])} cameras, RMS " + ", ".join(f"{v:.2f}" for v in row["rms_px"]) + " px"
        else:
            summary = ""
        table.add_row(row["name"], row["date"][:16].replace("T", " "), row["version"], _settings_text(row["settings"]),
                      summary)
    console.print(table)


def _print_comparison(data: dict) -> None:
    a, b = data["a"]["name"], data["b"]["name"]
    console.print(f"[bold]{a}[/] ({data['a']['kind']}, {data['a']['date'][:19]}) vs "
                  f"[bold]{b}[/] ({data['b']['kind']}, {data['b']['date'][:19]})")
    if data.get("note"):
        console.print(data["note"])
    diffs = {**data["settings_diff"], **{f"@{k}": v for k, v in data["attrs_diff"].items()}}
    if diffs:
        t = Table(title="Settings that differ")
        for col in ("setting", a, b):
            t.add_column(col)
        for k, v in diffs.items():
            t.add_row(k, json.dumps(v["a"], default=str), json.dumps(v["b"], default=str))
        console.print(t)
    else:
        console.print("Same settings.")
    if "parameters" in data:
        t = Table(title="Parameters")
        for col in ("parameter", a, b, "b − a", "relative", "in std. errors"):
            t.add_column(col, justify="right")
        for n, r in data["parameters"].items():
            rel = "–" if r["rel_diff"] != r["rel_diff"] else f"{r['rel_diff'] * 100:+.2f} %"
            t.add_row(n, _num(r["a"]), _num(r["b"]), _num(r["diff"]), rel, _num(r["diff_over_stderr"]))
        console.print(t)
    if "positions" in data:
        p = data["positions"]
        if "note" in p:
            console.print(p["note"])
        else:
            console.print(f"Marker positions: {p['common_marker_steps']} marker-steps in both; RMS distance "
                          f"{p['rms_distance_m'] * 1e3:.4f} mm, max {p['max_distance_m'] * 1e3:.4f} mm.")
