"""Image formation common to all simulated cameras: illumination, defocus, shot and read noise."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["SensorModel", "illumination_field", "expose"]


@dataclass(frozen=True)
class SensorModel:
    """Exposure, optics blur and noise of a simulated camera.

    Attributes
    ----------
    full_well : float
        Electrons at radiance 1 (a perfect white surface under the brightest illumination).
    exposure : float
        Fraction of full scale a radiance of 1 reaches (0.9: white nearly saturates).
    read_noise : float
        Read noise, electrons RMS.
    blur_sigma : float
        Gaussian defocus blur, px (0 = sharp).
    bit_depth : int
        8 -> uint8 output, 12 or 16 -> uint16 output.
    vignetting : float
        Relative illumination drop at the image corners (0.25 = 25 % darker).
    gradient : float
        Relative linear illumination gradient across the image.
    poisson : bool
        Exact Poisson shot noise (slower) instead of its Gaussian approximation.
    """

    full_well: float = 12000.0
    exposure: float = 0.9
    read_noise: float = 6.0
    blur_sigma: float = 0.8
    bit_depth: int = 8
    vignetting: float = 0.25
    gradient: float = 0.1
    poisson: bool = False

    @property
    def dtype(self) -> type:
        return np.uint8 if self.bit_depth <= 8 else np.uint16


def illumination_field(u: np.ndarray, v: np.ndarray, size: tuple[int, int], sensor: SensorModel, phase: float = 0.0) -> np.ndarray:
    """Relative illumination at pixels (u, v): vignetting plus a tilted gradient, <= 1."""
    w, h = size
    du = (u - w / 2) / (w / 2)
    dv = (v - h / 2) / (w / 2)
    rad2 = (du * du + dv * dv) / (1 + (h / w) ** 2)
    grad = 0.5 * (du * np.cos(phase) + dv * np.sin(phase))
    return (1 - sensor.vignetting * rad2) * (1 - sensor.gradient * (0.5 - grad))


def expose(radiance: np.ndarray, sensor: SensorModel, rng: np.random.Generator) -> np.ndarray:
    """Blur, add shot and read noise, quantise.

    Parameters
    ----------
    radiance : ndarray, shape (H, W)
        Relative scene radiance (1 = white under full illumination), float32.
    sensor : SensorModel
    rng : numpy Generator

    Returns
    -------
    ndarray, shape (H, W), uint8 or uint16
    """
    img = np.asarray(radiance, np.float32)
    if sensor.blur_sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), sensor.blur_sigma, borderType=cv2.BORDER_REFLECT)
    electrons = np.clip(img, 0, None) * np.float32(sensor.full_well * sensor.exposure)
    if sensor.poisson:
        electrons = rng.poisson(electrons).astype(np.float32)
    else:
        electrons = electrons + np.sqrt(electrons) * rng.standard_normal(electrons.shape, dtype=np.float32)
    electrons += np.float32(sensor.read_noise) * rng.standard_normal(electrons.shape, dtype=np.float32)
    max_dn = 2 ** min(sensor.bit_depth, 16) - 1
    dn = electrons * np.float32(max_dn / sensor.full_well)
    return np.clip(np.rint(dn), 0, max_dn).astype(sensor.dtype)
