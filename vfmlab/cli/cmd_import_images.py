"""``vfmlab import-images``: build a session from marker images taken with another rig."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np
from rich.progress import Progress

from vfmlab.cli._common import CliError, CliInputError, console, err_console, esc, print_json
from vfmlab.cli._outputs import check_output_path
from vfmlab.stages.errors import StageError
from vfmlab.stages.imports import FoundImages, first_images, measure_tube, mm_to_m, scan_images, write_imported_session
from vfmlab.stages.reconstruct import load_calibration_file

EPILOG = """
\b
Examples:
  vfmlab import-images images/ --calibration calibration.toml --loads loads.csv --marker-diameter-mm 0.4 -o a1.h5
  vfmlab import-images images/ --calibration cams.yaml --calibration-units m --loads loads.csv \\
      --marker-diameter-mm 0.4 --thickness-mm 1.3 -o a1.h5
Then: vfmlab reconstruct a1.h5
"""


@click.command("import-images", epilog=EPILOG)
@click.argument("images_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--calibration", required=True, type=click.Path(path_type=Path),
              help="Calibration of the cameras: aniposelib calibration.toml, OpenCV .yaml, or an OpenPTV folder "
                   "(cameras looking through a glass/water window).")
@click.option("--polarity", type=click.Choice(["dark", "bright"]), default="dark", show_default=True,
              help="Markers darker than their background (dark markers on tissue) or brighter (particles, "
                   "retro-reflective markers).")
@click.option("--calibration-units", type=click.Choice(["mm", "m", "cm", "um"]), default=None,
              help="Length unit of the calibration when the file does not say [default: mm].")
@click.option("--loads", "loads_csv", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="CSV: step,pressure_Pa|pressure_kPa|pressure_mmHg,axial_force_N,stretch (as import-markers).")
@click.option("-o", "--out", "out", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="Session file to create.")
@click.option("--marker-diameter-mm", type=float, required=True, help="Diameter of the spherical markers, mm.")
@click.option("--thickness-mm", type=float, default=None,
              help="Reference wall thickness, mm [default: 10 % of the radius, flagged in the notes].")
@click.option("--radius-mm", type=float, default=None,
              help="Reference outer radius, mm [default: measured from the step-0 images].")
@click.option("--length-mm", type=float, default=None,
              help="Reference length, mm [default: axial extent of the markers in step 0].")
@click.option("--specimen-id", default=None, help="Specimen identifier [default: the images folder name].")
@click.option("--notes", default="", help="Free-text notes about the specimen.")
@click.option("--force-is", type=click.Choice(["wall", "total"]), default="wall", show_default=True,
              help="What axial_force_N is: force carried by the wall, or a total reading behind a pressurised cannula.")
@click.option("--ends", type=click.Choice(["clamped", "free"]), default=None,
              help="How the specimen was held: clamped (tied on cannulae) or free (uniform up to the load cell); "
                   "recorded in the session for 'vfmlab identify' [default: not recorded; identify then lets the "
                   "data decide and says whether they could].")
@click.option("--force", "overwrite", is_flag=True, help="Overwrite OUT if it exists.")
@click.option("--json", "as_json", is_flag=True, help="Print what was imported as JSON (SI: m).")
def command(images_dir, calibration, polarity, calibration_units, loads_csv, out, marker_diameter_mm, thickness_mm,
            radius_mm, length_mm, specimen_id, notes, force_is, ends, overwrite, as_json):
    """Build a session from IMAGES_DIR/<camera>/<step>.png (camera names as in the calibration file,
    step 0 = reference), the camera calibration and a loads CSV. Then run 'vfmlab reconstruct OUT'."""
    from acquisition.markers_csv import read_loads_csv
    from acquisition.session import SessionError, SpecimenInfo

    check_output_path(out, force=overwrite, inputs=[calibration, loads_csv])
    if not marker_diameter_mm > 0:
        raise CliInputError(f"--marker-diameter-mm must be positive; got {marker_diameter_mm}")
    for name, value in (("--thickness-mm", thickness_mm), ("--radius-mm", radius_mm), ("--length-mm", length_mm)):
        if value is not None and not value > 0:
            raise CliInputError(f"{name} must be positive; got {value}")
    cams = load_calibration_file(calibration, calibration_units)
    names = [c.name for c in cams]
    steps, files = scan_images(images_dir, names)
    loads = read_loads_csv(loads_csv)
    missing = sorted(set(steps.tolist()) - set(loads["step"].tolist()))
    if missing:
        raise CliInputError(f"{loads_csv}: no loads for step(s) {missing} that have images in {images_dir}")
    rows = np.searchsorted(loads["step"], steps)
    first, dtype = first_images(cams, files)
    notes_extra = []
    if radius_mm is None or length_mm is None:
        radius_mm, length_mm = measure_tube(first, cams, marker_diameter_mm, polarity, radius_mm, length_mm,
                                             notes_extra)
    if thickness_mm is None:
        thickness_mm = 0.1 * radius_mm
        notes_extra.append("thickness not given: 10 % of the radius assumed")
    try:
        specimen = SpecimenInfo(specimen_id or images_dir.name, mm_to_m(radius_mm), mm_to_m(length_mm),
                                mm_to_m(thickness_mm), "; ".join([notes] * bool(notes) + notes_extra),
                                ends or "", "import option --ends" if ends else "")
    except ValueError as exc:
        raise CliError(str(exc)) from None
    rig = {"source": "import-images", "images_dir": str(images_dir), "calibration": str(calibration),
           "loads_csv": str(loads_csv), "marker_diameter_mm": marker_diameter_mm, "marker_polarity": polarity}
    found = FoundImages(cams, steps, rows, files, first, dtype)
    try:
        with Progress(console=err_console, transient=True) as progress:
            task = progress.add_task("importing images", total=int(steps.size))
            name = write_imported_session(out, specimen, found, loads, rig, str(calibration), force_is, overwrite,
                                          warn=lambda text: err_console.print(f"[yellow]Warning:[/] {esc(text)}"),
                                          advance=lambda: progress.advance(task))
    except StageError:  # an unreadable image: bad input (exit 2), not a failed write
        raise
    except (SessionError, ValueError) as exc:
        raise CliError(str(exc)) from None
    if as_json:
        print_json({"out": str(out), "n_steps": int(steps.size), "cameras": [c.name for c in cams],
                    "calibration_result": name, "radius_m": mm_to_m(radius_mm), "length_m": mm_to_m(length_mm),
                    "thickness_m": mm_to_m(thickness_mm)})
        return
    console.print(
        f"Imported {steps.size} steps × {len(cams)} cameras into [bold]{esc(out)}[/] (calibration stored as "
        f"{esc(name)}; radius {radius_mm:.3f} mm, length {length_mm:.3f} mm, wall thickness {thickness_mm:.3f} mm). "
        f"Next: vfmlab reconstruct {esc(out)}"
    )
