"""``vfmlab import-markers``: build a session from marker positions measured elsewhere."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np
from acquisition.markers_csv import read_loads_csv, read_markers_csv
from acquisition.session import SessionError, SessionWriter, SpecimenInfo, StepRecord, import_failure, staged_session
from vfmlab.cli._common import CliError, CliInputError, console, esc, print_json, show_warning
from vfmlab.cli._outputs import check_output_path
from vfmlab.stages.imports import check_marker_inputs, mm_to_m


EPILOG = """
\b
Examples:
  vfmlab import-markers markers.csv loads.csv --thickness-mm 1.3 -o a1.h5
  vfmlab import-markers markers.csv loads.csv --thickness-mm 1.3 --radius-mm 10 --force-is total -o a1.h5
Then: vfmlab identify a1.h5
"""


@click.command("import-markers", epilog=EPILOG)
@click.argument("markers_csv", type=click.Path(dir_okay=False))
@click.argument("loads_csv", type=click.Path(dir_okay=False))
@click.option("-o", "--out", "out", required=True, type=click.Path(dir_okay=False), help="Session file to create.")
@click.option("--thickness-mm", type=float, required=True, help="Reference wall thickness, mm.")
@click.option("--radius-mm", type=float, help="Reference radius of the marker surface, mm [default: fitted to step 0].")
@click.option("--length-mm", type=float, help="Reference specimen length, mm [default: axial extent of the markers].")
@click.option("--specimen-id", default=None, help="Specimen identifier [default: the markers file name].")
@click.option("--notes", default="", help="Free-text notes about the specimen.")
@click.option("--force-is", type=click.Choice(["wall", "total"]), default="wall", show_default=True,
              help="What axial_force_N is: force carried by the wall, or a total reading behind a pressurised cannula.")
@click.option("--ends", type=click.Choice(["clamped", "free"]), default=None,
              help="How the specimen was held: clamped (tied on cannulae) or free (uniform up to the load cell); "
                   "recorded in the session for 'vfmlab identify' [default: not recorded; identify then lets the "
                   "data decide and says whether they could].")
@click.option("--force", "overwrite", is_flag=True, help="Overwrite OUT if it exists.")
@click.option("--json", "as_json", is_flag=True, help="Print what was imported as JSON (SI: m).")
def command(markers_csv, loads_csv, out, thickness_mm, radius_mm, length_mm, specimen_id, notes, force_is, ends,
            overwrite, as_json):
    """Build a session from MARKERS_CSV (marker_id,step,x_m,y_m,z_m or x_mm,y_mm,z_mm) and LOADS_CSV
    (step,pressure_Pa|pressure_kPa|pressure_mmHg,axial_force_N,stretch). Step 0 is the reference."""
    check_output_path(out, force=overwrite, inputs=[markers_csv, loads_csv])
    table = read_markers_csv(markers_csv)
    loads = read_loads_csv(loads_csv)
    missing = sorted(set(table.steps.tolist()) - set(loads["step"].tolist()))
    if missing:
        raise CliInputError(f"{loads_csv}: no loads for step(s) {missing} that appear in {markers_csv}")
    rows = np.searchsorted(loads["step"], table.steps)
    radius, length, warnings = check_marker_inputs(table, loads, rows, markers_csv, loads_csv, thickness_mm,
                                                   radius_mm, length_mm, show_warning)
    try:
        specimen = SpecimenInfo(specimen_id or Path(markers_csv).stem, radius, length, mm_to_m(thickness_mm), notes,
                                ends or "", "import option --ends" if ends else "")
    except ValueError as exc:
        raise CliInputError(str(exc)) from None
    rig = {"source": "import-markers", "markers_csv": str(markers_csv), "loads_csv": str(loads_csv)}
    try:  # built under a temporary name and renamed onto OUT at the end: all or nothing
        with staged_session(out, overwrite=overwrite) as staged:
            with SessionWriter.create(staged.path, specimen, protocol_text="", rig=rig,
                                      load_cell_measures=force_is) as writer:
                for message in warnings:
                    writer.add_event("warning", message)
                for row in rows:
                    writer.add_step(StepRecord(
                        block=0, stretch=float(loads["stretch"][row]),
                        target_pressure=float(loads["pressure"][row]), pressure=float(loads["pressure"][row]),
                        force=float(loads["axial_force"][row]), t_monotonic=float("nan"), t_wall=float("nan")))
            visible = ~np.isnan(table.positions).any(axis=2)
            name = staged.add_result(
                "markers",
                {"positions": table.positions, "visible": visible,
                 "uncertainty": np.full(visible.shape, np.nan), "marker_id": np.arange(len(table.labels)),
                 "marker_label": table.labels, "step_index": np.arange(len(table.steps)),
                 "step_number": table.steps},
                {"source": "import-markers", "markers_csv": str(markers_csv)},
                units={"positions": "m", "uncertainty": "m"},
            )
    except SessionError as exc:
        raise CliError(str(exc)) from None
    except OSError as exc:
        raise CliError(import_failure(out, exc)) from None
    if as_json:
        print_json({"out": str(out), "result": name, "n_markers": len(table.labels), "n_steps": len(table.steps),
                    "radius_m": radius, "length_m": length, "thickness_m": mm_to_m(thickness_mm),
                    "load_cell_measures": force_is, "ends": ends})
        return
    console.print(
        f"Imported {len(table.labels)} markers × {len(table.steps)} steps into [bold]{esc(out)}[/] "
        f"(result {esc(name)}; radius {radius * 1e3:.3f} mm, length {length * 1e3:.3f} mm, "
        f"wall thickness {thickness_mm:.3f} mm, load cell measures {force_is} force, "
        + (f"ends {ends})." if ends else "ends not recorded: identify lets the data decide unless --ends says).")
    )
