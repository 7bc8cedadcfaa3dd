"""What ``vfmlab identify`` shows: the parameter table with intervals and verdicts, or a regional profile."""

from __future__ import annotations

from rich.markup import escape

from vfmlab.display import display_quantity, num

__all__ = ["WALL_NOTE", "identify_lines", "regional_lines"]


def esc(value) -> str:
    """``value`` as text safe inside rich markup."""
    return escape(str(value))


WALL_NOTE = {
    "membrane": "paper's plain membrane form (pressure on the marker surface)",
    "thick": "thick wall: markers on the outer surface, pressure on the lumen, layered divergence-free fields",
}


def identify_lines(outcome) -> list[tuple]:
    """What ``vfmlab identify`` shows of a homogeneous fit: the parameter table with intervals and verdicts, the
    verdict lines, the fit's figures, notes and warnings; ``(renderable, style)`` pairs in order."""
    from rich.table import Table

    from vfmlab.stages.identify import verdict_lines

    out: list[tuple] = []

    result, model, wall, units = outcome.result, outcome.settings.model, outcome.wall, outcome.units
    table = Table(title=f"{model} ({WALL_NOTE[wall]})")
    table.add_column("parameter")
    table.add_column("value", justify="right")
    table.add_column("std. error", justify="right")
    unc = result.uncertainty
    if unc is not None:
        table.add_column("95 % interval", justify="right")
    table.add_column("unit")
    verdicts = dict(result.parameter_verdicts or {})
    if verdicts:
        table.add_column("verdict")
    for n in result.parameters:
        v, unit = display_quantity(result.parameters[n], units[n])
        s, _ = display_quantity(result.stderr[n], units[n])
        interval = []
        if unc is not None:
            lo, _ = display_quantity(unc.interval[n][0], units[n])
            hi, _ = display_quantity(unc.interval[n][1], units[n])
            interval = [f"{num(lo, 4)} to {num(hi, 4)}"]
        table.add_row(esc(n), num(v, 4), num(s, 2), *interval, unit or "–", *([verdicts[n]] if verdicts else []))
    out.append((table, None))
    for line in verdict_lines(result.verdict, result.verdict_reasons, result.parameter_verdicts,
                              result.parameter_reasons):
        out.append((esc(line), "bold yellow" if "doubtful" in line else None))
    out.append((f"cost {num(result.cost, 3)}, RMS gap per field "
                  + ", ".join(f"{esc(f)}: {g:.2%}" for f, g in zip(result.field_names, result.residual_per_field))
                  + f", {result.n_evaluations} evaluations, converged: {result.converged}", None))
    for note in outcome.data["notes"]:
        out.append((f"[dim]{esc(note)}[/]", None))
    for flag in result.flags:
        out.append((f"[yellow]warning:[/] {esc(flag)}", None))
    out.append((f"stored as {esc(outcome.group)}", None))
    return out


def _table(result, model_units):
    from rich.table import Table

    what = "per axial band" if result.kind == "bands" else "along the axis (Legendre profile of the log)"
    table = Table(title=f"{result.model}: {', '.join(result.regional)} {what} (shared: "
                        f"{', '.join(result.parameters) or 'none'})")
    for col, just in (("band" if result.kind == "bands" else "point", "right"), ("from", "right"), ("to", "right"),
                      ("parameter", "left"), ("value", "right"), ("std. error", "right"), ("95 % interval", "right"),
                      ("unit", "left"), ("vs median", "right")):
        table.add_column(col, justify=just)
    for n in result.regional:
        for b in range(result.n_bands):
            v, unit = display_quantity(result.profiles[n][b], model_units[n])
            s, _ = display_quantity(result.stderr[n][b], model_units[n])
            lo, _ = display_quantity(result.interval[n][b, 0], model_units[n])
            hi, _ = display_quantity(result.interval[n][b, 1], model_units[n])
            mark = " *" if result.differs[b] else ""
            table.add_row(str(b), f"{result.edges[b] * 1e3:.1f} mm", f"{result.edges[b + 1] * 1e3:.1f} mm", esc(n),
                          num(v, 4), num(s, 2), f"{num(lo, 3)} to {num(hi, 3)}", unit or "–",
                          f"{result.contrast[n][b]:+.1%}{mark}")
    return table


def _choice_line(choice) -> str:
    rows = ", ".join(f"{k}: {c:.3g}" for k, c in zip(choice.candidates, choice.criterion))
    return (f"--regions auto chose {choice.n_bands} band(s): the least misfit of a step profile to the "
                  f"{choice.candidates[-1]}-band profile in its uncertainty, plus 2 per band (Akaike; per band count: "
                  f"{rows})")


def regional_lines(outcome) -> list:
    """What ``vfmlab identify --regions`` shows of a stored regional result: the choice, the table, the shared
    and homogeneous parameters, notes and warnings (rich renderables, in order)."""
    out: list = []
    result, data, model_units = outcome.result, outcome.data, outcome.units
    if data.get("choice") is not None:
        out.append(_choice_line(data["choice"]))
    out.append(_table(result, model_units))
    for n, v in result.parameters.items():
        val, unit = display_quantity(v, model_units[n])
        out.append(f"shared {esc(n)} = {num(val, 4)} {unit or ''}".rstrip())
    hom = result.homogeneous.parameters
    for n in result.regional:
        val, unit = display_quantity(hom[n], model_units[n])
        out.append(f"homogeneous fit for comparison: {esc(n)} = {num(val, 4)} {unit or ''}".rstrip())
    out.append("positions: reference axial coordinate from the mean marker position, towards the load cell; "
                  f"errors: {result.uncertainty}; * = differs from the median band")
    for note in data["notes"]:
        out.append(f"[dim]{esc(note)}[/]")
    for flag in result.flags:
        out.append(f"[yellow]warning:[/] {esc(flag)}")
    out.append(f"stored as {esc(outcome.group)}")
    return out
