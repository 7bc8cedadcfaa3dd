"""What both ways of calibrating (board images, :mod:`vfmlab.stages.calibrate`; an import,
:mod:`vfmlab.stages.calibrate_import`) return and write."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["CALIBRATION_UNITS", "CalibrationOutcome", "write_cameras"]

#: Units of the arrays of a stored "calibration" result.
CALIBRATION_UNITS = {"K": "px", "tvec": "m", "rvec": "rad", "rms": "px", "image_size": "px", "window_offset": "m",
                     "window_thickness": "m", "window_normal": "1", "window_index": "1"}


@dataclass
class CalibrationOutcome:
    """What :func:`calibrate` did: ``summary`` is the command's ``--json`` (SI, px, mm as the keys say);
    ``result`` the board calibration (``reconstruction.calibration``), None for an import; ``cameras``
    the calibrated cameras; ``meta`` what an import read (``body_rms_px``, ``self_calibration``, ...)."""

    summary: dict[str, Any]
    cameras: list
    stored: str | None
    result: Any = None
    meta: dict[str, Any] = field(default_factory=dict)


def write_cameras(out: Path, cameras: list, units: str, meta: dict) -> None:
    """Write ``cameras`` to ``out``: .toml (aniposelib) or .yaml/.yml (OpenCV FileStorage), translations in ``units``."""
    from reconstruction.calibration_io import cameras_to_toml, cameras_to_yaml

    text = (cameras_to_toml if out.suffix.lower() == ".toml" else cameras_to_yaml)(cameras, units=units, metadata=meta)
    out.write_text(text)
