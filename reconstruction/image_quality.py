"""How fit one camera image is for marker tracking: the pre-flight metrics of ``vfmlab check-rig``.

Pure functions over an image and its :class:`~reconstruction.detection.Detections` (no files, ports or
clock). Pixel coordinates are OpenCV's (x right, y down).

Metrics
-------
- ``n_markers``: accepted detections.
- ``sharpness``: variance of the Laplacian of the image divided by the variance of the image (a
  focus measure that does not change with exposure or gain; Pech-Pacheco et al. 2000).
- ``edge_width_px``: median over the markers of ``(background - core) / max |grad I|`` on the marker's
  patch. A step edge blurred by a Gaussian of sigma s has a width ``sqrt(2 pi) s`` ~ 2.5 s by this measure,
  so it grows linearly with defocus and does not depend on the illumination.
- ``saturated_fraction``: fraction of pixels at or above the saturation level.
- ``contrast``: median relative darkness of the accepted markers (``Detections.contrast``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from reconstruction.cameras import Camera
from reconstruction.correspondence import match_views
from reconstruction.detection_records import Detections

__all__ = ["ImageQuality", "image_quality", "saturation_level", "markers_in_views"]


@dataclass(frozen=True)
class ImageQuality:
    """Pre-flight metrics of one image (see the module docstring); NaN where there is nothing to measure."""

    n_markers: int
    sharpness: float
    edge_width_px: float
    saturated_fraction: float
    contrast: float
    noise: float

    def to_dict(self) -> dict[str, float]:
        return {"n_markers": self.n_markers, "sharpness": self.sharpness, "edge_width_px": self.edge_width_px,
                "saturated_fraction": self.saturated_fraction, "contrast": self.contrast, "noise": self.noise}


def saturation_level(image: np.ndarray) -> float:
    """Grey level counted as saturated: the integer dtype's maximum, else the image maximum (float images)."""
    if np.issubdtype(image.dtype, np.integer):
        return float(np.iinfo(image.dtype).max)
    return float(np.nanmax(image)) if image.size else math.nan


def _edge_widths(image: np.ndarray, det: Detections) -> np.ndarray:
    """Per marker ``(background - core) / max |grad|`` on a patch of twice its diameter, px; shape (n,)."""
    n = len(det)
    if n == 0:
        return np.empty(0)
    img = image.astype(np.float32)
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    grad = np.hypot(gx, gy)
    H, W = img.shape
    half = int(np.clip(np.ceil(np.nanmedian(det.diameter)), 3, 40))
    cx = np.clip(np.round(det.centres[:, 0]).astype(int), half, W - half - 1)
    cy = np.clip(np.round(det.centres[:, 1]).astype(int), half, H - half - 1)
    size = 2 * half + 1
    view = np.lib.stride_tricks.sliding_window_view
    patch = view(img, (size, size))[cy - half, cx - half]  # (n, P, P)
    gpatch = view(grad, (size, size))[cy - half, cx - half]
    flat = patch.reshape(n, -1)
    step = np.percentile(flat, 90, axis=1) - np.percentile(flat, 2, axis=1)
    peak = gpatch.reshape(n, -1).max(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(peak > 0, step / peak, np.nan)


def image_quality(image: np.ndarray, detections: Detections) -> ImageQuality:
    """Pre-flight metrics of ``image`` (shape (H, W), grey levels) with its ``detections``."""
    image = np.asarray(image)
    if image.ndim != 2 or image.size == 0:
        raise ValueError(f"image must be a non-empty 2-D grey-level array (H, W); got shape {image.shape}")
    img = image.astype(np.float64)
    var = float(img.var())
    lap = cv2.Laplacian(img, cv2.CV_64F, ksize=3)
    sharpness = float(lap.var() / var) if var > 0 else 0.0
    level = saturation_level(image)
    saturated = float(np.count_nonzero(image >= level) / image.size) if math.isfinite(level) else 0.0
    widths = _edge_widths(image, detections)
    n = len(detections)
    return ImageQuality(
        n_markers=n, sharpness=sharpness,
        edge_width_px=float(np.nanmedian(widths)) if n and np.any(np.isfinite(widths)) else math.nan,
        saturated_fraction=saturated,
        contrast=float(np.median(detections.contrast)) if n else math.nan,
        noise=float(detections.noise))


def markers_in_views(centres: list[np.ndarray], cameras: list[Camera], *, epipolar_px: float = 2.0,
                     max_reprojection_px: float = 1.5) -> tuple[int, np.ndarray]:
    """Markers seen by at least two cameras: ``(n_points, per_camera)``.

    Parameters
    ----------
    centres : list of ndarray, shape (n_i, 2)
        Detected centres per camera, px, in the order of ``cameras``.
    cameras : list of Camera
        The rig's calibration.

    Returns
    -------
    n_points : int
        Markers matched in two or more views and triangulated (:func:`reconstruction.match_views`).
    per_camera : ndarray of int, shape (n_cameras,)
        How many of each camera's detections belong to such a marker.
    """
    if len(centres) != len(cameras):
        raise ValueError(f"centres and cameras must have the same length; got {len(centres)} and {len(cameras)}")
    if len(cameras) < 2:
        return 0, np.zeros(len(cameras), int)
    corr = match_views([np.asarray(c, float).reshape(-1, 2) for c in centres], cameras, epipolar_px=epipolar_px,
                       max_reprojection_px=max_reprojection_px)
    obs = corr.observations
    return int(obs.shape[0]), (obs >= 0).sum(axis=0).astype(int) if obs.size else np.zeros(len(cameras), int)
