"""Cameras: one interface (open, configure with read-back, grab(timeout) -> Frame), several backends."""

from acquisition.cameras.base import (Camera, CameraConfigError, CameraDisconnected, CameraError, CameraExhausted,
                                      CameraNotFound, CameraTimeout, Frame, to_mono)
from acquisition.cameras.capture import CaptureError, CaptureResult, capture_all, open_camera
from acquisition.cameras.folder import FolderCamera
from acquisition.cameras.function import FunctionCamera

__all__ = [
    "Camera", "CameraConfigError", "CameraDisconnected", "CameraError", "CameraExhausted", "CameraNotFound",
    "CameraTimeout", "Frame", "to_mono", "CaptureError", "CaptureResult", "capture_all", "open_camera",
    "FolderCamera", "FunctionCamera",
]
