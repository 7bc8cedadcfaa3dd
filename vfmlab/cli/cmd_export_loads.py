"""``vfmlab export-loads``: write a session's step loads as the CSV import-markers reads; the stage is
:func:`vfmlab.stages.loads.export_loads`."""

from __future__ import annotations

import click

from vfmlab.cli._common import console, esc, print_json
from vfmlab.cli._outputs import check_output_path

EPILOG = """
\b
Examples:
  vfmlab export-loads a1.h5 -o a1-loads.csv
  vfmlab export-markers a1.h5 -o m.csv && vfmlab export-loads a1.h5 -o l.csv
  vfmlab import-markers m.csv l.csv --thickness-mm 1.3 -o copy.h5      # the same identification
"""


@click.command("export-loads", epilog=EPILOG)
@click.argument("session", type=click.Path(dir_okay=False))
@click.option("-o", "--out", required=True, type=click.Path(dir_okay=False), help="CSV file to write.")
@click.option("--result", default=None,
              help="Number the steps as export-markers does for this markers result (e.g. markers_002) "
                   "[default: latest].")
@click.option("--force", is_flag=True, help="Overwrite OUT if it exists (never a session file).")
@click.option("--json", "as_json", is_flag=True, help="Print what was written as JSON.")
def command(session, out, result, force, as_json):
    """Write the loads of SESSION, one row per step, as step,pressure_Pa,axial_force_N,stretch (SI, full
    precision): the loads file 'vfmlab import-markers' reads, with the step numbers 'vfmlab export-markers'
    writes."""
    from vfmlab.stages.loads import export_loads

    check_output_path(out, force=force, inputs=[session])
    o = export_loads(session, out, markers_name=result)
    if as_json:
        print_json(o.to_dict())
        return
    numbers = f"; step numbers of {esc(o.markers_result)}" if o.markers_result else ""
    console.print(f"Wrote the loads of {o.n_steps} steps to {esc(out)} (pressure in Pa, axial force in N{numbers}); "
                  f"import with --force-is {esc(o.load_cell_measures)} (what the load cell measures).")
