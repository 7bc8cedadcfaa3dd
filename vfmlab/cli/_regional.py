"""``vfmlab identify --regions N|auto|legendre:K``: the printout of a regional outcome (:mod:`vfmlab.stages.identify`)."""

from __future__ import annotations

from vfmlab.cli._common import console, display_quantity, esc, num, print_json


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


def _print_choice(choice) -> None:
    rows = ", ".join(f"{k}: {c:.3g}" for k, c in zip(choice.candidates, choice.criterion))
    console.print(f"--regions auto chose {choice.n_bands} band(s): the least misfit of a step profile to the "
                  f"{choice.candidates[-1]}-band profile in its uncertainty, plus 2 per band (Akaike; per band count: "
                  f"{rows})")


def print_regional(outcome, as_json: bool) -> None:
    """Print a stored regional result (``--regions``): JSON, or the table and its notes."""
    if as_json:
        print_json(outcome.to_dict())
        return
    result, data, model_units = outcome.result, outcome.data, outcome.units
    if data.get("choice") is not None:
        _print_choice(data["choice"])
    console.print(_table(result, model_units))
    for n, v in result.parameters.items():
        val, unit = display_quantity(v, model_units[n])
        console.print(f"shared {esc(n)} = {num(val, 4)} {unit or ''}".rstrip())
    hom = result.homogeneous.parameters
    for n in result.regional:
        val, unit = display_quantity(hom[n], model_units[n])
        console.print(f"homogeneous fit for comparison: {esc(n)} = {num(val, 4)} {unit or ''}".rstrip())
    console.print("positions: reference axial coordinate from the mean marker position, towards the load cell; "
                  f"errors: {result.uncertainty}; * = differs from the median band")
    for note in data["notes"]:
        console.print(f"[dim]{esc(note)}[/]")
    for flag in result.flags:
        console.print(f"[yellow]warning:[/] {esc(flag)}")
    console.print(f"stored as {esc(outcome.group)}")
