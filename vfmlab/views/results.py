"""What ``vfmlab results`` shows: each stored result as lines, and two results compared (rich renderables)."""

from __future__ import annotations

from rich.markup import escape
from rich.table import Table

from vfmlab.display import num, quantity, settings_text

__all__ = ["comparison_lines", "reachable_lines", "result_lines"]


def esc(value) -> str:
    """``value`` as text safe inside rich markup."""
    return escape(str(value))


def result_lines(row: dict, settings: str) -> list:
    """One stored result as lines: name, date and version; its settings; what it holds (parameters, verdict,
    warnings; marker counts; camera RMS)."""
    from vfmlab.stages.identify import verdict_lines

    out: list = []
    out.append(f"[bold cyan]{esc(row['name'])}[/]  {esc(row['date'][:19].replace('T', ' '))} UTC  "
                  f"vfmlab {esc(row['version'])}")
    out.append(f"    settings: {esc(settings)}")
    if row["kind"] == "identification":
        params = ", ".join(f"{esc(n)} = {quantity(p['value'], p['unit'])} ± {quantity(p['stderr'], p['unit'], 2)}"
                           for n, p in row["parameters"].items())
        state = "converged" if row["converged"] else "[red]NOT converged[/]"
        out.append(f"    {esc(row['model'])} ({esc(row['wall'])}), cost {num(row['cost'], 3)}, {state}: {params}")
        flags = row["flags"] if isinstance(row["flags"], list) else [f"{k}: {v}" for k, v in row["flags"].items()]
        for line in verdict_lines(row.get("verdict"), row.get("verdict_reasons", ()), row.get("parameter_verdicts"),
                                  row.get("parameter_reasons")):
            out.append(f"    {esc(line)}")
        for flag in flags:
            out.append(f"    [yellow]warning:[/] {esc(flag)}")
        out += reachable_lines(row)
    elif row["kind"] == "markers" and "n_markers" in row:
        out.append(f"    {row['n_markers']} markers × {row['n_steps']} steps, "
                      f"{row['completeness'] * 100:.1f} % of marker-steps reconstructed")
    elif row["kind"] == "calibration" and "rms_px" in row:
        out.append(f"    {len(row['rms_px'])} cameras, reprojection RMS "
                      + ", ".join(f"{esc(c)} {v:.3f} px" for c, v in zip(row["cameras"], row["rms_px"])))
    return out


def reachable_lines(row: dict) -> list:
    """The 95 % half-width achieved (1.96 standard errors) beside the one the bound allows this test, per parameter
    (:func:`vfmlab.stages.reachable.with_reachable`); nothing when the row does not carry it."""
    reach = row.get("reachable")
    if not reach:
        return []
    hw = reach.get("half_width_95_percent") or {}
    if not hw:
        return [f"    [dim]{esc(reach.get('note', 'reachable n/a'))}[/]"]
    cells = []
    for n, p in row["parameters"].items():
        got = 196.0 * p["stderr"] / abs(p["value"]) if p["value"] else float("nan")
        cells.append(f"{esc(n)} ±{num(got, 3)} % / ±{num(hw[n], 3)} %" if n in hw else f"{esc(n)} ±{num(got, 3)} % / n/a")
    return [f"    ± 95 % achieved / reachable: {', '.join(cells)}", f"    [dim]({esc(reach.get('note', ''))})[/]"]


def comparison_lines(data: dict) -> list:
    """Two results compared: the settings that differ, the parameters' differences, the marker distances."""
    out: list = []
    a, b = esc(data["a"]["name"]), esc(data["b"]["name"])
    out.append(f"[bold]{a}[/] ({esc(data['a']['kind'])}, {esc(data['a']['date'][:19])}) vs "
                  f"[bold]{b}[/] ({esc(data['b']['kind'])}, {esc(data['b']['date'][:19])})")
    if data.get("note"):
        out.append(esc(data["note"]))
    diffs = {**data["settings_diff"], **{f"@{k}": v for k, v in data["attrs_diff"].items()}}
    if diffs:
        t = Table(title="Settings that differ")
        for col in ("setting", a, b):
            t.add_column(col)
        for k, v in diffs.items():
            t.add_row(esc(k), esc(settings_text({"": v["a"]})[1:]), esc(settings_text({"": v["b"]})[1:]))
        out.append(t)
    else:
        out.append("Same settings.")
    if "parameters" in data:
        t = Table(title="Parameters")
        for col in ("parameter", a, b, "b − a", "relative", "in std. errors"):
            t.add_column(col, justify="right")
        for n, r in data["parameters"].items():
            rel = "–" if r["rel_diff"] != r["rel_diff"] else f"{r['rel_diff'] * 100:+.2f} %"
            unit = r.get("unit", "")
            t.add_row(esc(n), quantity(r["a"], unit), quantity(r["b"], unit), quantity(r["diff"], unit), rel,
                      num(r["diff_over_stderr"], 3))
        out.append(t)
    if "positions" in data:
        p = data["positions"]
        if "note" in p:
            out.append(esc(p["note"]))
        else:
            out.append(f"Marker positions: {p['common_marker_steps']} marker-steps in both; RMS distance "
                          f"{p['rms_distance_m'] * 1e3:.4f} mm, max {p['max_distance_m'] * 1e3:.4f} mm.")
    return out
