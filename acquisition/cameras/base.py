"""The camera interface: open, configure with read-back, grab(timeout) -> Frame; typed errors.

Every backend (simulated/injected function, image folder, OpenCV ``VideoCapture``, Basler
``pypylon``) implements :class:`Camera`. Pixels are monochrome ``(H, W)`` arrays (uint8 or
uint16), OpenCV pixel convention. Times: ``t_monotonic`` (host ``time.monotonic``, s) and
``t_wall`` (host ``time.time``, s) taken when the frame arrived on the host;
``device_timestamp`` is the camera's own clock in its unit (NaN if it has none).
"""

from __future__ import annotations

import logging
import math
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "CameraError",
    "CameraNotFound",
    "CameraTimeout",
    "CameraDisconnected",
    "CameraConfigError",
    "CameraExhausted",
    "Frame",
    "Camera",
    "to_mono",
]

log = logging.getLogger(__name__)


class CameraError(RuntimeError):
    """Any camera fault; ``camera`` names the camera."""

    def __init__(self, camera: str, message: str):
        super().__init__(f"camera {camera!r}: {message}")
        self.camera = camera


class CameraNotFound(CameraError):
    """The device (index, serial, folder) does not exist or cannot be opened."""


class CameraTimeout(CameraError):
    """No frame arrived within the timeout."""


class CameraDisconnected(CameraError):
    """The camera went away (unplugged, closed)."""


class CameraConfigError(CameraError):
    """A setting was refused, or read back different from what was asked."""


class CameraExhausted(CameraError):
    """A replay source has no more frames."""


@dataclass(frozen=True)
class Frame:
    """One image.

    Attributes
    ----------
    pixels : ndarray, shape (H, W)
        uint8 or uint16 monochrome image.
    t_monotonic, t_wall : float
        Host arrival times, s (``time.monotonic()`` / ``time.time()``).
    device_timestamp : float
        Camera clock (backend unit, e.g. ns for Basler), NaN if none.
    frame_id : int
        Camera's frame counter (or the backend's own count from 0).
    camera : str
    """

    pixels: np.ndarray
    t_monotonic: float
    t_wall: float
    device_timestamp: float = math.nan
    frame_id: int = -1
    camera: str = ""
    meta: dict = field(default_factory=dict, compare=False)


def to_mono(image: np.ndarray) -> np.ndarray:
    """``(H, W)`` or ``(H, W, 3|4)`` BGR(A) -> ``(H, W)`` monochrome, dtype kept."""
    image = np.asarray(image)
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] in (3, 4):
        weights = np.array([0.114, 0.587, 0.299])  # B, G, R (ITU-R 601, as cv2.cvtColor)
        mono = image[..., :3] @ weights
        if np.issubdtype(image.dtype, np.integer):
            mono = np.clip(np.rint(mono), 0, np.iinfo(image.dtype).max)
        return mono.astype(image.dtype)
    if image.ndim == 3 and image.shape[2] == 1:
        return image[..., 0]
    raise ValueError(f"image: expected shape (H, W) or (H, W, 3); got {image.shape}")


class Camera(ABC):
    """A camera. Use as a context manager, or call :meth:`open` / :meth:`close`.

    Subclasses implement ``_open``, ``_configure``, ``_grab`` and ``_close``; this base class
    keeps the open/closed state, checks read-back, stamps host times and counts frames.
    """

    backend: str = "?"
    #: True: a device that delivers in real time, so no frame within the capture timeout is a fault.
    #: False: a simulation, whose frame takes as long as computing it takes: :func:`capture_all` does not
    #: time it out on the wall clock, so a slow or busy machine slows a simulated test but never fails it
    #: (the camera can still raise :class:`CameraTimeout` itself, e.g. a simulated stall).
    real_time: bool = True

    def __init__(self, name: str, settings: dict | None = None):
        self.name = name
        self.requested: dict[str, Any] = dict(settings or {})
        self.settings: dict[str, Any] = {}
        self.identity: str = ""
        self._open_flag = False
        self._count = 0

    # ------------------------------------------------------------------ public
    @property
    def is_open(self) -> bool:
        return self._open_flag

    def open(self) -> Camera:
        """Open the device and apply the settings given at construction; returns self."""
        if not self._open_flag:
            self.identity = self._open()
            self._open_flag = True
            log.info("camera %s opened: %s", self.name, self.identity)
            self.configure(**self.requested)
        return self

    def configure(self, **settings: Any) -> dict[str, Any]:
        """Apply settings and return every setting as read back from the device.

        Raises
        ------
        CameraConfigError
            A setting is unknown to the backend or reads back different from the request
            (numbers compared to 1e-6 relative).
        """
        self._require_open()
        readback = self._configure(dict(settings))
        for key, want in settings.items():
            if key not in readback:
                raise CameraConfigError(self.name, f"setting {key!r} is not supported by the {self.backend} "
                                                   f"backend (supported: {sorted(readback)})")
            got = readback[key]
            if not _same(want, got):
                raise CameraConfigError(self.name, f"setting {key!r}: asked for {want!r}, device reads back {got!r}")
        self.settings = dict(readback)
        return dict(readback)

    def grab(self, timeout: float = 2.0) -> Frame:
        """Acquire one frame within ``timeout`` seconds.

        Raises
        ------
        CameraTimeout, CameraDisconnected, CameraExhausted, CameraError
        """
        self._require_open()
        if not (timeout > 0):
            raise ValueError(f"timeout: expected a positive number of seconds; got {timeout!r}")
        pixels, device_ts, frame_id = self._grab(float(timeout))
        t_mono, t_wall = time.monotonic(), time.time()
        pixels = to_mono(pixels)
        if frame_id < 0:
            frame_id = self._count
        self._count += 1
        return Frame(pixels, t_mono, t_wall, float(device_ts), int(frame_id), self.name)

    def close(self) -> None:
        if self._open_flag:
            self._open_flag = False
            try:
                self._close()
            except Exception:  # noqa: BLE001 - closing must not raise over the original error
                log.exception("camera %s: error while closing", self.name)

    def describe(self) -> dict[str, Any]:
        """JSON-able description for the session file."""
        return {"name": self.name, "backend": self.backend, "identity": self.identity, "settings": self.settings}

    def __enter__(self) -> Camera:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ backend hooks
    @abstractmethod
    def _open(self) -> str:
        """Open the device; return an identity string (model + serial)."""

    @abstractmethod
    def _configure(self, settings: dict[str, Any]) -> dict[str, Any]:
        """Apply ``settings``; return all current settings read back."""

    @abstractmethod
    def _grab(self, timeout: float) -> tuple[np.ndarray, float, int]:
        """Return ``(pixels, device_timestamp or NaN, frame_id or -1)``."""

    def _close(self) -> None:  # noqa: B027 (a hook: cameras with nothing to release keep it empty)
        """Release the device."""

    def _require_open(self) -> None:
        if not self._open_flag:
            raise CameraDisconnected(self.name, "camera is not open (call open() first)")


def _same(want: Any, got: Any) -> bool:
    if isinstance(want, (int, float)) and not isinstance(want, bool) and isinstance(got, (int, float)):
        return math.isclose(float(want), float(got), rel_tol=1e-6, abs_tol=1e-9)
    return want == got
