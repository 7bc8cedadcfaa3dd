"""What a marker detector returns: :class:`Detections` (centres, diameters, contrasts and the rejected
candidates with their reason), the reject record type and the helpers that build them. Shared by
:mod:`reconstruction.detection` and :mod:`reconstruction.particles`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["REJECT_DTYPE", "REJECT_REASONS", "Detections"]

REJECT_REASONS = ("too_small", "too_large", "merged", "not_round", "edge", "low_contrast", "glare")
REJECT_DTYPE = np.dtype(
    [("x", "f8"), ("y", "f8"), ("diameter", "f8"), ("contrast", "f8"), ("reason", "U12")]
)


@dataclass(frozen=True)
class Detections:
    """Markers found in one image.

    Attributes
    ----------
    centres : ndarray, shape (n, 2)
        Sub-pixel centres, px (OpenCV convention).
    diameter : ndarray, shape (n,)
        Equivalent diameter of the half-contrast area, px.
    contrast : ndarray, shape (n,)
        Relative darkness at the core, ``1 - I_core / I_background`` (0..1).
    quality : ndarray, shape (n,)
        Roundness: minor / major axis of the half-contrast area (1 = circle); 0.5 for the two
        centres recovered from a split merged blob.
    precision : ndarray, shape (n,)
        Estimated 1-sigma centre uncertainty per coordinate from image noise, px.
    rejects : structured ndarray, dtype REJECT_DTYPE, shape (n_rejects,)
        Rejected candidates with ``reason`` in ``REJECT_REASONS``.
    noise : float
        Robust estimate of the image noise, grey levels.
    threshold : float
        Candidate threshold on the black top-hat, grey levels (with ``noise``: the image's
        ``levels`` for :func:`detect_markers_near`).
    """

    centres: np.ndarray
    diameter: np.ndarray
    contrast: np.ndarray
    quality: np.ndarray
    precision: np.ndarray
    rejects: np.ndarray
    noise: float
    threshold: float = float("nan")

    def __len__(self) -> int:
        return int(self.centres.shape[0])

    def reject_counts(self) -> dict[str, int]:
        """Number of rejected candidates per reason."""
        return {r: int(np.count_nonzero(self.rejects["reason"] == r)) for r in REJECT_REASONS}


def _empty(noise: float, rejects: np.ndarray | None = None, threshold: float = float("nan")) -> Detections:
    z = np.zeros(0)
    return Detections(
        np.zeros((0, 2)), z, z.copy(), z.copy(), z.copy(),
        np.zeros(0, REJECT_DTYPE) if rejects is None else rejects, float(noise), float(threshold),
    )


def _records(xy, diam, contrast, reason) -> np.ndarray:
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    rec = np.zeros(xy.shape[0], REJECT_DTYPE)
    rec["x"], rec["y"] = xy[:, 0], xy[:, 1]
    rec["diameter"] = diam
    rec["contrast"] = contrast
    rec["reason"] = reason
    return rec


def _concat(parts: list[np.ndarray]) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros(0, REJECT_DTYPE)
