"""OpenCV ``VideoCapture`` cameras (webcams, video files, image sequences ``img_%03d.png``)."""

from __future__ import annotations

import math
import threading
from typing import Any

import cv2
import numpy as np

from acquisition.cameras.base import Camera, CameraDisconnected, CameraError, CameraNotFound, CameraTimeout

__all__ = ["OpenCVCamera"]

# setting name -> VideoCapture property
_PROPS = {
    "width": cv2.CAP_PROP_FRAME_WIDTH,
    "height": cv2.CAP_PROP_FRAME_HEIGHT,
    "fps": cv2.CAP_PROP_FPS,
    "exposure": cv2.CAP_PROP_EXPOSURE,
    "gain": cv2.CAP_PROP_GAIN,
}


class OpenCVCamera(Camera):
    """A ``cv2.VideoCapture`` source.

    Settings: ``device`` (int index, or a path/URL/``%0Nd`` pattern; fixed at open),
    ``width``, ``height``, ``fps``, ``exposure``, ``gain`` (whatever the driver accepts; each
    is read back and a mismatch raises :class:`CameraConfigError`).
    """

    backend = "opencv"

    def __init__(self, name: str, settings: dict | None = None):
        settings = dict(settings or {})
        self._device = settings.pop("device", 0)
        super().__init__(name, settings)
        self._cap: cv2.VideoCapture | None = None
        self._lock = threading.Lock()

    def _open(self) -> str:
        cap = cv2.VideoCapture(self._device)
        if not cap.isOpened():
            raise CameraNotFound(self.name, f"settings.device: OpenCV cannot open {self._device!r}")
        self._cap = cap
        return f"OpenCV {cap.getBackendName()} {self._device}"

    def _configure(self, settings: dict[str, Any]) -> dict[str, Any]:
        assert self._cap is not None
        for key, value in settings.items():
            if key in _PROPS:
                self._cap.set(_PROPS[key], float(value))
        out: dict[str, Any] = {"device": self._device}
        for key, prop in _PROPS.items():
            out[key] = self._cap.get(prop)
        out["width"], out["height"] = int(out["width"]), int(out["height"])
        return out

    def _grab(self, timeout: float) -> tuple[np.ndarray, float, int]:
        cap = self._cap
        if cap is None or not cap.isOpened():
            raise CameraDisconnected(self.name, "VideoCapture is closed")
        result: dict[str, Any] = {}

        def read() -> None:
            with self._lock:
                result["ok"], result["image"] = cap.read()
                result["pos"] = cap.get(cv2.CAP_PROP_POS_FRAMES)
                result["msec"] = cap.get(cv2.CAP_PROP_POS_MSEC)

        worker = threading.Thread(target=read, daemon=True, name=f"grab-{self.name}")
        worker.start()
        worker.join(timeout)
        if worker.is_alive():
            raise CameraTimeout(self.name, f"no frame within {timeout:g} s")
        if not result.get("ok"):
            raise CameraError(self.name, "VideoCapture.read() returned no frame (end of stream or device lost)")
        msec = result["msec"]
        ts = msec * 1e6 if msec and math.isfinite(msec) and msec > 0 else math.nan
        return result["image"], ts, int(result["pos"]) - 1

    def _close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None
