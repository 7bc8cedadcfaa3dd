"""``vfmlab import-markers``: a session from marker positions measured elsewhere (the stage:
:mod:`vfmlab.stages.import_points`); also the specimen options and the printed outcome ``import-dic`` shares."""

from __future__ import annotations

from pathlib import Path

import click

from vfmlab.cli._common import console, esc, print_json, show_warning
from vfmlab.cli._outputs import check_output_path

EPILOG = """
\b
Examples:
  vfmlab import-markers markers.csv loads.csv --thickness-mm 1.3 -o a1.h5
  vfmlab import-markers markers.csv loads.csv --thickness-mm 1.3 --radius-mm 10 --force-is total -o a1.h5
Then: vfmlab identify a1.h5
"""

_OPTIONS = (
    click.option("-o", "--out", "out", required=True, type=click.Path(dir_okay=False), help="Session file to create."),
    click.option("--thickness-mm", type=float, required=True, help="Reference wall thickness, mm."),
    click.option("--radius-mm", type=float, help="Reference radius of the marker surface, mm [default: fitted to step 0]."),
    click.option("--length-mm", type=float, help="Reference specimen length, mm [default: axial extent of the markers]."),
    click.option("--specimen-id", default=None, help="Specimen identifier [default: the markers file name]."),
    click.option("--notes", default="", help="Free-text notes about the specimen."),
    click.option("--force-is", type=click.Choice(["wall", "total"]), default="wall", show_default=True,
                 help="What axial_force_N is: force carried by the wall, or a total reading behind a pressurised cannula."),
    click.option("--ends", type=click.Choice(["clamped", "free"]), default=None,
                 help="How the specimen was held: clamped (tied on cannulae) or free (uniform up to the load cell); "
                      "recorded in the session for 'vfmlab identify' [default: not recorded; identify then lets the "
                      "data decide and says whether they could]."),
    click.option("--force", "overwrite", is_flag=True, help="Overwrite OUT if it exists."),
    click.option("--json", "as_json", is_flag=True, help="Print what was imported as JSON (SI: m)."),
)


def specimen_options(func):
    """Add -o and the specimen options (in the order of ``--help``) to a command."""
    for option in reversed(_OPTIONS):
        func = option(func)
    return func


def print_imported(out, done, as_json: bool) -> None:
    """What was imported (a ``vfmlab.stages.import_points.ImportedPoints``): one sentence, or ``--json``."""
    if as_json:
        print_json(done.summary(out))
    else:
        console.print(f"Imported {done.n_markers} markers × {done.n_steps} steps into [bold]{esc(out)}[/] "
                      f"({esc(done.details())}).")


@click.command("import-markers", epilog=EPILOG)
@click.argument("markers_csv", type=click.Path(dir_okay=False))
@click.argument("loads_csv", type=click.Path(dir_okay=False))
@specimen_options
def command(markers_csv, loads_csv, out, as_json, **options):
    """Build a session from MARKERS_CSV (marker_id,step,x_m,y_m,z_m or x_mm,y_mm,z_mm) and LOADS_CSV
    (step,pressure_Pa|pressure_kPa|pressure_mmHg,axial_force_N,stretch). Step 0 is the reference."""
    from vfmlab.stages.import_points import PointImportSettings, import_markers

    check_output_path(out, force=options["overwrite"], inputs=[markers_csv, loads_csv])
    s = PointImportSettings.from_options(options, Path(markers_csv).stem)
    print_imported(out, import_markers(markers_csv, loads_csv, out, s, warn=show_warning), as_json)
