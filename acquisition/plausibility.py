"""Physical plausibility of measured inputs, with the rig's and the specimen's own numbers.

Each check takes arrays in SI (Pa, N, m, L/L0), raises :class:`ImplausibleInputError` for values
no arterial inflation/extension test can produce (a sign or unit mistake: metres given as mm, kN
as N, mmHg as Pa) and returns warnings (one sentence each) for values that are merely unusual;
callers store the warnings in the session (event kind "warning") so that ``vfmlab info`` and the
report show them. Decision 0007 lists the rules in one table.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from acquisition.errors import ImplausibleInputError

__all__ = ["LoadLimits", "check_loads", "check_geometry", "check_marker_cloud", "check_cloud_scale", "check_identifiable",
           "STRETCH_RANGE", "MIN_MESH_MARKERS", "SPECIMEN_RANGES", "check_specimen_size", "MAX_IMAGE_SIDE_PX",
           "check_session_resources", "human_bytes"]

MMHG = 133.322387415  # Pa per mmHg
STRETCH_RANGE = (0.5, 3.0)  # axial stretch outside this open interval is refused
MIN_MESH_MARKERS = 8  # fewer reference markers cannot mesh a tube surface (decision 0007)
#: Plausible specimen sizes, m: (low, high) of radius, wall thickness and length; outside, refused (a unit
#: mistake or a typo: a 1 nm or a 2 m artery does not exist).
SPECIMEN_RANGES = {"radius": (1e-4, 0.1), "thickness": (5e-6, 0.05), "length": (5e-4, 1.0)}
_CLOUD_RATIO = 2.0
#: Largest image side a camera may have, px (as reconstruction.camera_checks: no sensor comes near).
MAX_IMAGE_SIDE_PX = 40_000
#: Working memory of a capture per pixel of the largest frame, bytes: the simulated rig renders in float64
#: with a few buffers, live detection filters in float32.
WORK_BYTES_PER_PIXEL = 48  # marker-cloud radius vs specimen radius: beyond this factor, refused


@dataclass(frozen=True)
class LoadLimits:
    """Pressure and force limits (Pa, N). Beyond ``max_*``: refused; beyond ``usual_*``: a warning.

    The defaults are for data from another rig: ``max_pressure`` 100 kPa (750 mmHg) and
    ``max_force`` 200 N are beyond any arterial test; a rig's own ``[safety]`` limits are tighter.
    A small negative pressure or force (transducer offset) is accepted down to ``min_*``.
    """

    max_pressure: float = 100e3
    usual_pressure: float = 300 * MMHG
    min_pressure: float = -1e3
    max_force: float = 200.0
    usual_force: float = 50.0
    min_force: float = -5.0


def _kpa_mmhg(p: float) -> str:
    return f"{p / 1e3:.4g} kPa ({p / MMHG:.4g} mmHg)"


def _first(mask: np.ndarray, steps: np.ndarray) -> tuple[int, int]:
    k = int(np.flatnonzero(mask)[0])
    return k, int(steps[k])


def check_loads(pressure: np.ndarray, force: np.ndarray, stretch: np.ndarray, *, source: str,
                steps: np.ndarray | None = None, limits: LoadLimits = LoadLimits()) -> list[str]:
    """Check the loads of every step: pressure (Pa), wall force (N, NaN = not measured), stretch (L/L0).

    Parameters
    ----------
    pressure, force, stretch : ndarray, shape (n_steps,)
    source : the file (or session) the values come from, named first in every message.
    steps : step numbers for the messages [default: 0..n_steps-1].

    Returns the warnings; raises :class:`ImplausibleInputError` at the first refused value.
    """
    pressure, force, stretch = (np.asarray(a, dtype=float) for a in (pressure, force, stretch))
    steps = np.arange(pressure.size) if steps is None else np.asarray(steps)
    warnings: list[str] = []
    checks = (
        (pressure < limits.min_pressure, lambda k: f"pressure {_kpa_mmhg(pressure[k])} is negative; expected "
                                                   f"0..{_kpa_mmhg(limits.max_pressure)} (sign error?)"),
        (pressure > limits.max_pressure, lambda k: f"pressure {_kpa_mmhg(pressure[k])} is beyond "
                                                   f"{_kpa_mmhg(limits.max_pressure)} (Pa given where kPa or "
                                                   "mmHg expected?)"),
        (force > limits.max_force, lambda k: f"axial force {force[k]:.4g} N is beyond the load cell's "
                                             f"{limits.max_force:.4g} N (kN or mN given where N expected?)"),
        (force < -limits.max_force, lambda k: f"axial force {force[k]:.4g} N is beyond the load cell's "
                                              f"-{limits.max_force:.4g} N"),
        ((stretch <= STRETCH_RANGE[0]) | (stretch >= STRETCH_RANGE[1]),
         lambda k: f"axial stretch {stretch[k]:.4g} is outside ({STRETCH_RANGE[0]}, {STRETCH_RANGE[1]}) "
                   "(a length or a percentage given where L/L0 expected?)"),
    )
    for bad, message in checks:
        if bad.any():
            k, step = _first(bad, steps)
            raise ImplausibleInputError(f"{source}, step {step}: {message(k)}")
    unusual = (
        (pressure > limits.usual_pressure, lambda k: f"pressure {_kpa_mmhg(pressure[k])} is above the usual "
                                                     f"{_kpa_mmhg(limits.usual_pressure)}"),
        (np.abs(force) > limits.usual_force, lambda k: f"axial force {force[k]:.4g} N is above the usual "
                                                       f"{limits.usual_force:.4g} N"),
        (force < limits.min_force, lambda k: f"axial force {force[k]:.4g} N is compressive"),
        (stretch < 1.0, lambda k: f"axial stretch {stretch[k]:.4g} is below 1 (the specimen is shorter than "
                                  "at the reference)"),
    )
    for bad, message in unusual:
        if bad.any():
            k, step = _first(bad, steps)
            more = int(bad.sum()) - 1
            warnings.append(f"{source}, step {step}: {message(k)}" + (f" (and {more} more step(s))" if more else ""))
    return warnings


def check_specimen_size(*, source: str, **sizes: float | None) -> None:
    """Each given size (``radius=``, ``thickness=``, ``length=``, m) within :data:`SPECIMEN_RANGES`."""
    for name, value in sizes.items():
        if value is None or not np.isfinite(value) or value <= 0:
            continue  # check_geometry's positive-length messages
        lo, hi = SPECIMEN_RANGES[name]
        if not lo <= value <= hi:
            raise ImplausibleInputError(f"{source}: the specimen {name} {value * 1e3:.4g} mm is outside the plausible "
                                        f"range {lo * 1e3:g}..{hi * 1e3:g} mm (a unit mistake?)")


def check_geometry(radius: float, thickness: float, length: float | None = None, *, source: str) -> list[str]:
    """Reference geometry (m): radius > 0, thickness < radius, sizes within :data:`SPECIMEN_RANGES`; a thick
    wall (e > R/2) is a warning."""
    if not (np.isfinite(radius) and radius > 0):
        raise ImplausibleInputError(f"{source}: the specimen radius must be a positive length; got "
                                    f"{radius * 1e3:.4g} mm")
    if not (np.isfinite(thickness) and thickness > 0):
        raise ImplausibleInputError(f"{source}: the wall thickness must be a positive length; got "
                                    f"{thickness * 1e3:.4g} mm")
    if thickness >= radius:
        raise ImplausibleInputError(f"{source}: the wall thickness {thickness * 1e3:.4g} mm is not smaller than the "
                                    f"radius {radius * 1e3:.4g} mm (the markers sit on the outer wall)")
    check_specimen_size(source=source, radius=radius, thickness=thickness, length=length)
    warnings = []
    if thickness > 0.5 * radius:
        warnings.append(f"{source}: the wall is thick (thickness {thickness * 1e3:.4g} mm > half the radius "
                        f"{radius * 1e3:.4g} mm): the membrane assumption is poor, prefer --wall thick")
    if length is not None and np.isfinite(length) and length < radius:
        warnings.append(f"{source}: the specimen is short (length {length * 1e3:.4g} mm < radius "
                        f"{radius * 1e3:.4g} mm): the end effects reach mid-span")
    return warnings


def check_marker_cloud(reference: np.ndarray, *, source: str, radius: float | None = None,
                       fitted_radius: float | None = None) -> list[str]:
    """The reference marker cloud ``(n_markers, 3)`` (m, NaN = not measured): enough markers, not collinear,
    and (when both are known) a fitted cloud radius within a factor of 2 of the specimen's radius."""
    reference = np.asarray(reference, dtype=float)
    points = reference[np.isfinite(reference).all(axis=1)]
    if len(points) == 0:
        raise ImplausibleInputError(f"{source}, step 0: no marker has coordinates at the reference step; "
                                    "every marker needs a reference position")
    if len(points) < MIN_MESH_MARKERS:
        raise ImplausibleInputError(f"{source}, step 0: {len(points)} marker(s) measured; at least "
                                    f"{MIN_MESH_MARKERS} are needed to mesh the specimen surface")
    centred = points - points.mean(axis=0)
    singular = np.linalg.svd(centred, compute_uv=False)
    if singular[0] == 0 or singular[1] < 1e-3 * singular[0]:
        raise ImplausibleInputError(f"{source}, step 0: the {len(points)} reference markers lie on one line; "
                                    "they must cover the tube's surface")
    if radius is not None and fitted_radius is not None and radius > 0:
        ratio = fitted_radius / radius
        if not 1 / _CLOUD_RATIO <= ratio <= _CLOUD_RATIO:
            hint = (" (metres given where mm expected?)" if ratio < 1e-2 else
                    " (µm given where mm expected?)" if ratio > 1e2 else "")
            raise ImplausibleInputError(
                f"{source}, step 0: the markers lie on a cylinder of radius {fitted_radius * 1e3:.4g} mm but the "
                f"specimen radius is {radius * 1e3:.4g} mm; expected within a factor of {_CLOUD_RATIO:g}{hint}")
    return []


