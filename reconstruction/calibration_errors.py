"""Calibration's exceptions: :class:`CalibrationError` (a calibration cannot proceed) and
:class:`CalibrationFileError` (a calibration file is malformed). Imported by the calibration modules, which depend
on nothing here.
"""

from __future__ import annotations

__all__ = ["CalibrationError", "CalibrationFileError", "CameraError"]


class CalibrationError(RuntimeError):
    """Calibration cannot proceed (too few views, disconnected cameras, ...)."""


class CalibrationFileError(ValueError):
    """A calibration file is malformed or uses an unsupported model."""


class CameraError(CalibrationFileError):
    """A calibration describes no possible camera (K = 0, a negative focal length, a non-finite rotation, ...).

    Attributes ``camera`` (its name, or where in the file) and ``field`` (``matrix``, ``size``, ``rotation``, ...).
    """

    def __init__(self, message: str, *, camera: str = "", field: str = "") -> None:
        super().__init__(message)
        self.camera = camera
        self.field = field
