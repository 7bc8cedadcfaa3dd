"""``vfmlab identify``: constitutive parameters from a session's marker tracks (Virtual Fields Method); the
stage is :mod:`vfmlab.stages.identify`, this module parses the options and prints the outcome."""

from __future__ import annotations

import importlib

import click

from vfmlab.cli._common import ModelChoice, print_json



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
@click.option("--uncertainty", type=click.Choice(["auto", "gls", "bootstrap", "gauss-newton"]), default="auto",
              show_default=True, help="auto: gls for the efficient weighting, bootstrap for the others; gls: standard "
                                      "errors and 95 % intervals from the efficient fit's own covariance (instant); "
                                      "bootstrap: from re-simulated measurements (a few seconds); gauss-newton: "
                                      "instant, but too small on noisy markers.")
@click.option("--weighting", type=click.Choice(["efficient", "paper", "noise"]), default="efficient",
              show_default=True,
              help="efficient: generalised least squares over the full noise covariance of the virtual-work gaps "
                   "(markers, the shared reference step, the readings): smaller errors than the paper's cost in every "
                   "case measured, up to 3x; "
                   "paper: the paper's cost, one scale per field; noise: each gap weighted by the inverse of its "
                   "noise under re-simulated marker noise. The weightings need smoothed data and lsq.")
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
        if as_json:
            print_json(outcome.to_dict())
            return
        from vfmlab.cli._common import console
        from vfmlab.views.identify import regional_lines

        for line in regional_lines(outcome):
            console.print(line)
        return
    if as_json:
        print_json(outcome.to_dict())
        return
    from vfmlab.cli._common import console  # rich: only for the table (not for --json)
    from vfmlab.views.identify import identify_lines

    for line, style in identify_lines(outcome):
        console.print(line, style=style)
