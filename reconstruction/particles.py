"""Small particles (a few pixels) in real images: threshold above the local background, connected
blobs, grey-weighted centroids, as particle-tracking tools do (OpenPTV ``targ_rec``).

Markers on tissue are discs of tens of pixels and go through :func:`reconstruction.detection.detect_markers`;
seeding particles are 1-5 px and need no disc model. Both return :class:`~reconstruction.detection.Detections`
with the same reject reasons. Pixels are OpenCV's (origin at the centre of the top-left pixel).
"""

from __future__ import annotations

import cv2
import numpy as np

from reconstruction.detection_records import Detections, _concat, _empty, _records
from reconstruction.particle_centres import (CENTRE_ESTIMATORS, HYBRID_SPLIT, MATCHED_FILTER_PX, gauss2d_centres,
                                             gauss3_centres, peak_pixels)

__all__ = ["detect_particles"]

#: Gaussian sigma (px) of the smoothing before peaks are split (noise peaks of a single particle merge)
SPLIT_SMOOTHING_PX = 1.0
#: the centroid's weights are the grey levels above this fraction of the threshold
CENTROID_WEIGHT_OFFSET = 0.5


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
    split_touching: bool = False,
    centre: str = "centroid",
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
    split_touching : bool
        Split blobs with several intensity peaks into one particle per peak (every pixel goes to the
        peak its steepest ascent reaches), as OpenPTV's ``targ_rec`` does; for dense seeding, where
        particle images touch. Off for large dots, whose noisy tops would be split.
    centre : {"centroid", "gauss3", "gauss3_smoothed", "gauss2d", "hybrid"}
        Sub-pixel centre estimator (:mod:`reconstruction.particle_centres`): grey-weighted centroid of the
        blob (default), three-point Gaussian per axis through the brightest pixel (of the image, or of the
        image smoothed by a matched Gaussian filter), a least-squares 2-D Gaussian on the 5 x 5 window
        around it with touching neighbours fitted jointly, or ``hybrid`` (the 2-D fit for particles split
        from a blob with others, the centroid for the others). On test_cavity's real images the centroid
        gives the most real matches (``docs/validation/reconstruction.md``, "Particle centres").

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
    if centre not in CENTRE_ESTIMATORS:
        raise ValueError(f"centre must be one of {CENTRE_ESTIMATORS}; got {centre!r}")
    lo, hi = (int(v) for v in pixels_range)
    if not 1 <= lo <= hi:
        raise ValueError(f"pixels_range must be (min, max) with 1 <= min <= max px; got {pixels_range}")
    img = image.astype(np.float32)
    top = _background_removed(img, polarity, int(background_px) | 1)
    noise = float(1.4826 * np.median(np.abs(top - np.median(top)))) or 1.0
    thr = float(threshold) if threshold is not None else threshold_sigma * noise
    mask = (top > thr).astype(np.uint8)
    if split_touching:
        n, labels, stats = _peak_regions(top, mask.astype(bool))
    else:
        n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return _empty(noise)
    refine = None
    if centre != "centroid":
        refine = {"centre": centre, "valid": _unsaturated(image) if centre in ("gauss2d", "hybrid") else None,
                  "blobs": cv2.connectedComponents(mask, connectivity=8)[1] if split_touching else labels}
    return _blob_detections(top, labels, stats[1:], thr, noise, img, (lo, hi), min_sum, edge_margin, refine)


