"""Building a session from data measured elsewhere (``vfmlab import-markers``, ``vfmlab import-images``): the
checks of the imported marker cloud and loads, and the reading of an image folder ``DIR/<camera>/<step>.png``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from acquisition.errors import ImplausibleInputError
from vfmlab.stages.errors import StageError
from vfmlab.stages.feedback import Notify, log_notes

__all__ = ["check_marker_inputs", "estimate_geometry", "first_images", "mm_to_m", "read_image", "scan_images"]


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
    from scipy.optimize import least_squares

    points = reference[~np.isnan(reference).any(axis=1)]
    centre = points.mean(axis=0)
    centred = points - centre
    _, _, vt = np.linalg.svd(centred, full_matrices=False)

    def radial(params):
        direction = np.array([np.sin(params[0]) * np.cos(params[1]), np.sin(params[0]) * np.sin(params[1]),
                              np.cos(params[0])])
        rel = centred - params[2:5]
        return np.linalg.norm(rel - (rel @ direction)[:, None] * direction, axis=1), direction

    best = None
    for axis in vt:
        theta0, phi0 = np.arccos(np.clip(axis[2], -1, 1)), np.arctan2(axis[1], axis[0])
        fit = least_squares(lambda q: radial(q)[0] - q[5], [theta0, phi0, 0, 0, 0, radial([theta0, phi0, 0, 0, 0])[0].mean()])
        if best is None or fit.cost < best.cost:
            best = fit
    _, direction = radial(best.x)
    axial = (centred - best.x[2:5]) @ direction
    return float(abs(best.x[5])), float(axial.max() - axial.min())


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
