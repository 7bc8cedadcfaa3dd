"""A camera whose pixels come from an injected function: the simulated cameras.

The rig simulator (``rig_sim``) renders the specimen at the current deformation; the CLI's
``--sim`` wiring passes that renderer here, so ``acquisition`` never imports ``rig_sim``.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from acquisition.cameras.base import Camera, CameraDisconnected, CameraError, CameraTimeout

__all__ = ["FunctionCamera"]


class FunctionCamera(Camera):
    """Frames from ``render(settings) -> ndarray (H, W)``.

    Parameters
    ----------
    name : str
    render : callable
        Called with the current settings dict (``width``, ``height``, ``exposure_us``, ...);
        returns the image. May raise :class:`CameraError` (e.g. a simulated fault).
    settings : dict
        Initial settings; ``width``/``height`` in pixels are required by most renderers.
    identity : str
    latency_s : float
        Simulated readout time, s.
    """

    backend = "sim"
    real_time = False  # rendering takes what it takes: never timed out by capture_all (Camera.real_time)

    def __init__(self, name: str, render: Callable[[dict], np.ndarray], settings: dict | None = None,
                 identity: str = "", latency_s: float = 0.0):
        super().__init__(name, settings)
        self._render = render
        self._identity = identity or f"simulated camera {name}"
        self._latency = float(latency_s)
        self._current: dict[str, Any] = {"width": 640, "height": 480, "exposure_us": 10000.0, "gain_db": 0.0}
        self._t0 = time.monotonic()
        self.unplugged = False  # fault injection: grab raises CameraDisconnected
        self.stalled = False  # fault injection: grab times out
        self._lock = threading.Lock()

    def _open(self) -> str:
        return self._identity

    def _configure(self, settings: dict[str, Any]) -> dict[str, Any]:
        for key in settings:
            if key not in self._current:
                return dict(self._current)  # base class names the unsupported key
        self._current.update(settings)
        return dict(self._current)

    def _grab(self, timeout: float) -> tuple[np.ndarray, float, int]:
        if self.unplugged:
            raise CameraDisconnected(self.name, "simulated camera unplugged")
        if self.stalled or self._latency > timeout:
            time.sleep(min(timeout, 0.05))
            raise CameraTimeout(self.name, f"no frame within {timeout:g} s")
        if self._latency:
            time.sleep(self._latency)
        with self._lock:
            try:
                image = np.asarray(self._render(dict(self._current)))
            except CameraError:
                raise
            except Exception as exc:  # renderer bug -> a camera error with the cause
                raise CameraError(self.name, f"renderer failed: {exc}") from exc
        w, h = int(self._current["width"]), int(self._current["height"])
        if image.shape[:2] != (h, w):
            raise CameraError(self.name, f"renderer returned shape {image.shape}, expected ({h}, {w})")
        device_ts = (time.monotonic() - self._t0) * 1e9  # ns, like Basler's tick counter
        return image, device_ts if math.isfinite(device_ts) else math.nan, -1
