"""``vfmlab identify``: constitutive parameters from a session's marker tracks (Virtual Fields Method); the
stage is :mod:`vfmlab.stages.identify`, this module parses the options and prints the outcome."""

from __future__ import annotations

import importlib

import click

from vfmlab.cli._common import ModelChoice, display_quantity, esc, num, print_json

WALL_NOTE = {
    "membrane": "paper's plain membrane form (pressure on the marker surface)",
    "thick": "thick wall: markers on the outer surface, pressure on the lumen, layered divergence-free fields",
}


EPILOG = """
\b
Examples:
  vfmlab identify a1.h5                                   # Fung; ends, wall: stated or judged by the data
  vfmlab identify a1.h5 --model hgo --wall membrane --ends free --smooth 4,2
  vfmlab identify a1.h5 --model delfino --json > delfino.json
  vfmlab identify a1.h5 --regions 4                       # beta per axial band (where is the wall weaker?)
  vfmlab identify a1.h5 --regions auto                    # band count chosen from the data
  vfmlab identify a1.h5 --regions legendre:4              # smooth profile of log beta along the axis
"""


@click.command(name="identify", epilog=EPILOG)
@click.argument("session_path", metavar="SESSION", type=click.Path(exists=True, dir_okay=False))
@click.option("--model", type=ModelChoice(), default="fung",
              show_default=True, help="Constitutive model.")
@click.option("--wall", type=click.Choice(["membrane", "thick"]), default=None,
              help="thick: markers on the outer surface, pressure on the lumen; membrane: the paper's plain form. "
                   "Default: thick unless the data say membrane (both fitted and judged against the noise).")
@click.option("--ends", type=click.Choice(["clamped", "free"]), default=None,
              help="clamped: tube tied on cannulae beyond the markers (pressure on the unmeasured strip counted); "
                   "free: uniform tube up to the load cell. Default: what the session records, else the data decide "
                   "(the verdict is 'doubtful' when they cannot tell); a value against the session's record is "
                   "used with a warning.")
@click.option("--optimizer", type=click.Choice(["lsq", "nelder-mead"]), default="lsq", show_default=True,
              help="lsq: fast least squares with several starts; nelder-mead: the paper's simplex.")
@click.option("--smooth", default="auto", show_default=True, metavar="auto|none|AXIAL,HARMONICS",
              help="Smooth the measured displacements before differentiating. auto: the basis (Legendre degree "
                   "along the axis, Fourier harmonics around) of each displacement component chosen from the data "
                   "by cross-validation, no smoothing when the markers look exact; none: raw markers; e.g. 4,2: "
                   "that basis.")
@click.option("--uncertainty", type=click.Choice(["bootstrap", "gauss-newton"]), default="bootstrap",
              show_default=True, help="bootstrap: standard errors and 95 % intervals from re-simulated measurements "
                                      "(a few seconds); gauss-newton: instant, but too small on noisy markers.")
@click.option("--weighting", type=click.Choice(["paper", "noise"]), default="paper", show_default=True,
              help="paper: the paper's cost, one scale per field; noise: each virtual-work gap weighted by the "
                   "inverse of its noise under re-simulated marker noise (smoothed data, lsq): halves the errors "
                   "on independent marker noise, but widens the intervals on sessions with systematic errors.")
@click.option("--regions", default=None, metavar="N|auto|legendre:K",
              help="Identify the stress-like parameter (beta) along the axis, the others shared: per band of N equal "
                   "axial bands (1-12), with the band count chosen from the data (auto: 1-6 bands), or as a smooth "
                   "profile of K Legendre coefficients of log beta (legendre:K, 1-8); with standard errors and 95 % "
                   "intervals (--uncertainty) and the bands that differ; stored as a 'regional' result.")
@click.option("--json", "as_json", is_flag=True,
              help="Print the result as JSON for scripts (SI; the unit of each parameter under 'units').")
def command(session_path, model, wall, ends, optimizer, smooth, uncertainty, weighting, regions, as_json):
    """Identify MODEL parameters from the latest marker tracks of SESSION and store the result in it.

    Units: parameters in SI (Pa, rad); the table shows kPa and degrees.
    """
    from vfmlab.cli._startup import modules_loading

    with modules_loading() as loaded:  # no garbage collection over the modules being loaded (~35 ms)
        from acquisition.session import start_preflight

        start_preflight(session_path)  # the damaged-file check runs on the other core while the modules load
        for module in ("identification", "vfmlab.pipeline"):  # scipy and the rest, loaded under the pause
            importlib.import_module(module)

        loaded()
        return _identify(session_path, as_json, model=model, wall=wall, ends=ends, optimizer=optimizer, smooth=smooth,
                         uncertainty=uncertainty, weighting=weighting, regions=regions)


def _identify(session_path, as_json, **options):
    """The command's work once its modules are loaded: identify, store, print."""
    from vfmlab.stages.identify import RegionalOutcome, identify
    from vfmlab.stages.settings import IdentifySettings

    from vfmlab.cli._feedback import progress_bar
    from vfmlab.stages.feedback import no_progress

    outcome = identify(session_path, IdentifySettings(**options), invoked_by="identify",
                       progress=no_progress if as_json else progress_bar)
    if isinstance(outcome, RegionalOutcome):
        from vfmlab.cli._regional import print_regional

        return print_regional(outcome, as_json)
    if as_json:
        print_json(outcome.to_dict())
        return
    _print(outcome)


def _print(outcome) -> None:
    from rich.table import Table

    from vfmlab.cli._common import console  # rich: only for the table (not for --json)
    from vfmlab.stages.identify import verdict_lines

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
    console.print(table)
    for line in verdict_lines(result.verdict, result.verdict_reasons, result.parameter_verdicts,
                              result.parameter_reasons):
        console.print(esc(line), style="bold yellow" if "doubtful" in line else None)
    console.print(f"cost {num(result.cost, 3)}, RMS gap per field "
                  + ", ".join(f"{esc(f)}: {g:.2%}" for f, g in zip(result.field_names, result.residual_per_field))
                  + f", {result.n_evaluations} evaluations, converged: {result.converged}")
    for note in outcome.data["notes"]:
        console.print(f"[dim]{esc(note)}[/]")
    for flag in result.flags:
        console.print(f"[yellow]warning:[/] {esc(flag)}")
    console.print(f"stored as {esc(outcome.group)}")

