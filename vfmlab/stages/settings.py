"""The settings of each stage: frozen dataclasses whose defaults are the command line's defaults.

``vfmlab identify S.h5`` and ``vfmlab.identify("S.h5")`` run with ``IdentifySettings()``; an option of
the command is a field of the same name (``--model hgo`` is ``IdentifySettings(model="hgo")``). The
identification's defaults are the library's own (``identification.DEFAULTS``, read from
``identification/defaults.py``): ``identification.identify`` called on the same arrays gives the same numbers.
This module imports nothing heavy: ``vfmlab --help`` and ``import vfmlab`` stay fast.
"""

from __future__ import annotations

import importlib.util
import sys
from dataclasses import dataclass, fields, replace
from pathlib import Path
from types import ModuleType
from typing import Any, TypeVar

__all__ = ["CalibrateSettings", "CheckLimits", "CheckRigSettings", "ExportSettings", "IdentifySettings", "ReconstructSettings", "RegionalSettings",
           "ReportSettings", "ReprocessSettings", "RunSettings", "SelfCalibrationSettings", "settings_with"]

S = TypeVar("S")


def _identification_defaults() -> ModuleType:
    """``identification.defaults`` (the one definition of the identification's defaults), loaded without running
    the package's ``__init__`` (numpy, scipy: ~1 s) and registered under its own name, so that the package, when
    imported later, uses this very module."""
    name = "identification.defaults"
    if name in sys.modules:
        return sys.modules[name]
    package = importlib.util.find_spec("identification")  # finds, does not import
    if package is None or not package.submodule_search_locations:
        raise ImportError("the identification package is not installed")
    spec = importlib.util.spec_from_file_location(name, Path(list(package.submodule_search_locations)[0]) / "defaults.py")
    if spec is None or spec.loader is None:
        raise ImportError("identification/defaults.py is missing")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


#: The identification's defaults (``identification.DEFAULTS``): the library's and the command's.
IDENTIFY_DEFAULTS = _identification_defaults().DEFAULTS
_D = IDENTIFY_DEFAULTS


def settings_with(cls: type[S], settings: S | None, overrides: dict[str, Any]) -> S:
    """``settings`` (default: ``cls()``) with ``overrides`` replaced; a TypeError names an unknown field."""
    base = cls() if settings is None else settings
    if not isinstance(base, cls):
        raise TypeError(f"settings must be a {cls.__name__}; got {type(base).__name__}")
    unknown = sorted(set(overrides) - {f.name for f in fields(cls)})
    if unknown:
        raise TypeError(f"{cls.__name__} has no field(s) {unknown}; its fields are {[f.name for f in fields(cls)]}")
    return replace(base, **overrides) if overrides else base


@dataclass(frozen=True)
class IdentifySettings:
    """``vfmlab identify``: the model identified from the latest marker tracks (see ``vfmlab identify --help``).

    ``smooth``: "auto", "none" or "AXIAL,HARMONICS" text as on the command line, or a pair of ints.
    ``regions``: None (one homogeneous fit) or "N", "auto", "legendre:K" (a "regional" result).
    """

    model: str = _D.model
    wall: str | None = _D.wall
    ends: str | None = _D.ends
    optimizer: str = _D.optimizer
    smooth: str | tuple[int, int] | None = _D.smoothing
    uncertainty: str = _D.uncertainty
    weighting: str = _D.weighting
    regions: str | int | None = None


@dataclass(frozen=True)
class RegionalSettings:
    """``vfmlab identify --regions``: the stress-like parameter along the axis, the others shared."""

    regions: str | int = "auto"
    model: str = _D.model
    wall: str | None = _D.wall
    ends: str | None = _D.ends
    smooth: str | tuple[int, int] | None = _D.smoothing
    uncertainty: str = _D.uncertainty


@dataclass(frozen=True)
class ReconstructSettings:
    """``vfmlab reconstruct``: detect, match, triangulate and track the markers (mm and px as on the command line)."""

    marker_diameter_mm: float | None = None
    calibration: Path | None = None
    calibration_units: str | None = None
    frame: str = "specimen"
    flip_axis: bool = False
    normals: str = "local"
    epipolar_px: float = 2.0
    max_reprojection_px: float = 1.5
    include_superseded: bool = False
    store: bool = True


