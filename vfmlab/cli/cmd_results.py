"""``vfmlab results``: list the derived results of a session and compare two of them."""

from __future__ import annotations

import click
from rich.table import Table

from vfmlab.cli._common import console, esc, num, print_json, quantity
from vfmlab.display import settings_text
from vfmlab.cli._sessions import cli_session


KEY_SETTINGS = {"identification": ("optimizer", "ends", "markers_result")}


def _settings_text(kind: str, settings: dict) -> str:
    return settings_text(settings, KEY_SETTINGS.get(kind))  # --json or --compare show every setting


EPILOG = """
\b
Examples:
  vfmlab results a1.h5
  vfmlab results a1.h5 --kind identification --json
  vfmlab results a1.h5 --compare identification_001 identification_002
"""


@click.command("results", epilog=EPILOG)
@click.argument("session", type=click.Path(dir_okay=False))
@click.option("--kind", help="Only results of this kind (calibration, markers, identification, ...).")
@click.option("--compare", nargs=2, metavar="A B", help="Compare two results by name, e.g. identification_001 identification_002.")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable JSON on stdout (SI; each parameter has its unit).")
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
        console.print(f"{esc(session)}: no results{' of kind ' + esc(kind) if kind else ''} yet.")
        return
    console.print(f"[bold]{esc(session)}[/]: {len(data)} result(s), oldest first")
    for row in data:
        _print_row(row)


def _print_row(row: dict) -> None:
    from vfmlab.stages.identify import verdict_lines

    console.print(f"[bold cyan]{esc(row['name'])}[/]  {esc(row['date'][:19].replace('T', ' '))} UTC  "
                  f"vfmlab {esc(row['version'])}")
    console.print(f"    settings: {esc(_settings_text(row['kind'], row['settings']))}")
    if row["kind"] == "identification":
        params = ", ".join(f"{esc(n)} = {quantity(p['value'], p['unit'])} ± {quantity(p['stderr'], p['unit'], 2)}"
                           for n, p in row["parameters"].items())
        state = "converged" if row["converged"] else "[red]NOT converged[/]"
        console.print(f"    {esc(row['model'])} ({esc(row['wall'])}), cost {num(row['cost'], 3)}, {state}: {params}")
        flags = row["flags"] if isinstance(row["flags"], list) else [f"{k}: {v}" for k, v in row["flags"].items()]
        for line in verdict_lines(row.get("verdict"), row.get("verdict_reasons", ()), row.get("parameter_verdicts"),
                                  row.get("parameter_reasons")):
            console.print(f"    {esc(line)}")
        for flag in flags:
            console.print(f"    [yellow]warning:[/] {esc(flag)}")
    elif row["kind"] == "markers" and "n_markers" in row:
        console.print(f"    {row['n_markers']} markers × {row['n_steps']} steps, "
                      f"{row['completeness'] * 100:.1f} % of marker-steps reconstructed")
    elif row["kind"] == "calibration" and "rms_px" in row:
        console.print(f"    {len(row['rms_px'])} cameras, reprojection RMS "
                      + ", ".join(f"{esc(c)} {v:.3f} px" for c, v in zip(row["cameras"], row["rms_px"])))


def _print_comparison(data: dict) -> None:
    a, b = esc(data["a"]["name"]), esc(data["b"]["name"])
    console.print(f"[bold]{a}[/] ({esc(data['a']['kind'])}, {esc(data['a']['date'][:19])}) vs "
                  f"[bold]{b}[/] ({esc(data['b']['kind'])}, {esc(data['b']['date'][:19])})")
    if data.get("note"):
        console.print(esc(data["note"]))
    diffs = {**data["settings_diff"], **{f"@{k}": v for k, v in data["attrs_diff"].items()}}
    if diffs:
        t = Table(title="Settings that differ")
        for col in ("setting", a, b):
            t.add_column(col)
        for k, v in diffs.items():
            t.add_row(esc(k), esc(settings_text({"": v["a"]})[1:]), esc(settings_text({"": v["b"]})[1:]))
        console.print(t)
    else:
        console.print("Same settings.")
    if "parameters" in data:
        t = Table(title="Parameters")
        for col in ("parameter", a, b, "b − a", "relative", "in std. errors"):
            t.add_column(col, justify="right")
        for n, r in data["parameters"].items():
            rel = "–" if r["rel_diff"] != r["rel_diff"] else f"{r['rel_diff'] * 100:+.2f} %"
            unit = r.get("unit", "")
            t.add_row(esc(n), quantity(r["a"], unit), quantity(r["b"], unit), quantity(r["diff"], unit), rel,
                      num(r["diff_over_stderr"], 3))
        console.print(t)
    if "positions" in data:
        p = data["positions"]
        if "note" in p:
            console.print(esc(p["note"]))
        else:
            console.print(f"Marker positions: {p['common_marker_steps']} marker-steps in both; RMS distance "
                          f"{p['rms_distance_m'] * 1e3:.4f} mm, max {p['max_distance_m'] * 1e3:.4f} mm.")
