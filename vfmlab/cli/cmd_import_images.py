"""``vfmlab import-images``: build a session from marker images taken with another rig."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np
from rich.progress import Progress

from vfmlab.cli._common import CliError, CliInputError, console, err_console, esc, print_json
from vfmlab.cli._outputs import check_output_path
from vfmlab.stages.errors import StageError
from vfmlab.stages.imports import first_images, read_image, scan_images
from vfmlab.stages.reconstruct import load_calibration_file

def _measure_tube(first: dict, cams: list, marker_diameter_mm: float, polarity: str, radius_mm, length_mm,
                  notes: list) -> tuple[float, float]:
    """Radius and length (mm) not given, measured from the step-0 markers (a tube, or an error); says so in ``notes``."""
    from reconstruction import ReconstructionSettings, fit_cylinder, reconstruct_step

    settings = ReconstructionSettings(marker_diameter=marker_diameter_mm * 1e-3, detection={"polarity": polarity})
    pts, _ = reconstruct_step(first, cams, settings)
    if pts.centres.shape[0] < 8:
        raise CliInputError("could not measure the specimen from the step-0 images (fewer than 8 markers "
                            "reconstructed); give --radius-mm and --length-mm")
    cyl = fit_cylinder(pts.centres)
    _check_tube(cyl, pts.centres)
    _, _, z = cyl.cylindrical(pts.centres)
    if radius_mm is None:
        radius_mm = (cyl.radius - 0.5 * marker_diameter_mm * 1e-3) * 1e3
        notes.append(f"radius measured from step-0 markers ({pts.centres.shape[0]} markers)")
    if length_mm is None:
        length_mm = float(np.ptp(z)) * 1e3
        notes.append("length = axial extent of the step-0 markers")
    return radius_mm, length_mm


def _check_tube(cyl, centres: np.ndarray) -> None:
    """The specimen's radius and length are measured assuming the step-0 markers lie on a tube: refuse when they do not."""
    extent = float(np.ptp(centres, axis=0).max())
    if not (cyl.rms < 0.1 * cyl.radius and cyl.radius < 2.0 * extent):
        raise CliError(
            f"the {centres.shape[0]} step-0 markers do not lie on a tube (cylinder fit: radius {cyl.radius * 1e3:.3g} mm, "
            f"RMS {cyl.rms * 1e3:.3g} mm, markers spread over {extent * 1e3:.3g} mm): the specimen's radius and length "
            "are measured assuming a tubular specimen; give --radius-mm and --length-mm"
        )


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
    from acquisition.session import CameraSpec, SessionError, SessionWriter, SpecimenInfo, StepRecord, write_result
    from reconstruction import cameras_to_arrays

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
        radius_mm, length_mm = _measure_tube(first, cams, marker_diameter_mm, polarity, radius_mm, length_mm,
                                             notes_extra)
    if thickness_mm is None:
        thickness_mm = 0.1 * radius_mm
        notes_extra.append("thickness not given: 10 % of the radius assumed")
    try:
        specimen = SpecimenInfo(specimen_id or images_dir.name, radius_mm * 1e-3, length_mm * 1e-3,
                                thickness_mm * 1e-3, "; ".join([notes] * bool(notes) + notes_extra),
                                ends or "", "import option --ends" if ends else "")
    except ValueError as exc:
        raise CliError(str(exc)) from None
    specs = [CameraSpec(c.name, "imported", c.image_size[0], c.image_size[1], dtype) for c in cams]
    rig = {"source": "import-images", "images_dir": str(images_dir), "calibration": str(calibration),
           "loads_csv": str(loads_csv), "marker_diameter_mm": marker_diameter_mm, "marker_polarity": polarity}
    try:
        with SessionWriter.create(out, specimen, cameras=specs, protocol_text="", rig=rig,
                                  load_cell_measures=force_is, overwrite=overwrite) as writer:
            with Progress(console=err_console, transient=True) as progress:
                task = progress.add_task("importing images", total=int(steps.size))
                for s, row in zip(steps, rows):
                    imgs = {}
                    for c in cams:
                        path = files[c.name].get(int(s))
                        if path is None:
                            err_console.print(f"[yellow]Warning:[/] no image of {esc(c.name)} for step {s}; "
                                              "stored blank.")
                            img = np.zeros((c.image_size[1], c.image_size[0]), dtype)
                        else:
                            img = first[c.name] if s == 0 else read_image(path)
                            if img.shape != (c.image_size[1], c.image_size[0]):
                                raise CliInputError(f"{path}: image size {img.shape[::-1]} differs from the calibration")
                        imgs[c.name] = img.astype(dtype, copy=False)
                    writer.add_step(StepRecord(
                        block=0, stretch=float(loads["stretch"][row]), target_pressure=float(loads["pressure"][row]),
                        pressure=float(loads["pressure"][row]), force=float(loads["axial_force"][row]),
                        t_monotonic=float("nan"), t_wall=float("nan")), images=imgs)
                    progress.advance(task)
        name = write_result(out, "calibration", cameras_to_arrays(cams), {"source": str(calibration)})
    except StageError:  # an unreadable image: bad input (exit 2), not a failed write
        raise
    except (SessionError, ValueError) as exc:
        raise CliError(str(exc)) from None
    if as_json:
        print_json({"out": str(out), "n_steps": int(steps.size), "cameras": [c.name for c in cams],
                    "calibration_result": name, "radius_m": radius_mm * 1e-3, "length_m": length_mm * 1e-3,
                    "thickness_m": thickness_mm * 1e-3})
        return
    console.print(
        f"Imported {steps.size} steps × {len(cams)} cameras into [bold]{esc(out)}[/] (calibration stored as "
        f"{esc(name)}; radius {radius_mm:.3f} mm, length {length_mm:.3f} mm, wall thickness {thickness_mm:.3f} mm). "
        f"Next: vfmlab reconstruct {esc(out)}"
    )
