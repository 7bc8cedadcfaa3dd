"""``vfmlab results``: list the derived results of a session and compare two of them."""

from __future__ import annotations

import json

import click
from rich.markup import escape
from rich.table import Table


from vfmlab.cli._common import CliError, console, print_json
from vfmlab.cli._sessions import cli_session


KEY_SETTINGS = {"identification": ("optimizer", "ends", "markers_result")}


def _settings_text(kind: str, settings: dict, limit: int = 120) -> str:
    keys = KEY_SETTINGS.get(kind)
    items = [(k, settings[k]) for k in keys if k in settings] if keys else sorted(settings.items())
    text = ", ".join(f"{k}={v}" if isinstance(v, str) else f"{k}={json.dumps(v)}" for k, v in items)
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
        data = compare_results(s, *compare) if compare else list_results(s, kind)
    if as_json:
        print_json(data)
        return
    if compare:
        _print_comparison(data)
        return
    if not data:
        console.print(f"{session}: no results{' of kind ' + kind if kind else ''} yet.")
        return
    console.print(f"[bold]{escape(str(session))}[/]: {len(data)} result(s), oldest first")
    for row in data:
        console.print(f"[bold cyan]{row['name']}[/]  {row['date'][:19].replace('T', ' ')} UTC  "
                      f"vfmlab {escape(row['version'])}", soft_wrap=True)
        console.print(f"    settings: {escape(_settings_text(row['kind'], row['settings']))}", soft_wrap=True)
        if row["kind"] == "identification":
            params = ", ".join(f"{n} = {_num(p['value'])} ± {_num(p['stderr'])}" for n, p in row["parameters"].items())
            state = "converged" if row["converged"] else "[red]NOT converged[/]"
            console.print(f"    {row['model']} ({row['wall']}), cost {_num(row['cost'])}, {state}: {params}",
                          soft_wrap=True)
            flags = row["flags"] if isinstance(row["flags"], list) else [f"{k}: {v}" for k, v in row["flags"].items()]
            for flag in flags:
                console.print(f"    [yellow]warning:[/] {escape(str(flag))}", soft_wrap=True)
        elif row["kind"] == "markers" and "n_markers" in row:
            console.print(f"    {row['n_markers']} markers × {row['n_steps']} steps, "
                          f"{row['completeness'] * 100:.1f} % of marker-steps reconstructed")
        elif row["kind"] == "calibration" and "rms_px" in row:
            console.print(f"    {len(row['rms_px'])} cameras, reprojection RMS "
                          + ", ".join(f"{c} {v:.3f}" for c, v in zip(row["cameras"], row["rms_px"])) + " px",
                          soft_wrap=True)


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
