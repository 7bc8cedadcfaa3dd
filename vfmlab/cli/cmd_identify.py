"""``vfmlab identify``: constitutive parameters from a session's marker tracks (Virtual Fields Method)."""

from __future__ import annotations

import click
import numpy as np

from vfmlab.cli._common import CliError, console, print_json

WALL_NOTE = {
    "membrane": "paper's plain membrane form (pressure on the marker surface)",
    "thick": "thick wall: markers on the outer surface, pressure on the lumen, layered divergence-free fields",
}


def load_session_data(session) -> dict:
    """Positions, pressure and wall force of the steps used by the latest markers result.

    Returns a dict with positions (n_steps, n_markers, 3) m, pressure (n_steps,) Pa, force (n_steps,) N
    (wall force), thickness m, and notes (list of str) about corrections applied.
    """
    from vfmlab.cli._sessions import latest_markers

    markers = latest_markers(session)
    arrays = markers["arrays"]
    if "positions" not in arrays:
        raise CliError(f"{session.path}: the markers result {markers['name']} has no 'positions' array")
    positions = np.asarray(arrays["positions"], dtype=float)
    if "visible" in arrays:
        positions = np.where(np.asarray(arrays["visible"], bool)[..., None], positions, np.nan)
    steps = session.steps
    rows = np.asarray(arrays["step_index"], int) if "step_index" in arrays else np.arange(positions.shape[0])
    if rows.size != positions.shape[0] or (rows.size and (rows.max() >= session.n_steps or rows.min() < 0)):
        raise CliError(f"{session.path}: markers result {markers['name']} refers to steps {rows.tolist()} but the "
                       f"session has {session.n_steps} steps")
    pressure = np.asarray(steps["pressure"], float)[rows]
    force = np.asarray(steps["force"], float)[rows]
    specimen = session.specimen
    notes = []
    if session.load_cell_measures == "total":
        # docs/decisions/0003: F_wall = F_total + p pi r_i^2, r_i = lumen radius at the cannula, which we take
        # as the reference inner radius (specimen radius - thickness): the cannula fixes the lumen there.
        r_i = specimen.radius - specimen.thickness
        force = force + pressure * np.pi * r_i**2
        notes.append(f"load cell measures total force: wall force = total + p*pi*r_i^2 with r_i = {r_i * 1e3:.3f} mm")
    return {"positions": positions, "pressure": pressure, "force": force, "thickness": float(specimen.thickness),
            "markers_result": markers["name"], "rows": rows, "notes": notes}


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
    from acquisition.session import SessionError, write_result
    from identification import IdentificationError, identify
    from vfmlab.cli._sessions import cli_session

    smoothing = None
    if smooth == "auto":
        smoothing = "auto"
    elif smooth:
        try:
            smoothing = tuple(int(v) for v in smooth.split(","))
            if len(smoothing) != 2 or min(smoothing) < 0:
                raise ValueError
        except ValueError:
            raise CliError(f"--smooth must be two non-negative integers AXIAL,HARMONICS like 4,2; got {smooth!r}")
    with cli_session(session_path) as session:
        data = load_session_data(session)
    try:
        result = identify(data["positions"], data["pressure"], data["force"], thickness=data["thickness"],
                          model=model, wall=wall, ends=ends, optimizer=optimizer, smoothing=smoothing)
    except IdentificationError as exc:
        raise CliError(f"{session_path}: cannot identify: {exc}") from None
    names = list(result.parameters)
    arrays = {
        "parameters": np.array([result.parameters[n] for n in names]),
        "stderr": np.array([result.stderr[n] for n in names]),
        "parameter_names": np.array(names, dtype=object).astype(str),
        "correlation": result.correlation,
        "ivw": result.ivw,
        "evw": result.evw,
        "residuals": result.residuals,
        "step_index": data["rows"],
    }
    settings = {"model": model, "wall": wall, "ends": ends, "optimizer": optimizer, "smoothing": smoothing,
                "markers_result": data["markers_result"], "thickness": data["thickness"],
                "force_correction": data["notes"]}
    attrs = {"model": model, "wall": wall, "cost": result.cost, "converged": result.converged,
             "flags": list(result.flags), "message": result.message, "n_evaluations": result.n_evaluations,
             "field_names": list(result.field_names)}
    try:
        group = write_result(session_path, "identification", arrays, settings, attrs=attrs,
                             units={"ivw": "J", "evw": "J", "residuals": "1"})
    except SessionError as exc:
        raise CliError(str(exc)) from None
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