def check_cloud_scale(fitted_radius: float, *, source: str) -> None:
    """Without a given radius: refuse a fitted cloud radius no artery has (below 0.1 mm or above 100 mm)."""
    if not np.isfinite(fitted_radius) or fitted_radius < 1e-4:
        raise ImplausibleInputError(
            f"{source}, step 0: the markers lie on a cylinder of radius {fitted_radius * 1e3:.3g} mm; expected "
            "0.1..100 mm (metres given where mm expected?)")
    if fitted_radius > 0.1:
        raise ImplausibleInputError(
            f"{source}, step 0: the markers lie on a cylinder of radius {fitted_radius * 1e3:.4g} mm; expected "
            "0.1..100 mm (µm given where mm expected?)")


def check_identifiable(positions: np.ndarray, *, source: str, steps: np.ndarray | None = None) -> list[str]:
    """Positions ``(n_steps, n_markers, 3)``: the reference and at least two loaded steps with markers."""
    positions = np.asarray(positions, dtype=float)
    steps = np.arange(positions.shape[0]) if steps is None else np.asarray(steps)
    observed = np.isfinite(positions).all(axis=2).any(axis=1)
    if positions.shape[0] < 3:
        raise ImplausibleInputError(f"{source}: {positions.shape[0]} step(s); identification needs the reference "
                                    "and at least two loaded steps")
    if not observed[0]:
        raise ImplausibleInputError(f"{source}, step {int(steps[0])}: the reference step has no measured marker")
    empty = steps[~observed].tolist()
    if observed.sum() < 3:
        raise ImplausibleInputError(f"{source}: steps {empty} have no measured marker; identification needs the "
                                    "reference and at least two loaded steps with markers")
    return [f"{source}: steps {empty} have no measured marker and are left out"] if empty else []


