"""Sub-pixel detection of dark circular markers in one grey-level image.

Method
------
1. Candidates: black top-hat (morphological closing minus image) with a square element larger
   than the largest marker, thresholded a few robust sigmas above its background level; then
   connected components (``cv2.connectedComponentsWithStats``).
2. Per candidate, on a fixed-size patch (all candidates at once, vectorised): peak contrast, the
   half-contrast area (diameter), second moments (elongation), border contact and nearby
   saturation, giving accept / reject with a reason.
3. Sub-pixel centre: iterated windowed centroid of the *normalised darkness*
   ``w = 1 - I / B(x, y)`` where ``B`` is a plane fitted robustly to an annulus around the
   marker (multiplicative illumination: a black disc gives ``w = 1`` whatever the illumination
   gradient, so the centroid is unbiased by shading), with a soft-edged circular window that
   follows the estimate.

Pixel coordinates are OpenCV's (x right, y down, origin at the centre of the top-left pixel).
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from .detection_blobs import _candidate_mask, _components, _glare_blobs
from .detection_centroids import _NO_SPLIT, _centroids, _Split, _split_groups
from .detection_measure import _classify, _joined, _measure_groups, _Measures
from .detection_records import REJECT_DTYPE, REJECT_REASONS, Detections, _concat, _empty, _records

__all__ = ["Detections", "REJECT_DTYPE", "REJECT_REASONS", "detect_markers", "detect_markers_near"]

log = logging.getLogger(__name__)


def _saturation_level(image: np.ndarray, saturation: float | None | str) -> float | None:
    if saturation is None:
        return None
    if saturation != "auto":
        return float(saturation)
    if image.dtype == np.uint8:
        return 254.5
    if image.dtype == np.uint16:
        return 65534.5
    return None


def detect_markers(
    image: np.ndarray,
    *,
    diameter_range: tuple[float, float] | None = None,
    threshold_sigma: float = 6.0,
    min_darkness: float = 0.3,
    min_relative_contrast: float = 0.6,
    max_elongation: float = 1.6,
    edge_margin: int = 2,
    saturation: float | None | str = "auto",
    window_margin: float = 2.0,
    iterations: int = 4,
    centroid_threshold: float = 0.2,
    background_order: int = 3,
    split_merged: bool = True,
    _levels: tuple[float, float] | None = None,
    polarity: str = "dark",
) -> Detections:
    """Detect dark circular markers (or bright particles, ``polarity="bright"``) with sub-pixel centres.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        Grey-level image (uint8, uint16 or float).
    diameter_range : (float, float), optional
        Accepted marker diameters, px. Default: 0.6x .. 1.5x the median diameter of the
        candidates (with an absolute search range of 3..80 px).
    threshold_sigma : float
        Candidate threshold in robust sigmas of the top-hat background.
    min_darkness : float
        Candidate pixels must be at least this fraction darker than their local upper envelope
        (morphological closing): 0.3 keeps tissue texture and shading out while black markers
        (~0.9) pass.
    min_relative_contrast : float
        Reject blobs whose relative darkness is below this fraction of the median of the
        accepted markers (grey debris, shadows).
    max_elongation : float
        Major/minor axis ratio above which a blob is rejected (``merged`` when its area is also
        about twice a marker's, else ``not_round``).
    edge_margin : int
        Blobs whose bounding box comes within this many pixels of the border are ``edge``.
    saturation : float, None or "auto"
        Grey level counted as saturated (glare); "auto" = dtype maximum for integer images.
    window_margin : float
        Centroid window radius = diameter / 2 + window_margin, px.
    iterations : int
        Window re-centring iterations of the centroid.
    split_merged : bool
        Fit two overlapping blurred discs to blobs classified as ``merged`` (two markers touching
        or overlapping in projection, common in oblique views) and return both centres with
        ``quality = 0.5``; blobs the fit does not explain stay rejected as ``merged``.
    background_order : int
        Order (1-3) of the 2-D polynomial fitted robustly to the annulus around each blob as
        the local illumination x albedo; 3 follows smooth tissue texture best.
    centroid_threshold : float
        Fraction of each blob's peak darkness subtracted before the centroid (weights
        ``max(w - t * peak, 0)``), so that background texture inside the window does not pull
        the centre; 0 gives the plain background-subtracted grey-value centroid.
    polarity : {"dark", "bright"}
        "dark": dark markers on bright tissue; "bright": bright particles on a dark background
        (the image is inverted first, and saturation then means nothing unless given).
    _levels : (float, float), optional
        Internal (:func:`detect_markers_near`): candidate threshold and noise (grey levels) of the
        whole image, used for a crop instead of the crop's own statistics.

    Returns
    -------
    Detections
    """
    image, sat, dmin, dmax = _checked_inputs(image, diameter_range, polarity, saturation)
    rejects: list[np.ndarray] = [] if sat is None else [_glare_blobs(image, sat)]
    mask, noise, thr = _candidate_mask(image, dmax, threshold_sigma, min_darkness, _levels)
    blobs, dmax = _components(mask, dmin, dmax, estimate_size=diameter_range is None, rejects=rejects)
    if blobs is None:
        return _empty(noise, _concat(rejects), thr)
    groups = _measure_groups(image, blobs, dmax, window_margin, background_order, edge_margin, sat)
    m = _joined(groups, len(blobs.ids))
    reason, lo, hi, dref = _classify(m, diameter_range, dmin, dmax, max_elongation, min_relative_contrast)
    split = _split_groups(groups, reason, dref, lo, hi) if split_merged else _NO_SPLIT
    return _accepted(groups, m, reason, split, noise, thr, rejects, window_margin, iterations, centroid_threshold)


def _checked_inputs(image, diameter_range, polarity: str, saturation):
    """The (dark-marker) image, its saturation level or None and the diameter search range, px."""
    image = np.asarray(image)
    if image.ndim != 2:
        raise ValueError(f"image must be a 2-D grey-level array (H, W); got shape {image.shape}")
    image, saturation = _apply_polarity(image, polarity, saturation)
    dmin, dmax = (3.0, 80.0) if diameter_range is None else map(float, diameter_range)
    if not 0 < dmin < dmax:
        raise ValueError(f"diameter_range must be (min, max) with 0 < min < max px; got {diameter_range}")
    return image, _saturation_level(image, saturation), dmin, dmax


def _accepted(groups: list, m: _Measures, reason, split: _Split, noise, thr, rejects: list, window_margin,
              iterations, centroid_threshold) -> Detections:
    """Steps 3-4: rejects recorded (joined measures ``m``), sub-pixel centres of the accepted
    candidates (per patch-size group), all assembled."""
    bad = (reason != "") & (reason != "split")
    if np.any(bad):
        rec = _records(m.cxy[bad], m.diam[bad], m.peak[bad], "")
        rec["reason"] = reason[bad]
        rejects.append(rec)
    if not np.any(reason == "") and split.centres.shape[0] == 0:
        return _empty(noise, _concat(rejects), thr)
    found = [_centroids(mg, np.flatnonzero(reason[idx] == ""), noise, window_margin, iterations, centroid_threshold,
                        rejects) for idx, mg in groups]
    single = _Split(*(np.concatenate([f[0][k] for f in found]) for k in range(4)))
    return _assemble((single, np.concatenate([f[1] for f in found])), split, noise, thr, rejects)


def detect_markers_near(
    image: np.ndarray,
    points: np.ndarray,
    radius: float,
    *,
    levels: tuple[float, float] | None = None,
    tile: int = 64,
    max_fraction: float = 0.7,
    **kwargs,
) -> Detections:
    """:func:`detect_markers` restricted to the neighbourhood of expected marker positions.

    The image is cut into ``tile`` x ``tile`` px tiles; the tiles within ``radius`` of a point are
    searched, each group of touching tiles as one crop with a margin wide enough for the
    morphology and the patch measurements to see what they see on the whole image. The candidate
    threshold and the noise are the whole image's statistics: give them as ``levels`` (from a
    whole-image detection of the same camera, :attr:`Detections.threshold` and ``noise``), else
    each crop's own are used (they differ: a crop holds less bath and more tissue). Markers whose
    centre lies outside the searched tiles are not reported. When the searched crops would cover
    more than ``max_fraction`` of the image, the whole image is searched.

    Parameters
    ----------
    image : ndarray, shape (H, W)
    points : ndarray, shape (m, 2)
        Expected centres, px (OpenCV convention); non-finite rows are ignored.
    radius : float
        Search radius around each point, px.
    levels : (float, float), optional
        Candidate threshold and noise, grey levels.
    **kwargs
        Keywords of :func:`detect_markers`; ``diameter_range`` is required (it sizes the margin).

    Returns
    -------
    Detections
        As :func:`detect_markers` (``noise`` is the median over the crops).
    """
    image = np.asarray(image)
    if kwargs.get("diameter_range") is None:
        raise ValueError("detect_markers_near needs diameter_range=(min, max) px to size its search margin; got None")
    if not radius > 0:
        raise ValueError(f"radius must be > 0 px; got {radius}")
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    points = points[np.all(np.isfinite(points), axis=1)]
    H, W = image.shape[:2]
    dmax = float(kwargs["diameter_range"][1])
    margin = int(np.ceil(1.3 * dmax)) + int(np.ceil(1.1 * dmax + kwargs.get("window_margin", 2.0) + 6))
    groups, crops = _search_tiles(points, radius, (H, W), tile, margin)
    if sum((y1 - y0) * (x1 - x0) for x0, y0, x1, y1 in crops) > max_fraction * H * W:
        return detect_markers(image, **kwargs)
    if levels is not None and not np.all(np.isfinite(levels)):
        levels = None
    parts = [_crop_detections(image, crop, groups == g + 1, tile, levels, kwargs) for g, crop in enumerate(crops)]
    if not parts:
        return _empty(0.0)
    centres = np.concatenate([d.centres for d in parts])
    order = np.lexsort((centres[:, 0], centres[:, 1]))
    return Detections(
        centres=centres[order],
        diameter=np.concatenate([d.diameter for d in parts])[order],
        contrast=np.concatenate([d.contrast for d in parts])[order],
        quality=np.concatenate([d.quality for d in parts])[order],
        precision=np.concatenate([d.precision for d in parts])[order],
        rejects=_concat([d.rejects for d in parts]),
        noise=float(np.median([d.noise for d in parts])),
        threshold=float(np.median([d.threshold for d in parts])),
    )


def _search_tiles(points: np.ndarray, radius: float, shape: tuple[int, int], tile: int, margin: int):
    """Tiles within ``radius`` of the points, labelled by group of touching tiles, and each
    group's crop (x0, y0, x1, y1) px with ``margin`` (clipped to the image).

    Returns (labels (n_tile_rows, n_tile_cols) int, 0 = not searched; list of crops)."""
    H, W = shape
    grid = np.zeros((-(-H // tile), -(-W // tile)), np.uint8)
    lo = np.floor((points - radius) / tile).astype(int)
    hi = np.floor((points + radius) / tile).astype(int)
    span = int(np.max(hi - lo)) + 1 if points.size else 0
    for dy in range(span):  # a few tile offsets, vectorised over the points
        for dx in range(span):
            ty, tx = lo[:, 1] + dy, lo[:, 0] + dx
            ok = (ty <= hi[:, 1]) & (tx <= hi[:, 0]) & (ty >= 0) & (tx >= 0) & (ty < grid.shape[0]) & (tx < grid.shape[1])
            grid[ty[ok], tx[ok]] = 1
    n, labels, stats, _ = cv2.connectedComponentsWithStats(grid, connectivity=8)
    crops = []
    for x, y, w, h, _ in stats[1:]:
        crops.append((max(x * tile - margin, 0), max(y * tile - margin, 0),
                      min((x + w) * tile + margin, W), min((y + h) * tile + margin, H)))
    return labels, crops


def _crop_detections(image: np.ndarray, crop, searched: np.ndarray, tile: int, levels, kwargs: dict) -> Detections:
    """Detections in one crop, moved to image coordinates, keeping those in the ``searched`` tiles."""
    x0, y0, x1, y1 = crop
    det = detect_markers(image[y0:y1, x0:x1], _levels=levels, **kwargs)
    shift = np.array([x0, y0], dtype=float)
    centres = det.centres + shift
    rejects = det.rejects.copy()
    rejects["x"] += x0
    rejects["y"] += y0

    def inside(xy):
        t = np.floor(xy / tile).astype(int)
        t[:, 0] = np.clip(t[:, 0], 0, searched.shape[1] - 1)
        t[:, 1] = np.clip(t[:, 1], 0, searched.shape[0] - 1)
        return searched[t[:, 1], t[:, 0]]

    keep = inside(centres)
    rkeep = inside(np.stack([rejects["x"], rejects["y"]], axis=1))
    return Detections(centres[keep], det.diameter[keep], det.contrast[keep], det.quality[keep], det.precision[keep],
                      rejects[rkeep], det.noise, det.threshold)


def _assemble(found, split: _Split, noise: float, threshold: float, rejects: list) -> Detections:
    """Step 4: single and split centres together, sorted by (y, x)."""
    single, q = found
    centres = np.concatenate([single.centres, split.centres])
    order = np.lexsort((centres[:, 0], centres[:, 1]))
    return Detections(
        centres=centres[order],
        diameter=np.concatenate([single.diameter, split.diameter])[order],
        contrast=np.concatenate([single.contrast, split.contrast])[order],
        quality=np.concatenate([q, np.full(split.centres.shape[0], 0.5)])[order],
        precision=np.concatenate([single.precision, split.precision])[order],
        rejects=_concat(rejects),
        noise=noise,
        threshold=threshold,
    )


def _apply_polarity(image: np.ndarray, polarity: str, saturation):
    """Invert bright-on-dark images so that the dark-marker detector sees dark blobs."""
    if polarity not in ("dark", "bright"):
        raise ValueError(f"polarity must be 'dark' (dark markers on a bright background) or 'bright'; got {polarity!r}")
    if polarity == "dark":
        return image, saturation
    top = np.iinfo(image.dtype).max if np.issubdtype(image.dtype, np.integer) else float(np.nanmax(image))
    return (top - image).astype(image.dtype), (None if saturation == "auto" else saturation)


