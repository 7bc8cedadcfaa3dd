"""Replay images from a folder (``*.png``, ``*.tif``, ...), in file-name order."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from acquisition.cameras.base import Camera, CameraError, CameraExhausted, CameraNotFound

__all__ = ["FolderCamera"]

_EXTS = (".png", ".tif", ".tiff", ".bmp", ".jpg", ".jpeg", ".pgm")


class FolderCamera(Camera):
    """A camera that replays the images of a folder.

    Settings: ``path`` (folder), ``pattern`` (glob, default every image), ``loop`` (bool,
    restart at the end instead of raising :class:`CameraExhausted`), ``start`` (index).
    Read-back adds ``n_images``, ``width``, ``height`` (of the first image).
    """

    backend = "folder"

    def __init__(self, name: str, settings: dict | None = None):
        super().__init__(name, settings)
        self._files: list[Path] = []
        self._cur: dict[str, Any] = {}
        self._index = 0

    def _open(self) -> str:
        path = Path(self.requested.get("path", ""))
        if not path.is_dir():
            raise CameraNotFound(self.name, f"settings.path: image folder {str(path)!r} does not exist")
        self._scan(path, self.requested.get("pattern", "*"))
        return f"image folder {path} ({len(self._files)} images)"

    def _scan(self, path: Path, pattern: str) -> None:
        files = sorted(p for p in path.glob(pattern) if p.suffix.lower() in _EXTS)
        if not files:
            raise CameraNotFound(self.name, f"no images matching {pattern!r} in {str(path)!r}")
        first = cv2.imread(str(files[0]), cv2.IMREAD_UNCHANGED)
        if first is None:
            raise CameraError(self.name, f"cannot read image {files[0]}")
        self._files = files
        self._cur = {"path": str(path), "pattern": pattern, "loop": False, "start": 0,
                     "n_images": len(files), "width": int(first.shape[1]), "height": int(first.shape[0])}

    def _configure(self, settings: dict[str, Any]) -> dict[str, Any]:
        if "path" in settings or "pattern" in settings:
            self._scan(Path(settings.get("path", self._cur["path"])), settings.get("pattern", self._cur["pattern"]))
        for key in ("loop", "start"):
            if key in settings:
                self._cur[key] = settings[key]
        if "start" in settings:
            self._index = int(settings["start"])
        return dict(self._cur)

    def _grab(self, timeout: float) -> tuple[np.ndarray, float, int]:
        if self._index >= len(self._files):
            if not self._cur["loop"]:
                raise CameraExhausted(self.name, f"all {len(self._files)} images replayed")
            self._index = 0
        path = self._files[self._index]
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise CameraError(self.name, f"cannot read image {path}")
        index = self._index
        self._index += 1
        return image, math.nan, index
