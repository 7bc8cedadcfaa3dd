"""``vfmlab import-dic``: a session from another lab's DIC points (the stage: :mod:`vfmlab.stages.import_points`)."""

from __future__ import annotations

from pathlib import Path

import click

from vfmlab.cli._common import show_warning
from vfmlab.cli._outputs import check_output_path
from vfmlab.cli.cmd_import_markers import print_imported, specimen_options

EPILOG = """
\b
Examples:
  vfmlab import-dic DIC3Dstereo.mat --format duodic --loads loads.csv --thickness-mm 1.3 -o a1.h5
  vfmlab import-dic exports/ --format vic3d --loads loads.csv --thickness-mm 1.3 -o a1.h5
  vfmlab import-dic p.csv --format table --columns id=pt,step=frame,x=X,y=Y,z=Z --loads loads.csv --thickness-mm 1.3 -o a1.h5
Formats and conventions: docs/guide/other-labs-dic.md
"""


@click.command("import-dic", epilog=EPILOG)
@click.argument("paths", nargs=-1, required=True, type=click.Path(exists=True, path_type=Path))
@click.option("--format", "fmt", required=True, type=click.Choice(["duodic", "multidic", "vic3d", "table"]),
              help="DuoDIC DIC3Dstereo.mat, MultiDIC DIC3DPPresults.mat, VIC-3D CSV exports (one per step, in step "
                   "order, or their folder), or a CSV/NPZ table mapped by --columns.")
@click.option("--columns", help="With --format table: ROLE=COLUMN for id, step, x, y, z (and quality).")
@click.option("--unit", type=click.Choice(["mm", "m", "um"]), default="mm", show_default=True,
              help="Length unit of the points in the files.")
@click.option("--loads", "loads_csv", required=True, type=click.Path(dir_okay=False),
              help="Loads CSV: step,pressure_Pa|pressure_kPa|pressure_mmHg,axial_force_N,stretch.")
@specimen_options
def command(paths, fmt, columns, unit, loads_csv, out, as_json, **options):
    """Build a session from the 3-D points of a DIC result (PATH...) as import-markers does from a marker CSV:
    each DIC point is a marker, NaN where it was not measured. Step 0 is the reference."""
    from vfmlab.stages.import_points import DICSource, PointImportSettings, import_dic

    check_output_path(out, force=options["overwrite"], inputs=[*paths, loads_csv])
    s = PointImportSettings.from_options(options, paths[0].stem)
    print_imported(out, import_dic(DICSource(paths, fmt, columns, unit), loads_csv, out, s, warn=show_warning), as_json)
