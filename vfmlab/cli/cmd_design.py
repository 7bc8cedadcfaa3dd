"""``vfmlab design``: before the test, the 95 % half-width each parameter can reach, and which added steps help."""

from __future__ import annotations

import click

from vfmlab.cli._common import CliInputError, ModelChoice, print_json

EPILOG = """
\b
Examples:
  vfmlab design examples/paper-protocol.toml --specimen examples/specimen.toml
  vfmlab design examples/paper-protocol.toml --specimen examples/specimen.toml --noise-mm 0.05 --markers 1000
  vfmlab design examples/multi-stretch-protocol.toml --specimen examples/specimen.toml --model hgo --json
  vfmlab design examples/paper-protocol.toml --specimen examples/specimen.toml --params beta=8000,alpha12=0.5
"""


@click.command(name="design", epilog=EPILOG)
@click.argument("protocol_path", metavar="PROTOCOL", type=click.Path(exists=True, dir_okay=False))
@click.option("--specimen", "specimen_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Specimen file (radius, thickness, length in mm).")
@click.option("--markers", "n_markers", type=click.IntRange(3, 100_000), default=300, show_default=True,
              help="Number of markers, spread evenly over the circumference and the length.")
@click.option("--noise-mm", type=click.FloatRange(min=0.0, min_open=True), default=0.17, show_default=True,
              help="Standard deviation of each marker coordinate, mm (the paper's accuracy was 0.17 mm).")
@click.option("--model", type=ModelChoice(), default="fung",
              show_default=True, help="Constitutive model.")
@click.option("--params", default=None, metavar="NAME=VALUE,...",
              help="The law to predict at, SI (Pa, rad); unnamed parameters keep the seed paper's Table 1 values.")
@click.option("--wall", type=click.Choice(["membrane", "thick"]), default="membrane", show_default=True,
              help="membrane: the paper's form; thick: markers on the outer surface, pressure on the lumen.")
@click.option("--force-is", "force_is", type=click.Choice(["wall", "total"]), default="wall", show_default=True,
              help="What the load cell reads (decision 0003): the wall force, or the wall force minus the "
                   "pressure end-load.")
@click.option("--json", "as_json", is_flag=True, help="Print the prediction as JSON for scripts (SI keys).")
def command(protocol_path, specimen_path, n_markers, noise_mm, model, params, wall, force_is, as_json):
    """Predict the 95 % half-width each MODEL parameter can reach with PROTOCOL on a specimen.

    The Cramér-Rao bound of a homogeneous tube: every marker's position at every step (the stress-free reference
    included) with --noise-mm, pressure and force with 0.1 % of reading (floors 3 Pa, 2 mN); the radius, the
    stretches, the axis and each marker's material coordinates are estimated too; the reference markers' noise
    is divided by sqrt(N) when the protocol captures the reference N times ([reference] repeats). Also tries a
    second or third axial stretch with the same pressure levels, more markers, and capturing the reference 4
    times, and shows what each would give.
    """
    from acquisition.protocol import ConfigError, load_protocol, load_specimen
    from vfmlab.stages.design import design_report, design_tables, parse_parameters

    try:
        protocol = load_protocol(protocol_path)
        specimen = load_specimen(specimen_path)
        values = parse_parameters(model, params)
        report = design_report(protocol, specimen, model=model, params=values, n_markers=n_markers,
                               noise_m=noise_mm * 1e-3, wall=wall, force_measures=force_is)
    except (ConfigError, ValueError) as exc:
        raise CliInputError(str(exc)) from None
    if as_json:
        print_json(report)
        return
    from vfmlab.cli._common import console

    for item in design_tables(report):
        console.print(item)
