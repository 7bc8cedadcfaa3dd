"""Capture every camera at once, as one operation with one timeout; failures are reported."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

from acquisition.cameras.base import Camera, CameraError, CameraTimeout, Frame

__all__ = ["CaptureError", "CaptureResult", "capture_all", "open_camera"]

log = logging.getLogger(__name__)


class CaptureError(CameraError):
    """One or more cameras failed during a capture.

    Attributes
    ----------
    failures : dict[str, CameraError]
        Camera name -> its error.
    frames : dict[str, Frame]
        Frames of the cameras that succeeded (not to be stored alone: the step is retried).
    """

    def __init__(self, failures: Mapping[str, Exception], frames: Mapping[str, Frame]):
        names = ", ".join(sorted(failures))
        detail = "; ".join(str(e) for e in failures.values())
        RuntimeError.__init__(self, f"capture failed on camera(s) {names}: {detail}")
        self.camera = names
        self.failures = dict(failures)
        self.frames = dict(frames)


@dataclass(frozen=True)
class CaptureResult:
    """Frames of every camera (name -> Frame) and the host time span of the capture, s."""

    frames: dict[str, Frame]
    t_start: float
    t_end: float

    @property
    def spread_s(self) -> float:
        """Largest difference between the cameras' host arrival times, s."""
        t = [f.t_monotonic for f in self.frames.values()]
        return max(t) - min(t) if t else 0.0


def capture_all(cameras: Sequence[Camera], timeout: float) -> CaptureResult:
    """Grab one frame from every camera in parallel, all within ``timeout`` seconds.

    ``timeout`` bounds the real-time cameras only: a simulated camera (``Camera.real_time`` False) is waited
    for as long as it computes its frame, so a loaded machine slows a simulated test but does not fail it.

    Raises
    ------
    CaptureError
        If any camera fails or does not deliver in time; ``failures`` names each one (a
        camera is never silently skipped).
    """
    if not cameras:
        raise ValueError("cameras: expected at least one camera to capture")
    frames: dict[str, Frame] = {}
    failures: dict[str, Exception] = {}
    lock = threading.Lock()
    t_start = time.monotonic()

    def grab(cam: Camera) -> None:
        try:
            frame = cam.grab(timeout)
        except Exception as exc:  # noqa: BLE001 - reported per camera
            with lock:
                failures.setdefault(cam.name, exc if isinstance(exc, CameraError) else CameraError(cam.name, repr(exc)))
            return
        with lock:
            if cam.name not in failures:  # a real-time frame after the deadline stays a timeout
                frames[cam.name] = frame

    threads = {c.name: threading.Thread(target=grab, args=(c,), daemon=True, name=f"capture-{c.name}")
               for c in cameras}
    for t in threads.values():
        t.start()
    deadline = t_start + timeout
    for cam in cameras:  # the real-time cameras by the deadline ...
        if cam.real_time:
            threads[cam.name].join(max(0.0, deadline - time.monotonic()) + 0.05)
    with lock:
        for cam in cameras:
            if cam.real_time and cam.name not in frames and cam.name not in failures:
                failures[cam.name] = CameraTimeout(cam.name, f"no frame within the capture timeout {timeout:g} s")
    for cam in cameras:  # ... the simulated ones for as long as they compute
        if not cam.real_time:
            threads[cam.name].join()
    with lock:
        if failures:
            log.warning("capture failed: %s", ", ".join(f"{k}: {v}" for k, v in failures.items()))
            raise CaptureError(failures, frames)
        return CaptureResult(dict(frames), t_start, time.monotonic())


def open_camera(name: str, backend: str, settings: dict | None = None,
                factories: Mapping[str, Callable[[str, dict], Camera]] | None = None) -> Camera:
    """Build (not open) a camera from a rig-file entry.

    Parameters
    ----------
    backend : str
        'folder', 'opencv', 'basler', or any key of ``factories`` (e.g. 'sim', injected by the
        CLI's simulated-rig wiring).
    factories : mapping, optional
        Extra backends: ``backend -> factory(name, settings) -> Camera``.
    """
    settings = dict(settings or {})
    if factories and backend in factories:
        return factories[backend](name, settings)
    if backend == "folder":
        from acquisition.cameras.folder import FolderCamera
        return FolderCamera(name, settings)
    if backend == "opencv":
        from acquisition.cameras.opencv import OpenCVCamera
        return OpenCVCamera(name, settings)
    if backend == "basler":
        from acquisition.cameras.basler import BaslerCamera
        return BaslerCamera(name, settings)
    known = ["folder", "opencv", "basler", *sorted(factories or {})]
    hint = " ('sim' cameras exist only with --sim)" if backend == "sim" else ""
    raise ValueError(f"backend: expected one of {known}{hint}; got {backend!r}")
