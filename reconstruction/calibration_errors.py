"""Calibration's exceptions: :class:`CalibrationError` (a calibration cannot proceed) and
:class:`CalibrationFileError` (a calibration file is malformed). Imported by the calibration modules, which depend
on nothing here.
"""

from __future__ import annotations

__all__ = ["CalibrationError", "CalibrationFileError"]


class CalibrationError(RuntimeError):
    """Calibration cannot proceed (too few views, disconnected cameras, ...)."""


class CalibrationFileError(ValueError):
    """A calibration file is malformed or uses an unsupported model."""
