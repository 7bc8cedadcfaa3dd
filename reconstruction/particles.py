"""Small particles (a few pixels) in real images: threshold above the local background, connected
blobs, grey-weighted centroids, as particle-tracking tools do (OpenPTV ``targ_rec``).

Markers on tissue are discs of tens of pixels and go through :func:`reconstruction.detection.detect_markers`;
seeding particles are 1-5 px and need no disc model. Both return :class:`~reconstruction.detection.Detections`
with the same reject reasons. Pixels are OpenCV's (origin at the centre of the top-left pixel).
"""

from __future__ import annotations

import cv2
import numpy as np

from reconstruction.detection import Detections, _records, _concat, _empty

__all__ = ["detect_particles"]


def _background_removed(img: np.ndarray, polarity: str, background_px: int) -> np.ndarray:
    """Top-hat: the image minus its local background (opening for bright, closing for dark blobs)."""
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (background_px, background_px))
    if polarity == "bright":
        return img - cv2.morphologyEx(img, cv2.MORPH_OPEN, k)
    if polarity == "dark":
        return cv2.morphologyEx(img, cv2.MORPH_CLOSE, k) - img
    raise ValueError(f"polarity must be 'bright' (bright particles on a dark background) or 'dark'; got {polarity!r}")


def detect_particles(
    image: np.ndarray,
    *,
    polarity: str = "bright",
    threshold: float | None = None,
    threshold_sigma: float = 4.0,
    pixels_range: tuple[int, int] = (2, 200),
    min_sum: float = 0.0,
    edge_margin: int = 1,
    background_px: int = 9,
) -> Detections:
    """Detect small particles with grey-weighted sub-pixel centres.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        Grey-level image.
    polarity : {"bright", "dark"}
        Bright particles on a dark background (default) or the reverse.
    threshold : float, optional
        Grey levels above the local background a pixel needs; default ``threshold_sigma`` robust
        noise sigmas.
    pixels_range : (int, int)
        Accepted blob areas, px (``too_small`` / ``too_large`` outside).
    min_sum : float
        Minimum summed grey value above background (``low_contrast`` below).
    edge_margin : int
        Blobs touching this many border pixels are ``edge``.
    background_px : int
        Size of the structuring element that estimates the background, px (> particle size).

    Returns
    -------
    Detections
        ``diameter`` is the equivalent diameter of the blob area, ``contrast`` its peak above
        background relative to the background, ``quality`` minor/major axis, ``precision`` the
        centroid noise estimate.
    """
    image = np.asarray(image)
    if image.ndim != 2:
        raise ValueError(f"image must be a 2-D grey-level array (H, W); got shape {image.shape}")
    lo, hi = (int(v) for v in pixels_range)
    if not 1 <= lo <= hi:
        raise ValueError(f"pixels_range must be (min, max) with 1 <= min <= max px; got {pixels_range}")
    img = image.astype(np.float32)
    top = _background_removed(img, polarity, int(background_px) | 1)
    noise = float(1.4826 * np.median(np.abs(top - np.median(top)))) or 1.0
    thr = float(threshold) if threshold is not None else threshold_sigma * noise
    n, labels, stats, _ = cv2.connectedComponentsWithStats((top > thr).astype(np.uint8), connectivity=8)
    if n <= 1:
        return _empty(noise)
    return _blob_detections(top, labels, stats[1:], thr, noise, img, (lo, hi), min_sum, edge_margin)


def _blob_detections(top, labels, stats, thr, noise, img, area_range, min_sum, edge_margin) -> Detections:
    """Weighted centroids and shape of every labelled blob, then the reject gates."""
    n = stats.shape[0]
    H, W = top.shape
    lab = labels.ravel()
    fg = lab > 0
    idx = lab[fg] - 1
    w = (top.ravel()[fg] - thr * 0.5).clip(min=0.0)
    yy, xx = np.divmod(np.flatnonzero(fg), W)
    sw = np.bincount(idx, w, n)
    safe = np.where(sw > 0, sw, 1.0)
    cx, cy = np.bincount(idx, w * xx, n) / safe, np.bincount(idx, w * yy, n) / safe
    sxx = np.bincount(idx, w * xx * xx, n) / safe - cx**2
    syy = np.bincount(idx, w * yy * yy, n) / safe - cy**2
    sxy = np.bincount(idx, w * xx * yy, n) / safe - cx * cy
    tr, det = sxx + syy, sxx * syy - sxy**2
    disc = np.sqrt(np.maximum(tr**2 / 4 - det, 0))
    quality = np.sqrt(np.maximum(tr / 2 - disc, 0) / np.maximum(tr / 2 + disc, 1e-12))
    peak = np.full(n, -np.inf)
    np.maximum.at(peak, idx, top.ravel()[fg])
    bg = np.maximum(img.ravel()[fg] - top.ravel()[fg], 1.0)
    base = np.bincount(idx, bg, n) / np.maximum(np.bincount(idx, None, n), 1)
    area = stats[:, cv2.CC_STAT_AREA]
    diam = 2 * np.sqrt(area / np.pi)
    contrast = peak / base
    x0, y0 = stats[:, cv2.CC_STAT_LEFT], stats[:, cv2.CC_STAT_TOP]
    x1, y1 = x0 + stats[:, cv2.CC_STAT_WIDTH], y0 + stats[:, cv2.CC_STAT_HEIGHT]
    reason = np.full(n, "", dtype="U12")
    reason[np.bincount(idx, top.ravel()[fg] - thr, n) < min_sum] = "low_contrast"
    reason[area > area_range[1]] = "too_large"
    reason[area < area_range[0]] = "too_small"
    reason[(x0 < edge_margin) | (y0 < edge_margin) | (x1 > W - edge_margin) | (y1 > H - edge_margin)] = "edge"
    ok = reason == ""
    xy = np.stack([cx, cy], axis=1)
    rejects = _concat([_records(xy[reason == r], diam[reason == r], contrast[reason == r], r)
                       for r in ("too_small", "too_large", "edge", "low_contrast")])
    precision = noise * np.sqrt(np.maximum(tr, 0.25)) / np.maximum(sw, 1e-12) * np.sqrt(area)
    return Detections(xy[ok], diam[ok], contrast[ok], quality[ok], precision[ok], rejects, noise)