def _peak_regions(top: np.ndarray, mask: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    """Watershed by steepest ascent, vectorised: every foreground pixel points to its highest 8-neighbour
    in the foreground (itself at a peak), pointers are followed to their root by doubling, one region
    per root. Returns ``(n_labels + 1, labels (H, W) with 0 = background, stats)`` as
    ``cv2.connectedComponentsWithStats`` does (left, top, width, height, area)."""
    H, W = top.shape
    # a light smoothing and a tiny position ramp break the plateaus of 8-bit images
    height = cv2.GaussianBlur(top, (0, 0), SPLIT_SMOOTHING_PX).astype(np.float64)
    height += np.arange(H * W).reshape(H, W) * 1e-9
    height[~mask] = -np.inf
    padded = np.pad(height, 1, constant_values=-np.inf)
    best = height.copy()
    index = np.arange(H * W).reshape(H, W)
    target = index.copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy == 0 and dx == 0:
                continue
            nb = padded[1 + dy : 1 + dy + H, 1 + dx : 1 + dx + W]
            up = nb > best
            best = np.where(up, nb, best)
            target = np.where(up, index + dy * W + dx, target)
    parent = np.where(mask, target, -1).ravel()
    fg = np.flatnonzero(mask.ravel())
    p = parent[fg]
    while True:
        q = parent[p]
        if np.array_equal(q, p):
            break
        p = q
    roots, lab = np.unique(p, return_inverse=True)
    labels = np.zeros(H * W, np.int32)
    labels[fg] = lab + 1
    yy, xx = np.divmod(fg, W)
    n = roots.size
    x0 = np.full(n, W)
    y0 = np.full(n, H)
    x1 = np.zeros(n, int)
    y1 = np.zeros(n, int)
    np.minimum.at(x0, lab, xx)
    np.minimum.at(y0, lab, yy)
    np.maximum.at(x1, lab, xx)
    np.maximum.at(y1, lab, yy)
    stats = np.zeros((n + 1, 5), np.int64)
    stats[1:, cv2.CC_STAT_LEFT], stats[1:, cv2.CC_STAT_TOP] = x0, y0
    stats[1:, cv2.CC_STAT_WIDTH], stats[1:, cv2.CC_STAT_HEIGHT] = x1 - x0 + 1, y1 - y0 + 1
    stats[1:, cv2.CC_STAT_AREA] = np.bincount(lab, minlength=n)
    return n + 1, labels.reshape(H, W), stats


def _blob_detections(top, labels, stats, thr, noise, img, area_range, min_sum, edge_margin,
                     refine: dict | None = None) -> Detections:
    """Centres and shape of every labelled blob, then the reject gates; ``refine``: keywords of
    :func:`_refined_centres` (other estimator than the centroid)."""
    n = stats.shape[0]
    H, W = top.shape
    lab = labels.ravel()
    fg = lab > 0
    idx = lab[fg] - 1
    w = (top.ravel()[fg] - thr * CENTROID_WEIGHT_OFFSET).clip(min=0.0)
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
    if refine is not None:
        xy[ok] = _refined_centres(top, labels, xy, ok, **refine)
    rejects = _concat([_records(xy[reason == r], diam[reason == r], contrast[reason == r], r)
                       for r in ("too_small", "too_large", "edge", "low_contrast")])
    precision = noise * np.sqrt(np.maximum(tr, 0.25)) / np.maximum(sw, 1e-12) * np.sqrt(area)
    return Detections(xy[ok], diam[ok], contrast[ok], quality[ok], precision[ok], rejects, noise)


def _unsaturated(image: np.ndarray) -> np.ndarray | None:
    """Pixels below the integer type's largest value (a clipped top is no Gaussian); None for float images."""
    if not np.issubdtype(image.dtype, np.integer):
        return None
    return image < np.iinfo(image.dtype).max


def _refined_centres(top, labels, xy, ok, centre, valid, blobs) -> np.ndarray:
    """Centres ``(ok.sum(), 2)`` of the accepted blobs ``ok`` ``(n,)`` by the ``centre`` estimator (every blob
    labelled takes part in the joint 2-D fit as a neighbour); ``xy`` ``(n, 2)``: the centroids; ``valid``:
    pixels the 2-D fit may use; ``blobs`` ``(H, W)``: the connected blobs before splitting."""
    n = len(xy)
    if centre == "hybrid":
        owner = blobs[labels > 0]
        first = np.zeros(n, np.int64)
        first[labels[labels > 0] - 1] = owner
        split = np.bincount(first, minlength=int(blobs.max()) + 1)[first] > 1
        out = xy.copy()
        if split.any():
            out[split] = _refined_centres(top, labels, xy, split, HYBRID_SPLIT, valid, blobs)
        return out[ok]
    peaks = peak_pixels(top, labels, n)
    if centre == "gauss3":
        return gauss3_centres(top, peaks[ok])
    if centre == "gauss3_smoothed":
        smooth = cv2.GaussianBlur(top, (0, 0), MATCHED_FILTER_PX)
        return gauss3_centres(smooth, peak_pixels(smooth, labels, n)[ok])
    return gauss2d_centres(top, labels, peaks, valid=valid)[0][ok]
