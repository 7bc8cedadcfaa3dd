"""``vfmlab identify``: constitutive parameters from a session's marker tracks (Virtual Fields Method)."""

from __future__ import annotations

import click
import numpy as np

from vfmlab.cli._common import CliInputError, console, print_json

WALL_NOTE = {
    "membrane": "paper's plain membrane form (pressure on the marker surface)",
    "thick": "thick wall: markers on the outer surface, pressure on the lumen, layered divergence-free fields",
}


@click.command(name="identify")
@click.argument("session_path", metavar="SESSION", type=click.Path(exists=True, dir_okay=False))
@click.option("--model", type=click.Choice(["fung", "delfino", "hgo", "neohookean"]), default="fung",
              show_default=True, help="Constitutive model.")
@click.option("--wall", type=click.Choice(["membrane", "thick"]), default="membrane", show_default=True,
              help="membrane: the paper's plain form; thick: markers on the outer surface, pressure on the lumen.")
@click.option("--ends", type=click.Choice(["clamped", "free"]), default="clamped", show_default=True,
              help="clamped: tube tied on cannulae beyond the markers (pressure on the unmeasured strip counted).")
@click.option("--optimizer", type=click.Choice(["lsq", "nelder-mead"]), default="lsq", show_default=True,
              help="lsq: fast least squares with several starts; nelder-mead: the paper's simplex.")
@click.option("--smooth", default=None, metavar="AXIAL,HARMONICS|auto",
              help="Smooth the measured displacements (Legendre degree along the axis, Fourier harmonics around) "
                   "before differentiating; e.g. 4,2 for noisy markers (>~0.02 mm); 'auto' smooths (4,2) only when "
                   "the estimated marker noise exceeds 0.02 mm.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON (SI units) for scripts.")
def command(session_path, model, wall, ends, optimizer, smooth, as_json):
    """Identify MODEL parameters from the latest marker tracks of SESSION and store the result in it.

    Units: parameters in SI (Pa, rad); the table shows kPa and degrees.
    """
    from vfmlab.pipeline import identify_stored

    smoothing = None
    if smooth == "auto":
        smoothing = "auto"
    elif smooth:
        try:
            smoothing = tuple(int(v) for v in smooth.split(","))
            if len(smoothing) != 2 or min(smoothing) < 0:
                raise ValueError
        except ValueError:
            raise CliInputError(f"--smooth must be two non-negative integers AXIAL,HARMONICS like 4,2; got {smooth!r}")
    group, result, data = identify_stored(session_path, model=model, wall=wall, ends=ends, optimizer=optimizer,
                                          smoothing=smoothing, invoked_by="identify")
    names = list(result.parameters)
    if as_json:
        print_json({"model": model, "wall": wall, "parameters": result.parameters, "stderr": result.stderr,
                    "cost": result.cost, "converged": result.converged, "flags": list(result.flags),
                    "result_group": group})
        return
    from rich.table import Table

    table = Table(title=f"{model} ({WALL_NOTE[wall]})")
    table.add_column("parameter")
    table.add_column("value", justify="right")
    table.add_column("std. error", justify="right")
    table.add_column("unit")
    for n in names:
        v, s = result.parameters[n], result.stderr[n]
        unit = get_unit(model, n)
        if unit == "Pa":
            v, s, unit = v / 1e3, s / 1e3, "kPa"
        elif unit == "rad":
            v, s, unit = np.degrees(v), np.degrees(s), "deg"
        table.add_row(n, f"{v:.4g}", f"{s:.2g}", unit)
    console.print(table)
    console.print(f"cost {result.cost:.3g}, RMS gap per field "
                  + ", ".join(f"{f}: {g:.2%}" for f, g in zip(result.field_names, result.residual_per_field))
                  + f", {result.n_evaluations} evaluations, converged: {result.converged}")
    for note in data["notes"]:
        console.print(f"[dim]{note}[/]")
    for flag in result.flags:
        console.print(f"[yellow]warning:[/] {flag}")
    console.print(f"stored as {group}")


def get_unit(model: str, name: str) -> str:
    from identification import get_model

    m = get_model(model)
    return m.units[m.parameter_names.index(name)]
