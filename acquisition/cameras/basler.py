"""Basler cameras through ``pypylon`` (optional). Tested against pylon's camera emulation
(``PYLON_CAMEMU=N`` in the environment creates N emulated cameras, no hardware needed)."""

from __future__ import annotations

from typing import Any

import numpy as np

from acquisition.cameras.base import (Camera, CameraConfigError, CameraDisconnected, CameraError, CameraNotFound,
                                      CameraTimeout)

__all__ = ["BaslerCamera", "pylon_available"]

# setting name -> GenICam feature
_FEATURES = {
    "width": "Width",
    "height": "Height",
    "offset_x": "OffsetX",
    "offset_y": "OffsetY",
    "exposure_us": "ExposureTime",
    "gain_db": "Gain",
    "pixel_format": "PixelFormat",
}


def pylon_available() -> bool:
    """True if ``pypylon`` is installed (checked without importing it: importing pylon's native
    libraries is slow and, inside some hosts such as pytest, has been seen to crash the process)."""
    import importlib.util

    return importlib.util.find_spec("pypylon") is not None


class BaslerCamera(Camera):
    """A Basler GenICam camera.

    Settings: ``serial`` (serial number; fixed at open; '' = first camera found), ``width``,
    ``height``, ``offset_x``, ``offset_y``, ``exposure_us``, ``gain_db``, ``pixel_format``
    (``"Mono8"``/``"Mono12"``...). Device timestamps are the camera's tick counter (ns on most
    models); frame ids are the camera's ``BlockID``.
    """

    backend = "basler"

    def __init__(self, name: str, settings: dict | None = None):
        settings = dict(settings or {})
        self._serial = str(settings.pop("serial", ""))
        super().__init__(name, settings)
        self._cam = None
        self._pylon = None

    def _open(self) -> str:
        try:
            from pypylon import genicam, pylon
        except ImportError as exc:
            raise CameraNotFound(self.name, "backend 'basler' needs pypylon (pip install pypylon)") from exc
        self._pylon, self._genicam = pylon, genicam
        factory = pylon.TlFactory.GetInstance()
        devices = factory.EnumerateDevices()
        chosen = [d for d in devices if not self._serial or d.GetSerialNumber() == self._serial]
        if not chosen:
            found = [d.GetSerialNumber() for d in devices]
            raise CameraNotFound(self.name, f"settings.serial: no Basler camera {self._serial!r} (found {found})")
        try:
            cam = pylon.InstantCamera(factory.CreateDevice(chosen[0]))
            cam.Open()
        except genicam.GenericException as exc:
            raise CameraNotFound(self.name, f"cannot open Basler {self._serial!r}: {exc}") from exc
        self._cam = cam
        info = cam.GetDeviceInfo()
        return f"Basler {info.GetModelName()} {info.GetSerialNumber()}"

    def _node(self, feature: str):
        node = getattr(self._cam, feature, None)
        if node is None:
            return None
        try:
            if not self._genicam.IsReadable(node):
                return None
        except Exception:  # noqa: BLE001 - feature missing on this model
            return None
        return node

    def _configure(self, settings: dict[str, Any]) -> dict[str, Any]:
        for key, value in settings.items():
            if key not in _FEATURES:
                continue  # base class reports the unsupported key
            node = self._node(_FEATURES[key])
            if node is None:
                raise CameraConfigError(self.name, f"setting {key!r}: feature {_FEATURES[key]} not available")
            try:
                node.SetValue(value)
            except self._genicam.GenericException as exc:
                raise CameraConfigError(self.name, f"setting {key!r} = {value!r} refused: {exc}") from exc
        out: dict[str, Any] = {"serial": self._serial}
        for key, feature in _FEATURES.items():
            node = self._node(feature)
            if node is not None:
                out[key] = node.GetValue()
        return out

    def _grab(self, timeout: float) -> tuple[np.ndarray, float, int]:
        pylon, cam = self._pylon, self._cam
        if cam is None or not cam.IsOpen():
            raise CameraDisconnected(self.name, "camera is closed or was removed")
        try:
            if not cam.IsGrabbing():
                cam.StartGrabbing(pylon.GrabStrategy_LatestImageOnly)
            result = cam.RetrieveResult(int(timeout * 1000), pylon.TimeoutHandling_Return)
        except self._genicam.GenericException as exc:
            if cam.IsCameraDeviceRemoved():
                raise CameraDisconnected(self.name, f"device removed: {exc}") from exc
            raise CameraError(self.name, f"grab failed: {exc}") from exc
        if result is None or not result.IsValid():
            raise CameraTimeout(self.name, f"no frame within {timeout:g} s")
        try:
            if not result.GrabSucceeded():
                raise CameraError(self.name, f"grab failed: {result.ErrorCode} {result.ErrorDescription}")
            return np.array(result.Array, copy=True), float(result.TimeStamp), int(result.BlockID)
        finally:
            result.Release()

    def _close(self) -> None:
        if self._cam is not None:
            if self._cam.IsGrabbing():
                self._cam.StopGrabbing()
            self._cam.Close()
            self._cam = None
