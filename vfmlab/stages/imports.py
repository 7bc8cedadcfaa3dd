"""Building a session from data measured elsewhere (``vfmlab import-markers``, ``vfmlab import-images``): the
checks of the imported marker cloud and loads, and the reading of an image folder ``DIR/<camera>/<step>.png``."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.errors import ImplausibleInputError
from vfmlab.stages.errors import StageError, StageFailed
from vfmlab.stages.feedback import Notify, log_notes

__all__ = ["FoundImages", "OUTLIER_RADII", "check_marker_inputs", "check_tube", "estimate_geometry", "first_images",
           "marker_outliers", "measure_tube", "mm_to_m", "read_image", "scan_images", "write_imported_session"]


def mm_to_m(value_mm: float) -> float:
    """A length typed in mm, in m, rounded to 12 significant digits: 1.3 mm -> 0.0013 m, not the
    0.0013000000000000002 that ``1.3 * 1e-3`` gives and the session would store."""
    return float(f"{value_mm * 1e-3:.12g}")

_IMAGE_SUFFIXES = {".png", ".tif", ".tiff", ".bmp", ".pgm", ".jpg", ".jpeg"}


def scan_images(images_dir: Path, camera_names: list[str]) -> tuple[np.ndarray, dict[str, dict[int, Path]]]:
    """Step numbers present and ``{camera: {step: path}}`` from ``DIR/<camera>/<step>.<ext>``."""
    if not images_dir.is_dir():
        raise StageError(f"IMAGES_DIR: {images_dir} is not a folder (expected IMAGES_DIR/<camera>/<step>.png)")
    folders = sorted(p.name for p in images_dir.iterdir() if p.is_dir())
    missing = [c for c in camera_names if c not in folders]
    if missing:
        raise StageError(
            f"IMAGES_DIR: no folder for calibrated camera(s) {missing} in {images_dir} "
            f"(found {folders}; folder names must be the camera names of the calibration file)"
        )
    files: dict[str, dict[int, Path]] = {}
    for cam in camera_names:
        files[cam] = {}
        for p in sorted((images_dir / cam).iterdir()):
            if p.suffix.lower() not in _IMAGE_SUFFIXES:
                continue
            try:
                step = int(p.stem)
            except ValueError:
                raise StageError(f"{p}: image names must be step numbers (0.png, 1.png, ...); got {p.name!r}") from None
            if step in files[cam]:
                raise StageError(f"{images_dir / cam}: two images for step {step}")
            files[cam][step] = p
    steps = np.array(sorted(set().union(*[set(f) for f in files.values()])), dtype=int)
    if steps.size == 0:
        raise StageError(f"IMAGES_DIR: no images under {images_dir}/<camera>/ ({', '.join(sorted(_IMAGE_SUFFIXES))})")
    if steps[0] != 0:
        raise StageError(f"IMAGES_DIR: no images for step 0 (the reference configuration); first step is {steps[0]}")
    return steps, files


def read_image(path: Path) -> np.ndarray:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise StageError(f"{path}: cannot read the image")
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY)
    if img.dtype not in (np.uint8, np.uint16):
        raise StageError(f"{path}: expected an 8- or 16-bit grey image; got {img.dtype}")
    return img


def first_images(cams: list, files: dict) -> tuple[dict, str]:
    """The step-0 image of every camera that has one (at least two, of the calibration's size) and the session's
    pixel type ("uint16" when any image is 16-bit)."""
    first = {c.name: read_image(files[c.name][0]) for c in cams if 0 in files[c.name]}
    if len(first) < 2:
        raise StageError(f"IMAGES_DIR: step 0 needs images from at least two cameras; found {sorted(first)}")
    for c in cams:
        if c.name in first and first[c.name].shape != (c.image_size[1], c.image_size[0]):
            raise StageError(
                f"{files[c.name][0]}: image is {first[c.name].shape[1]}x{first[c.name].shape[0]} px but the "
                f"calibration of {c.name} is for {c.image_size[0]}x{c.image_size[1]}"
            )
    dtypes = {c: str(first[c].dtype) for c in first}
    return first, "uint16" if "uint16" in dtypes.values() else "uint8"


def estimate_geometry(reference: np.ndarray) -> tuple[float, float]:
    """Radius and axial extent (m) of a reference marker cloud ``(n_markers, 3)``.

    Least-squares cylinder fit (axis point, axis direction, radius), started from each of the
    cloud's principal directions; the best fit wins.
    """
    points = reference[~np.isnan(reference).any(axis=1)]
    _, direction, radius, axial = _fit_cylinder(points)
    return radius, float(axial.max() - axial.min())


#: Points the cylinder of a plausibility check is fitted to at most (a DIC cloud's 50,000 took 7 s a fit, 20 s an
#: import): larger clouds are subsampled for the axis.
FIT_POINTS = 1000


def _fit_cylinder(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """A point on the axis (3,) m, the axis direction (3,), the radius (m) and the axial coordinates (n,) m
    of the points (n, 3); the axis fitted to :data:`FIT_POINTS` of them drawn at random (seeded) when there are
    more (a stride could alias with a DIC grid's rows), the radius then the mean distance of all from it."""
    from scipy.optimize import least_squares

    centre = points.mean(axis=0)
    centred = points - centre
    fitted = centred
    if len(centred) > FIT_POINTS:
        fitted = centred[np.sort(np.random.default_rng(0).choice(len(centred), FIT_POINTS, replace=False))]
    _, _, vt = np.linalg.svd(fitted, full_matrices=False)

    def radial(params):
        direction = np.array([np.sin(params[0]) * np.cos(params[1]), np.sin(params[0]) * np.sin(params[1]),
                              np.cos(params[0])])
        rel = fitted - params[2:5]
        return np.linalg.norm(rel - (rel @ direction)[:, None] * direction, axis=1), direction

    best = None
    for axis in vt:
        theta0, phi0 = np.arccos(np.clip(axis[2], -1, 1)), np.arctan2(axis[1], axis[0])
        fit = least_squares(lambda q: radial(q)[0] - q[5], [theta0, phi0, 0, 0, 0, radial([theta0, phi0, 0, 0, 0])[0].mean()])
        if best is None or fit.cost < best.cost:
            best = fit
    _, direction = radial(best.x)
    rel = centred - best.x[2:5]
    axial = rel @ direction
    radius = abs(best.x[5]) if fitted is centred else np.mean(np.linalg.norm(rel - axial[:, None] * direction, axis=1))
    return centre + best.x[2:5], direction, float(radius), axial


#: A marker farther from the tube axis than this many radii is a typo, not a measurement: at the reference
#: step, and (the tube inflates) at a loaded step.
OUTLIER_RADII = (2.0, 3.0)


def marker_outliers(positions: np.ndarray, labels, steps, *, source: str, radius: float | None = None) -> None:
    """An ImplausibleInputError naming the first marker that lies far off the tube (decision 0007).

    ``positions`` (n_steps, n_markers, 3) m, NaN = not measured; ``labels`` (n_markers,), ``steps`` (n_steps,)
    for the message. The axis is fitted to the reference markers (step 0) without the markers farthest from
    their median (a typo must not pull the fit), then to those near that cylinder; ``radius`` (m) the
    specimen's, else the fitted one. A marker more than :data:`OUTLIER_RADII` radii from the axis is refused,
    not fitted.
    """
    positions = np.asarray(positions, float)
    ref = positions[0]
    keep = np.isfinite(ref).all(axis=1)
    if keep.sum() < 8:
        return  # too few to fit an axis: check_marker_cloud says so
    # a typo must not pull the fit: first the 90 % of the markers nearest the cloud's median, then those near it
    near = np.linalg.norm(np.where(keep[:, None], ref, np.nan) - np.nanmedian(ref[keep], axis=0), axis=1)
    core = keep & (near <= np.nanpercentile(near, 90))
    centre, direction, fitted, _ = _fit_cylinder(ref[core])
    core = keep & (np.abs(_axis_distance(ref, centre, direction) - fitted) <= 0.5 * fitted)
    if core.sum() >= 8:
        centre, direction, fitted, _ = _fit_cylinder(ref[core])
    r = radius if radius else fitted
    for k in range(positions.shape[0]):
        d = _axis_distance(positions[k], centre, direction)
        limit = OUTLIER_RADII[0 if k == 0 else 1] * r
        bad = np.flatnonzero(np.nan_to_num(d, nan=0.0) > limit)
        if bad.size:
            m = int(bad[np.argmax(d[bad])])
            raise ImplausibleInputError(
                f"{source}, step {int(np.asarray(steps)[k])}: marker {np.asarray(labels)[m]} lies {d[m] * 1e3:.4g} mm "
                f"from the tube axis, {d[m] / r:.3g} times the radius {r * 1e3:.4g} mm (at most "
                f"{OUTLIER_RADII[0 if k == 0 else 1]:g} radii); a typo? Correct or delete it"
                + (f" (and {bad.size - 1} more marker(s) at this step)" if bad.size > 1 else ""))


def _axis_distance(points: np.ndarray, centre: np.ndarray, direction: np.ndarray) -> np.ndarray:
    rel = points - centre
    return np.linalg.norm(rel - (rel @ direction)[:, None] * direction, axis=1)


def check_marker_inputs(table, loads, rows, markers_csv, loads_csv, thickness_mm, radius_mm, length_mm,
                        warn: Notify = log_notes) -> tuple[float, float, list[str]]:
    """Plausibility of the imported data (decision 0007): the reference radius and length (m) to record and
    the warnings to store in the session (also shown now); ImplausibleInputError for refused values."""
    from acquisition.plausibility import (check_cloud_scale, check_geometry, check_identifiable, check_loads,
                                          check_marker_cloud)

    for name, value in (("--thickness-mm", thickness_mm), ("--radius-mm", radius_mm), ("--length-mm", length_mm)):
        if value is not None and not (np.isfinite(value) and value > 0):
            raise StageError(f"{name} must be a positive length in mm; got {value}")
    warnings = check_loads(loads["pressure"][rows], loads["axial_force"][rows], loads["stretch"][rows],
                           source=str(loads_csv), steps=table.steps)
    reference = table.positions[0]
    check_marker_cloud(reference, source=str(markers_csv))
    marker_outliers(table.positions, table.labels, table.steps, source=str(markers_csv),
                    radius=radius_mm * 1e-3 if radius_mm else None)
    fitted_radius, fitted_length = estimate_geometry(reference)
    if radius_mm:
        check_marker_cloud(reference, source=str(markers_csv), radius=radius_mm * 1e-3, fitted_radius=fitted_radius)
    else:
        check_cloud_scale(fitted_radius, source=str(markers_csv))
    radius = mm_to_m(radius_mm) if radius_mm else fitted_radius
    length = mm_to_m(length_mm) if length_mm else fitted_length
    warnings += check_geometry(radius, mm_to_m(thickness_mm), length, source=str(markers_csv))
    try:
        warnings += check_identifiable(table.positions, source=str(markers_csv), steps=table.steps)
    except ImplausibleInputError as exc:  # importing is fine; identifying will refuse
        warnings.append(f"{exc}; 'vfmlab identify' will refuse this session")
    for message in warnings:
        warn(message)
    return radius, length, warnings


def measure_tube(first: dict, cams: list, marker_diameter_mm: float, polarity: str, radius_mm, length_mm,
                  notes: list) -> tuple[float, float]:
    """Radius and length (mm) not given, measured from the step-0 markers (a tube, or an error); says so in ``notes``."""
    from reconstruction import ReconstructionSettings, fit_cylinder, reconstruct_step

    settings = ReconstructionSettings(marker_diameter=marker_diameter_mm * 1e-3, detection={"polarity": polarity})
    pts, _ = reconstruct_step(first, cams, settings)
    if pts.centres.shape[0] < 8:
        raise StageError("could not measure the specimen from the step-0 images (fewer than 8 markers "
                            "reconstructed); give --radius-mm and --length-mm")
    cyl = fit_cylinder(pts.centres)
    check_tube(cyl, pts.centres)
    _, _, z = cyl.cylindrical(pts.centres)
    if radius_mm is None:
        radius_mm = (cyl.radius - 0.5 * marker_diameter_mm * 1e-3) * 1e3
        notes.append(f"radius measured from step-0 markers ({pts.centres.shape[0]} markers)")
    if length_mm is None:
        length_mm = float(np.ptp(z)) * 1e3
        notes.append("length = axial extent of the step-0 markers")
    return radius_mm, length_mm


def check_tube(cyl, centres: np.ndarray) -> None:
    """The specimen's radius and length are measured assuming the step-0 markers lie on a tube: refuse when they do not."""
    extent = float(np.ptp(centres, axis=0).max())
    if not (cyl.rms < 0.1 * cyl.radius and cyl.radius < 2.0 * extent):
        raise StageFailed(
            f"the {centres.shape[0]} step-0 markers do not lie on a tube (cylinder fit: radius {cyl.radius * 1e3:.3g} mm, "
            f"RMS {cyl.rms * 1e3:.3g} mm, markers spread over {extent * 1e3:.3g} mm): the specimen's radius and length "
            "are measured assuming a tubular specimen; give --radius-mm and --length-mm"
        )


@dataclass(frozen=True)
class FoundImages:
    """An image folder as read: calibrated ``cams``, ``steps`` (n,) with their ``rows`` in the loads table, the
    ``files`` {camera: {step: path}}, the step-0 images ``first`` {camera: (H, W)} and their ``dtype``."""

    cams: list
    steps: np.ndarray
    rows: np.ndarray
    files: dict[str, dict[int, Path]]
    first: dict[str, np.ndarray]
    dtype: Any


def write_imported_session(out: Path, specimen: Any, found: FoundImages, loads: Any, rig: dict, calibration: str,
                           force_is: str, overwrite: bool, *, warn: Notify = log_notes,
                           advance: Callable[[], None] = lambda: None) -> str:
    """Create the session ``out`` with one step per image step (a missing image stored blank, with a warning) and
    store the cameras as its first "calibration" result; returns that result's name. An implausible geometry
    (thickness not below the radius, sizes outside the plausible ranges) is refused first."""
    from acquisition.plausibility import check_geometry
    from acquisition.session import CameraSpec, SessionWriter, StepRecord, write_result
    from reconstruction import cameras_to_arrays

    try:  # before the file exists
        for message in check_geometry(specimen.radius, specimen.thickness, specimen.length,
                                      source=str(rig.get("images_dir", out))):
            warn(message)
    except ImplausibleInputError as exc:
        raise StageError(str(exc)) from None
    cams, dtype = found.cams, found.dtype
    specs = [CameraSpec(c.name, "imported", c.image_size[0], c.image_size[1], dtype) for c in cams]
    with SessionWriter.create(out, specimen, cameras=specs, protocol_text="", rig=rig, load_cell_measures=force_is,
                              overwrite=overwrite) as writer:
        for s, row in zip(found.steps, found.rows):
            imgs = {}
            for c in cams:
                path = found.files[c.name].get(int(s))
                if path is None:
                    warn(f"no image of {c.name} for step {s}; stored blank.")
                    img = np.zeros((c.image_size[1], c.image_size[0]), dtype)
                else:
                    img = found.first[c.name] if s == 0 else read_image(path)
                    if img.shape != (c.image_size[1], c.image_size[0]):
                        raise StageError(f"{path}: image size {img.shape[::-1]} differs from the calibration")
                imgs[c.name] = img.astype(dtype, copy=False)
            writer.add_step(StepRecord(
                block=0, stretch=float(loads["stretch"][row]), target_pressure=float(loads["pressure"][row]),
                pressure=float(loads["pressure"][row]), force=float(loads["axial_force"][row]),
                t_monotonic=float("nan"), t_wall=float("nan")), images=imgs)
            advance()
    return write_result(out, "calibration", cameras_to_arrays(cams), {"source": calibration})