@dataclass(frozen=True)
class SelfCalibrationSettings:
    """``vfmlab calibrate --import FOLDER --self-calibrate FRAMES``: refine on the particles of ``frames``."""

    frames: str
    images: str = "img_1/cam{camera}.{frame}"
    body_weight: float = 0.5
    volume: str | None = None
    body_sides: bool = True


@dataclass(frozen=True)
class CalibrateSettings:
    """``vfmlab calibrate``: board images (a folder or the session's) or an imported calibration."""

    images_dir: Path | None = None
    board: str = "charuco"
    squares: str = "8x6"
    square_size_mm: float = 4.5
    marker_size_mm: float = 3.4
    dictionary: str = "DICT_4X4_50"
    subpix_window: int = 5
    reference: str | None = None
    world_view: int | None = None
    fix_k3: bool | None = None  # None: fixed or free as held-out views decide (reconstruction.calibration_select)
    out: Path | None = None
    units: str = "mm"
    store: bool = True
    import_file: Path | None = None
    selfcal_frames: str | None = None
    particle_images: str = "img_1/cam{camera}.{frame}"
    body_weight: float = 0.5
    body_sides: bool = True
    volume_mm: str | None = None
    import_units: str = "mm"
    body: str | None = None
    refine_window: bool = False

    def self_calibration(self) -> SelfCalibrationSettings | None:
        """The ``--self-calibrate`` part, or None."""
        if self.selfcal_frames is None:
            return None
        return SelfCalibrationSettings(self.selfcal_frames, self.particle_images, self.body_weight, self.volume_mm,
                                       self.body_sides)


@dataclass(frozen=True)
class ReportSettings:
    """``vfmlab report``: ``out`` default <SESSION stem>_report next to the session."""

    out: Path | None = None
    strain_scale: str = "shared"


@dataclass(frozen=True)
class ExportSettings:
    """``vfmlab export``: ``out`` default <SESSION stem>_export next to the session; ``markers_name`` default the latest."""

    out: Path | None = None
    fmt: str = "vtu"
    markers_name: str | None = None


@dataclass(frozen=True)
class ReprocessSettings:
    """``vfmlab reprocess``: stages re-run on stored sessions (comma-separated lists as on the command line)."""

    stages: str = "identify"
    models: str = _D.model
    walls: str | None = _D.wall
    ends: str | None = _D.ends
    optimizer: str = _D.optimizer
    smooth: str | tuple[int, int] | None = _D.smoothing
    weighting: str = _D.weighting
    set_pairs: tuple[str, ...] = ()
    workers: int = 1
    scheduler: str | None = None
    summary: Path | None = None


@dataclass(frozen=True)
class RunSettings:
    """``vfmlab run``: a protocol on the rig (or the simulated rig) into a new session file."""

    rig: str | None = None
    sim: bool = False
    sim_speed: float = 1.0
    sim_seed: int | None = None
    yes: bool = False
    detect: bool = True
    live_models: str = _D.model
    #: seconds of instrument readings of the pre-flight check at the start (0 = no pre-flight check)
    check_seconds: float = 2.0


@dataclass(frozen=True)
class CheckLimits:
    """What the pre-flight check (``vfmlab check-rig``, the start of ``vfmlab run``) accepts; SI except where
    the name says. A camera: at least ``min_markers`` markers, sharpness (variance of the Laplacian over the
    image variance) and median marker contrast at least the minima, at most ``max_saturated`` of its pixels
    saturated, and at least ``min_matched`` of its markers seen by another camera (with a calibration). An
    instrument: zero offset, noise (standard deviation) and drift (linear fit) within the limits."""

    min_markers: int = 20
    min_sharpness: float = 0.02
    min_contrast: float = 0.4
    max_saturated: float = 0.01
    min_matched: int = 6
    max_pressure_offset_pa: float = 2 * 133.322387415
    max_pressure_noise_pa: float = 133.322387415
    max_pressure_drift_pa_per_s: float = 133.322387415 / 60
    max_force_offset_n: float = 0.1
    max_force_noise_n: float = 0.02
    max_force_drift_n_per_s: float = 0.05 / 60


@dataclass(frozen=True)
class CheckRigSettings:
    """``vfmlab check-rig``: a frame from every camera and a few seconds of every instrument, judged."""

    rig: str | None = None
    sim: bool = False
    sim_seed: int | None = None
    seconds: float = 3.0
    out: str | None = None
    limits: CheckLimits = CheckLimits()
