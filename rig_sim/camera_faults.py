"""Camera faults of the simulated rig, applied to a rendered image: defocus and over-exposure.

A marker-less camera is rendered rather than post-processed (:class:`vfmlab.simrig.SimScene` renders the
specimen without its markers for it). These feed ``vfmlab check-rig``'s tests: each must be flagged.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["defocus", "overexpose"]


def defocus(image: np.ndarray, sigma_px: float) -> np.ndarray:
    """``image`` (H, W) blurred by a Gaussian of ``sigma_px`` px (a lens out of focus), same dtype."""
    if not sigma_px > 0:
        raise ValueError(f"sigma_px must be > 0 px; got {sigma_px}")
    out = cv2.GaussianBlur(image.astype(np.float32), (0, 0), float(sigma_px), borderType=cv2.BORDER_REFLECT)
    return _as(out, image.dtype)


def overexpose(image: np.ndarray, gain: float = 4.0) -> np.ndarray:
    """``image`` (H, W) with its grey levels times ``gain``, clipped at the dtype's full scale (same dtype)."""
    if not gain > 0:
        raise ValueError(f"gain must be > 0; got {gain}")
    return _as(image.astype(np.float32) * float(gain), image.dtype)


def _as(values: np.ndarray, dtype: np.dtype) -> np.ndarray:
    if np.issubdtype(dtype, np.integer):
        top = np.iinfo(dtype).max
        return np.clip(np.rint(values), 0, top).astype(dtype)
    return values.astype(dtype)