def human_bytes(n: float) -> str:
    """``n`` bytes as ``"123 GB"`` (decimal units)."""
    for unit, size in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{n:.0f} B"


def check_session_resources(frames: list[tuple[int, int, int]], n_captures: int, *, free_disk: float,
                            memory: float, source: str) -> None:
    """Refuse a recording that cannot fit the machine, before anything moves, with the estimate.

    ``frames``: (width, height, bytes per pixel) of each camera; ``n_captures``: the images each camera takes
    (steps and calibration views); ``free_disk`` and ``memory`` (physical RAM), bytes.
    """
    per_capture = sum(w * h * b for w, h, b in frames)
    disk = 1.02 * n_captures * per_capture + 16e6  # HDF5 metadata, logs and the runner's reserve
    if disk > free_disk:
        raise ImplausibleInputError(
            f"{source}: the session would need about {human_bytes(disk)} on disk ({n_captures:,} captures x "
            f"{len(frames)} camera(s) x {human_bytes(per_capture / max(len(frames), 1))} per image) but only "
            f"{human_bytes(free_disk)} are free there; fewer steps or smaller images, or another disk")
    largest = max((w * h for w, h, _ in frames), default=0)
    work = WORK_BYTES_PER_PIXEL * largest + per_capture
    if work > 0.5 * memory:
        raise ImplausibleInputError(
            f"{source}: capturing would need about {human_bytes(work)} of memory (largest frame {largest:,} px) "
            f"but the machine has {human_bytes(memory)}; use smaller images")
