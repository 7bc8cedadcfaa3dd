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
from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np
from scipy.optimize import leastsq
from scipy.special import erfc

__all__ = ["Detections", "REJECT_DTYPE", "REJECT_REASONS", "detect_markers", "detect_markers_near"]

log = logging.getLogger(__name__)

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


@dataclass(frozen=True)
class _Blobs:
    """Candidate connected components (n of them) of one image."""

    labels: np.ndarray  # (h, w) int32 label image of the mask's bounding box
    origin: tuple[int, int]  # (x0, y0) of that box in the image, px
    ids: np.ndarray  # (n,) their labels
    box: np.ndarray  # (n, 4) int: left, top, width, height, px
    cxy: np.ndarray  # (n, 2) centroid of the thresholded pixels, px


@dataclass(frozen=True)
class _Measures:
    """Patch measurements of n candidates on a (P, P) grid centred on each blob's pixel ``ci``."""

    cxy: np.ndarray  # (n, 2) blob centroids, px
    ci: np.ndarray  # (n, 2) int patch centres, px
    xx: np.ndarray  # (P, P) x offset from the patch centre, px
    yy: np.ndarray  # (P, P) y offset, px
    other: np.ndarray  # (n, P, P) bool: pixels of other blobs
    dark: np.ndarray  # (n, P, P) normalised darkness 1 - I / B
    background: np.ndarray  # (n, P, P) fitted local background B, grey levels
    peak: np.ndarray  # (n,) peak (3x3-smoothed) darkness
    area: np.ndarray  # (n,) half-contrast area, px^2
    diam: np.ndarray  # (n,) its equivalent diameter, px
    mean: np.ndarray  # (n, 2) its centroid relative to ci, px
    cov: np.ndarray  # (n, 3) its second moments sxx, syy, sxy, px^2
    axes: np.ndarray  # (n, 2) major and minor eigenvalues of cov, px^2
    near_edge: np.ndarray  # (n,) bool
    glare: np.ndarray  # (n,) bool


class _Split(NamedTuple):
    """Centres recovered from merged blobs (two per fitted blob)."""

    centres: np.ndarray  # (m, 2) px
    diameter: np.ndarray  # (m,) px
    contrast: np.ndarray  # (m,)
    precision: np.ndarray  # (m,) px


_NO_SPLIT = _Split(np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(0))


def _candidate_mask(image: np.ndarray, dmax: float, threshold_sigma: float, min_darkness: float,
                    levels: tuple[float, float] | None):
    """Step 1: pixels darker than their local upper envelope (morphological closing) by a robust
    threshold and by at least ``min_darkness`` of the envelope.

    Integer images stay integer (OpenCV's morphology is several times faster on them and the
    result is the same). Returns (mask uint8 (H, W), noise in grey levels).
    """
    H, W = image.shape
    work = image if image.dtype in (np.uint8, np.uint16) else image.astype(np.float32)
    k = int(np.ceil(1.3 * dmax)) | 1
    closed = cv2.morphologyEx(work, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_RECT, (k, k)))
    tophat = cv2.subtract(closed, work)
    sub = (slice(None, None, max(1, H // 256)), slice(None, None, max(1, W // 256)))
    if levels is None:
        sample = tophat[sub].ravel().astype(np.float32)
        med = float(np.median(sample))
        mad = float(np.median(np.abs(sample - med))) * 1.4826
        floor = 0.03 * float(np.median(closed[sub]))
        thr = med + max(threshold_sigma * mad, floor)
        noise = _image_noise(work[sub].astype(np.float32))
    else:
        thr, noise = levels
    # relative darkness against the local upper envelope: markers are nearly black, texture and
    # shading are not; the absolute threshold keeps noise in dark regions (bath) out
    if work.dtype != np.float32:
        relative = cv2.addWeighted(tophat, 1.0, closed, -min_darkness, 0.0, dtype=cv2.CV_32F) > 0
    else:
        relative = tophat > min_darkness * np.maximum(closed, 1e-6 * max(1.0, float(closed.max())))
    mask = ((tophat > thr) & relative).view(np.uint8)
    return mask, noise, thr


def _image_noise(img: np.ndarray) -> float:
    """Robust noise estimate (grey levels) from the 4-neighbour Laplacian of a (sub-sampled) image."""
    lap = img[1:-1, 1:-1] - 0.25 * (img[:-2, 1:-1] + img[2:, 1:-1] + img[1:-1, :-2] + img[1:-1, 2:])
    return float(np.median(np.abs(lap - np.median(lap)))) * 1.4826 / np.sqrt(1.25) if lap.size else 0.0


def _components(mask: np.ndarray, dmin: float, dmax: float, *, estimate_size: bool, rejects: list):
    """Step 1b: connected components of the candidate mask, specks and oversized blobs removed.

    With ``estimate_size`` the working size limit ``dmax`` is lowered to twice the typical compact
    candidate. Appends ``too_large`` rejects; returns (_Blobs or None, dmax).
    """
    # label only the bounding box of the candidate pixels (about a third of the image around the
    # specimen): same components, same raster order of their labels
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if rows.size == 0:
        return None, dmax
    y0, x0 = int(rows[0]) & ~1, int(cols[0]) & ~1  # even: OpenCV's 2x2-block labelling numbers as on the whole
    n_lab, labels, stats, cents = _labelled(mask[y0 : rows[-1] + 1, x0 : cols[-1] + 1])
    stats[:, cv2.CC_STAT_LEFT] += x0
    stats[:, cv2.CC_STAT_TOP] += y0
    cents = cents + np.array([x0, y0], dtype=float)
    ids = np.arange(1, n_lab)
    areas = stats[1:, cv2.CC_STAT_AREA].astype(float)
    # ignore specks that are a fraction of the smallest accepted marker (noise, texture)
    keep = areas >= max(3.0, 0.25 * np.pi * (0.5 * dmin) ** 2)
    ids, areas = ids[keep], areas[keep]
    if estimate_size and ids.size:
        # working size limit from the typical compact candidate (speeds up the patch stage)
        size = np.maximum(stats[ids, cv2.CC_STAT_WIDTH], stats[ids, cv2.CC_STAT_HEIGHT])
        compact = areas >= 0.5 * size**2
        if np.count_nonzero(compact) >= 3:
            dmax = min(dmax, max(2.0 * float(np.median(2 * np.sqrt(areas[compact] / np.pi))), 4.0 * dmin))
    if ids.size == 0:
        return None, dmax
    box = stats[ids, :4]
    big = (np.max(box[:, 2:], axis=1) > 2.2 * dmax) | (areas > 2.6 * np.pi * (0.5 * dmax) ** 2)
    if np.any(big):
        rejects.append(_records(cents[ids][big], np.sqrt(4 * areas[big] / np.pi), np.nan, "too_large"))
    if np.all(big):
        return None, dmax
    return _Blobs(labels, (x0, y0), ids[~big], box[~big], cents[ids][~big]), dmax


def _labelled(mask: np.ndarray):
    """8-connected components of a sparse uint8 mask (H, W), as ``cv2.connectedComponentsWithStats``
    returns them (same labels; stats (n, 5) left, top, width, height, area and centroids (n, 2)
    x, y of the pixels, for the labels >= 1; row 0, the background, is zero). The labels come from
    ``cv2.connectedComponents`` and the statistics from the foreground pixels only: OpenCV's own
    statistics pass costs several times the labelling on a 5-MP mask with a few % foreground."""
    n, labels = cv2.connectedComponents(mask, connectivity=8, ltype=cv2.CV_32S)
    stats = np.zeros((n, 5), np.int32)
    cents = np.zeros((n, 2))
    if n <= 1:
        return n, labels, stats, cents
    xy = cv2.findNonZero(mask).reshape(-1, 2)
    x, y = xy[:, 0], xy[:, 1]
    lab = labels[y, x]
    area = np.bincount(lab, minlength=n)
    left, right = np.full(n, mask.shape[1], np.int32), np.zeros(n, np.int32)
    np.minimum.at(left, lab, x)
    np.maximum.at(right, lab, x)
    top, bottom = np.full(n, mask.shape[0], np.int32), np.zeros(n, np.int32)
    np.minimum.at(top, lab, y)
    np.maximum.at(bottom, lab, y)
    stats[1:] = np.stack([left, top, right - left + 1, bottom - top + 1, area], axis=1)[1:]
    with np.errstate(invalid="ignore", divide="ignore"):
        cents[1:] = np.stack([np.bincount(lab, x, n), np.bincount(lab, y, n)], axis=1)[1:] / area[1:, None]
    return n, labels, stats, cents


def _patches(image: np.ndarray, labels: np.ndarray, centres: np.ndarray, size: int, origin=(0, 0)):
    """(n, P, P) float32 grey-level patches (border reflected) and int label patches (0 outside)
    around integer pixel centres (n, 2) (x, y); ``labels`` covers the image from ``origin`` (x0, y0).

    Patches that lie inside the image and the label box (nearly all) are copied as blocks from
    sliding-window views; the others are gathered with mirrored indices."""
    top_left = centres[:, ::-1] - size // 2  # (n, 2) row, column
    lab_tl = top_left - np.array(origin[::-1])
    block = (np.all(top_left >= 0, axis=1) & np.all(top_left + size <= image.shape, axis=1)
             & np.all(lab_tl >= 0, axis=1) & np.all(lab_tl + size <= labels.shape, axis=1))
    patch = np.empty((centres.shape[0], size, size), np.float32)
    plab = np.empty((centres.shape[0], size, size), labels.dtype)
    if np.any(block):
        view = np.lib.stride_tricks.sliding_window_view
        b = np.flatnonzero(block)
        patch[b] = view(image, (size, size))[top_left[b, 0], top_left[b, 1]]
        plab[b] = view(labels, (size, size))[lab_tl[b, 0], lab_tl[b, 1]]
    if not np.all(block):
        g = np.flatnonzero(~block)
        patch[g], plab[g] = _gathered_patches(image, labels, centres[g], size, origin)
    return patch, plab


def _gathered_patches(image: np.ndarray, labels: np.ndarray, centres: np.ndarray, size: int, origin=(0, 0)):
    """:func:`_patches` by index gathering (border reflected, labels 0 outside their box)."""
    H, W = image.shape
    off = np.arange(size) - size // 2
    rows = centres[:, 1, None] + off[None, :]
    cols = centres[:, 0, None] + off[None, :]
    r_img, c_img = _reflect(rows, H)[:, :, None], _reflect(cols, W)[:, None, :]
    patch = image[r_img, c_img].astype(np.float32)
    inside = ((rows >= 0) & (rows < H))[:, :, None] & ((cols >= 0) & (cols < W))[:, None, :]
    x0, y0 = origin
    lr, lc = rows - y0, cols - x0
    in_box = (((lr >= 0) & (lr < labels.shape[0]))[:, :, None] & ((lc >= 0) & (lc < labels.shape[1]))[:, None, :])
    plab = np.where(inside & in_box, labels[np.clip(lr, 0, labels.shape[0] - 1)[:, :, None],
                                             np.clip(lc, 0, labels.shape[1] - 1)[:, None, :]], 0)
    return patch, plab


def _reflect(index: np.ndarray, n: int) -> np.ndarray:
    """Indices mirrored at the borders as OpenCV's BORDER_REFLECT (``fedcba|abcdefgh|hgfedcb``)."""
    index = np.where(index < 0, -index - 1, index)
    index = np.where(index >= n, 2 * n - index - 1, index)
    return np.clip(index, 0, n - 1)


def _measure_groups(image, blobs: _Blobs, dmax, window_margin, background_order, edge_margin, sat) -> list:
    """Step 2 in two patch sizes: the blobs no larger than ``dmax`` (nearly all) on the patch that
    the largest accepted marker needs, the larger ones (merged pairs, debris) on a patch that
    holds the largest of them. A blob's measures then do not depend on the other blobs of the
    image or crop (the whole-image and the guided search agree), and one large blob no longer
    enlarges every patch. Returns [(blob indices (k,), _Measures of those k blobs), ...]."""
    size = np.maximum(blobs.box[:, 2], blobs.box[:, 3])
    small = size <= dmax
    out = []
    for sel in (small, ~small):
        idx = np.flatnonzero(sel)
        if idx.size:
            sub = _Blobs(blobs.labels, blobs.origin, blobs.ids[idx], blobs.box[idx], blobs.cxy[idx])
            out.append((idx, _measure_blobs(image, sub, dmax, window_margin, background_order, edge_margin, sat)))
    return out


def _joined(groups: list, n: int) -> _Measures:
    """The per-blob measures of all groups in blob order (n blobs); the patch fields (``xx``,
    ``yy``, ``other``, ``dark``, ``background``) stay with the groups and are None here."""
    if len(groups) == 1:
        return groups[0][1]
    order = np.argsort(np.concatenate([idx for idx, _ in groups]), kind="stable")
    per_blob = {}
    for f in ("cxy", "ci", "peak", "area", "diam", "mean", "cov", "axes", "near_edge", "glare"):
        per_blob[f] = np.concatenate([getattr(mg, f) for _, mg in groups])[order]
    return _Measures(xx=None, yy=None, other=None, dark=None, background=None, **per_blob)


def _split_groups(groups: list, reason: np.ndarray, dref: float, lo: float, hi: float) -> _Split:
    """Step 2c per patch-size group (``reason`` of all blobs, updated in place)."""
    parts = []
    for idx, mg in groups:
        r = reason[idx]
        parts.append(_split_merged(mg, r, dref, lo, hi))
        reason[idx] = r
    return _Split(*(np.concatenate([p[k] for p in parts]) for k in range(4)))


def _measure_blobs(image, blobs: _Blobs, dmax, window_margin, background_order, edge_margin, sat) -> _Measures:
    """Step 2: per candidate, on a fixed-size patch (vectorised): background, darkness, peak,
    half-contrast area and its moments, border contact and nearby saturation."""
    H, W = image.shape
    bx, by, bw, bh = blobs.box.T
    size = np.maximum(bw, bh)
    P = int(2 * np.ceil(max(np.max(size) * 0.5 + window_margin + 3, 0.5 * dmax + window_margin + 3)) + 1)
    ci = np.rint(blobs.cxy).astype(int)  # patch centre, integer pixel (x, y)
    patch, plab = _patches(image, blobs.labels, ci, P, blobs.origin)
    own = plab == blobs.ids[:, None, None]
    other = (plab != 0) & ~own
    off = (np.arange(P) - P // 2).astype(float)
    yy, xx = np.meshgrid(off, off, indexing="ij")
    bg = _annulus_plane(patch, own | other, xx, yy, r_in=0.5 * size + 2.0, r_out=P // 2 - 0.5, order=background_order)
    with np.errstate(divide="ignore", invalid="ignore"):
        dark = 1.0 - patch / np.maximum(bg, 1e-12)
    peak = np.max(np.where(own, _smooth3(dark), np.float32(-np.inf)), axis=(1, 2)).astype(float)
    half = own & (dark > (0.5 * peak).astype(np.float32)[:, None, None])
    area = half.sum(axis=(1, 2)).astype(float)
    mean, cov, axes = _moments(half, area, xx, yy)
    diam = 2.0 * np.sqrt(area / np.pi)
    near_edge = (bx < edge_margin) | (by < edge_margin) | (bx + bw > W - edge_margin) | (by + bh > H - edge_margin)
    glare = np.zeros(ci.shape[0], dtype=bool)
    if sat is not None:
        inner = np.hypot(xx, yy)[None] <= (0.5 * diam + window_margin)[:, None, None]
        glare = np.any((patch >= sat) & inner, axis=(1, 2))
    return _Measures(blobs.cxy, ci, xx, yy, other, dark, bg, peak, area, diam, mean, cov, axes, near_edge, glare)


def _moments(mask: np.ndarray, area: np.ndarray, xx: np.ndarray, yy: np.ndarray):
    """Centroid (n, 2), second moments (n, 3: sxx, syy, sxy) and their eigenvalues (n, 2: major,
    minor) of (n, P, P) masks with pixel counts ``area`` (raw moments as one matrix product)."""
    x, y = xx.ravel(), yy.ravel()
    raw = mask.reshape(mask.shape[0], -1).astype(float) @ np.stack([x, y, x * x, y * y, x * y], axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mx, my, mxx, myy, mxy = (raw / area[:, None]).T
    sxx = np.maximum(mxx - mx * mx, 0.0)
    syy = np.maximum(myy - my * my, 0.0)
    sxy = mxy - mx * my
    tr = sxx + syy
    disc = np.sqrt(np.maximum((sxx - syy) ** 2 / 4 + sxy**2, 0.0))
    l1 = tr / 2 + disc
    l2 = np.maximum(tr / 2 - disc, 1e-12)
    return np.stack([mx, my], axis=1), np.stack([sxx, syy, sxy], axis=1), np.stack([l1, l2], axis=1)


def _classify(m: _Measures, diameter_range, dmin, dmax, max_elongation, min_relative_contrast):
    """Step 2b: reject reason per candidate ("" = accepted) and the accepted diameter range.

    Returns (reason (n,) str, lo, hi, dref) with the diameters in px.
    """
    elong = np.sqrt(m.axes[:, 0] / m.axes[:, 1])
    reason = np.full(m.peak.size, "", dtype="U12")
    reason[m.glare] = "glare"
    reason[(reason == "") & m.near_edge] = "edge"
    reason[(reason == "") & ~np.isfinite(m.peak)] = "low_contrast"
    lo, hi = dmin, dmax
    if diameter_range is None:
        plausible = (reason == "") & (elong < max_elongation) & (m.diam >= dmin)
        if np.any(plausible):
            dmed = float(np.median(m.diam[plausible]))
            lo, hi = 0.6 * dmed, 1.5 * dmed
    dref = 0.5 * (lo + hi) if diameter_range is not None else (lo + hi) / 2.1
    area_ratio = m.area / (np.pi * (0.5 * dref) ** 2)
    reason[(reason == "") & (elong > max_elongation) & (area_ratio > 1.4)] = "merged"
    reason[(reason == "") & (elong > max_elongation)] = "not_round"
    reason[(reason == "") & (m.diam < lo)] = "too_small"
    reason[(reason == "") & (m.diam > hi)] = "too_large"
    good = reason == ""
    if np.any(good):
        cref = float(np.median(m.peak[good]))
        reason[good & (m.peak < min_relative_contrast * cref)] = "low_contrast"
    return reason, lo, hi, dref


def _split_merged(m: _Measures, reason: np.ndarray, dref: float, lo: float, hi: float) -> _Split:
    """Step 2c: fit two discs to each ``merged`` blob; fitted ones get reason "split" (in place)."""
    parts = []
    for i in np.flatnonzero(reason == "merged"):  # merged blobs are few; each is a small 8-parameter fit
        fit = _fit_two_discs(m.dark[i], m.other[i], m.xx, m.yy, m.mean[i], m.cov[i], 0.5 * dref, lo, hi)
        if fit is not None:
            parts.append((i, fit))
            reason[i] = "split"
    if not parts:
        return _NO_SPLIT
    return _Split(
        np.concatenate([m.ci[i].astype(float) + f[0] for i, f in parts]),
        np.concatenate([2 * f[1] for _, f in parts]),
        np.concatenate([np.full(2, f[2]) for _, f in parts]),
        np.concatenate([f[3] for _, f in parts]),
    )


def _centroids(m: _Measures, g, noise, window_margin, iterations, centroid_threshold, rejects) -> _Split:
    """Step 3: iterated sub-pixel centroid of the normalised darkness in a soft circular window,
    for the accepted candidates ``g``; non-finite ones are appended to ``rejects`` as
    ``low_contrast``. Returns centres, diameters, contrasts and precisions (as a _Split) and the
    roundness (minor / major axis) of the kept ones."""
    if g.size == 0:
        return _NO_SPLIT, np.zeros(0)
    # the window (radius <= half the largest accepted diameter + margin, re-centred by < 1-2 px)
    # lies well inside the patch: work on the central part only
    P = m.xx.shape[0]
    half = min(P // 2, int(np.ceil(0.5 * np.max(m.diam[g]) + window_margin + 4 + np.max(np.abs(m.mean[g])))))
    inner = slice(P // 2 - half, P // 2 + half + 1)
    xx, yy = m.xx[inner, inner], m.yy[inner, inner]
    d_g = np.where(m.other[g, inner, inner], np.float32(0.0), m.dark[g, inner, inner])
    if centroid_threshold > 0:
        d_g = np.maximum(d_g - (centroid_threshold * m.peak[g]).astype(np.float32)[:, None, None], np.float32(0.0))
    c, win, s = _window_centroid(d_g, xx, yy, 0.5 * m.diam[g] + window_margin, m.mean[g], iterations)
    # noise-limited precision: var(cx) = sigma_rel^2 sum(win (x - cx)^2) / s^2
    sigma_rel = noise / np.maximum(np.median(m.background[g], axis=(1, 2)), 1e-12)
    win_x = win.reshape(win.shape[0], -1).astype(float) @ np.stack([np.ones(xx.size), xx.ravel(), xx.ravel() ** 2], 1)
    spread = win_x[:, 2] - 2 * c[:, 0] * win_x[:, 1] + c[:, 0] ** 2 * win_x[:, 0]  # sum(win (x - cx)^2)
    prec = sigma_rel * np.sqrt(np.maximum(spread, 0.0)) / np.abs(s)
    centres = m.ci[g].astype(float) + c
    ok = np.all(np.isfinite(centres), axis=1)
    if not np.all(ok):
        rejects.append(_records(m.cxy[g][~ok], m.diam[g][~ok], m.peak[g][~ok], "low_contrast"))
    q = np.sqrt(m.axes[g, 1] / np.maximum(m.axes[g, 0], 1e-12))
    return _Split(centres[ok], m.diam[g][ok], m.peak[g][ok], prec[ok]), q[ok]


def _window_centroid(d_g: np.ndarray, xx: np.ndarray, yy: np.ndarray, rw: np.ndarray, c: np.ndarray, iterations: int):
    """Iterated centroid of the weights ``d_g`` (n, p, p) in a soft-edged circular window of radius
    ``rw`` (n,) px that follows the estimate, from ``c`` (n, 2) px (offsets ``xx``, ``yy`` (p, p)
    from the patch centre). The window is float32 like the weights; the weighted sums are float64
    (one matrix product per iteration). Returns (centres (n, 2) px, last window (n, p, p), sum of
    the windowed weights (n,))."""
    n = d_g.shape[0]
    basis = np.stack([np.ones(xx.size), xx.ravel(), yy.ravel()], axis=1)  # (p*p, 3)
    x32, y32 = xx.astype(np.float32)[None], yy.astype(np.float32)[None]
    edge = (rw + 0.5).astype(np.float32)[:, None, None]
    for _ in range(max(1, iterations)):
        cf = c.astype(np.float32)
        rr = np.hypot(x32 - cf[:, 0, None, None], y32 - cf[:, 1, None, None])
        win = np.clip(edge - rr, 0.0, 1.0)
        sums = (d_g * win).reshape(n, -1).astype(float) @ basis
        s = sums[:, 0]
        with np.errstate(invalid="ignore", divide="ignore"):
            c = sums[:, 1:] / s[:, None]
    return c, win, s


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


def _fit_two_discs(dark, other, xx, yy, m, cov, r0, dmin, dmax):
    """Fit the union of two blurred discs to a merged blob's darkness patch.

    Model: ``a * (1 - (1 - D1)(1 - D2))`` with ``D = erfc((|x - c| - r) / (sqrt(2) s)) / 2``
    (the silhouette of two overlapping spheres is the union of their outlines). Returns
    (centres (2, 2) relative to the patch centre, radii (2,), contrast, precision (2,)) or None
    when the fit is not a clean pair of marker-sized discs.
    """
    sxx, syy, sxy = cov
    tr = sxx + syy
    disc = np.sqrt(max((sxx - syy) ** 2 / 4 + sxy**2, 0.0))
    l1, l2 = tr / 2 + disc, max(tr / 2 - disc, 1e-12)
    ang = 0.5 * np.arctan2(2 * sxy, sxx - syy)
    e = np.array([np.cos(ang), np.sin(ang)])
    half_sep = np.sqrt(max(l1 - l2, 1e-12))
    c1 = np.array(m) + half_sep * e
    c2 = np.array(m) - half_sep * e
    x0 = np.array([c1[0], c1[1], c2[0], c2[1], r0, r0, 0.9, 0.8])
    near = (np.hypot(xx - m[0], yy - m[1]) <= half_sep + r0 + 4) & ~other
    X, Y, D = xx[near], yy[near], dark[near]

    memo: dict = {}

    def parts(p):  # MINPACK asks for the Jacobian at the point whose residuals it just had
        key = p.tobytes()
        if key not in memo:
            memo.clear()
            memo[key] = _two_disc_parts(p, X, Y)
        return memo[key]

    def resid(p):
        *_, u1, u2 = parts(p)
        return p[6] * (1 - (1 - u1) * (1 - u2)) - D

    def jac(p):
        dx1, dy1, dx2, dy2, d1, d2, s, z1, z2, u1, u2 = parts(p)
        k = 1.0 / (np.sqrt(2) * s)
        g1 = -np.exp(-z1 * z1) / np.sqrt(np.pi) * p[6] * (1 - u2)  # dm/dz1
        g2 = -np.exp(-z2 * z2) / np.sqrt(np.pi) * p[6] * (1 - u1)
        J = np.empty((X.size, 8))
        J[:, 0] = g1 * k * (-dx1 / d1)
        J[:, 1] = g1 * k * (-dy1 / d1)
        J[:, 2] = g2 * k * (-dx2 / d2)
        J[:, 3] = g2 * k * (-dy2 / d2)
        J[:, 4] = -g1 * k
        J[:, 5] = -g2 * k
        J[:, 6] = 1 - (1 - u1) * (1 - u2)
        J[:, 7] = -(g1 * z1 + g2 * z2) / s * np.sign(p[7] if p[7] != 0 else 1.0)
        return J

    if X.size < x0.size:  # pragma: no cover - too few pixels
        return None
    # MINPACK's Levenberg-Marquardt (what least_squares(method="lm") runs, with its tolerances and
    # scaling) called directly: the wrapper's per-evaluation overhead was a third of these small fits
    p, _, info, _, status = leastsq(resid, x0, Dfun=jac, full_output=True, ftol=1e-8, xtol=1e-8, gtol=1e-8,
                                    maxfev=100)
    fun = info["fvec"]
    r = np.abs(p[4:6])
    cen = p[:4].reshape(2, 2)
    sep = np.linalg.norm(cen[0] - cen[1])
    rms = np.sqrt(np.mean(fun**2))
    # both spheres are the same size at about the same distance: radii must agree with each other
    # and with the expected marker radius
    if not (status in (1, 2, 3, 4) and np.all(2 * r >= dmin) and np.all(2 * r <= dmax) and sep > 0.6 * r.sum()
            and abs(r[0] - r[1]) < 0.12 * r.mean() and abs(r.mean() - r0) < 0.3 * r0
            and rms < 0.05 * abs(p[6]) and np.all(np.isfinite(p))):
        return None
    J = jac(p)
    try:
        cov_p = np.linalg.inv(J.T @ J) * (np.sum(fun**2) / max(fun.size - p.size, 1))
        prec = np.sqrt(np.abs(np.diag(cov_p)[[0, 2]]))
    except np.linalg.LinAlgError:
        return None
    return cen, r, float(abs(p[6])), prec


def _two_disc_parts(p: np.ndarray, X: np.ndarray, Y: np.ndarray):
    """Offsets, distances, blur, normalised edge distances and disc coverages of the two-disc model
    at parameters ``p`` (8,) on the pixels ``X``, ``Y`` (k,) (see :func:`_fit_two_discs`)."""
    dx1, dy1 = X - p[0], Y - p[1]
    dx2, dy2 = X - p[2], Y - p[3]
    d1 = np.hypot(dx1, dy1) + 1e-12
    d2 = np.hypot(dx2, dy2) + 1e-12
    s = abs(p[7]) + 0.3
    z1 = (d1 - p[4]) / (np.sqrt(2) * s)
    z2 = (d2 - p[5]) / (np.sqrt(2) * s)
    u1, u2 = 0.5 * erfc(z1), 0.5 * erfc(z2)
    return dx1, dy1, dx2, dy2, d1, d2, s, z1, z2, u1, u2


def _apply_polarity(image: np.ndarray, polarity: str, saturation):
    """Invert bright-on-dark images so that the dark-marker detector sees dark blobs."""
    if polarity not in ("dark", "bright"):
        raise ValueError(f"polarity must be 'dark' (dark markers on a bright background) or 'bright'; got {polarity!r}")
    if polarity == "dark":
        return image, saturation
    top = np.iinfo(image.dtype).max if np.issubdtype(image.dtype, np.integer) else float(np.nanmax(image))
    return (top - image).astype(image.dtype), (None if saturation == "auto" else saturation)


def _smooth3(a: np.ndarray) -> np.ndarray:
    """3x3 box mean over the last two axes (edges replicated), as two separable 3-sums."""
    p = np.pad(a, ((0, 0), (1, 1), (1, 1)), mode="edge")
    rows = p[:, :-2] + p[:, 1:-1] + p[:, 2:]
    return (rows[:, :, :-2] + rows[:, :, 1:-1] + rows[:, :, 2:]) / a.dtype.type(9.0)


def _annulus_plane(patch, exclude, xx, yy, r_in, r_out, order=1) -> np.ndarray:
    """Robust polynomial fit ``B(x, y)`` (``order`` 1-3) to an annulus of each patch (n, P, P);
    returns B on the patch grid, float32 (n, P, P).

    The normal equations are accumulated in float64 (each ring's ``A^T A`` from the products of
    the distinct pairs of terms, as one matrix product over the blobs); residuals, their median
    and the returned surface are float32 like the patches (grey levels to ~1e-5 relative).
    """
    rr = np.hypot(xx, yy)
    ring = (rr[None] >= np.asarray(r_in)[:, None, None]) & (rr[None] <= r_out) & ~exclude
    A_full = _poly_terms(xx, yy, max(float(r_out), 1.0), order)  # (P*P, m)
    n = patch.shape[0]
    ring_f = ring.reshape(n, -1)
    # only the pixels that lie in some blob's annulus enter the fit: drop the other columns once
    # (about 60 % of the patch: the disc inside and the corners outside)
    cols = np.flatnonzero(ring_f.any(axis=0))
    A, ring_f = A_full[cols], ring_f[:, cols]
    A32 = A.astype(np.float32)
    flat = patch.reshape(n, -1)[:, cols]
    m = A.shape[1]
    iu, ju = np.triu_indices(m)
    AA = A[:, iu] * A[:, ju]  # (cols, m (m + 1) / 2): the distinct products
    w = ring_f.astype(float)
    coef = np.zeros((n, m))
    for it in range(3):
        AtA = np.empty((n, m, m))
        AtA[:, iu, ju] = AtA[:, ju, iu] = w @ AA
        AtA += 1e-9 * np.eye(m)
        Atb = (w * flat) @ A
        coef = np.linalg.solve(AtA, Atb[..., None])[..., 0]
        if it == 2:
            break
        # robust: drop annulus pixels more than 3 MAD from the plane (texture, neighbours)
        res = np.abs(flat - coef.astype(np.float32) @ A32.T)
        # a blob whose annulus is entirely excluded keeps its plain fit (infinite MAD)
        mad = _masked_median(res, ring_f) * 1.4826 + 1e-9
        mad = np.where(np.isfinite(mad), mad, np.inf)
        w = (ring_f & (res <= 3.0 * mad[:, None])).astype(float)
    return (coef.astype(np.float32) @ A_full.astype(np.float32).T).reshape(patch.shape)


def _poly_terms(xx: np.ndarray, yy: np.ndarray, scale: float, order: int) -> np.ndarray:
    """The 2-D polynomial terms (1, u, v, u^2, uv, v^2, u^3, ...) up to ``order`` of the scaled
    offsets ``u = xx / scale``, ``v = yy / scale``: (P*P, m) float64."""
    u, v = xx / scale, yy / scale
    terms = [np.ones_like(xx), u, v]
    if order >= 2:
        terms += [u * u, u * v, v * v]
    if order >= 3:
        terms += [u**3, u * u * v, u * v * v, v**3]
    return np.stack(terms, axis=-1).reshape(-1, len(terms))


def _masked_median(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Row-wise median of ``values`` (n, m) over the entries where ``mask`` (n, m) is True; NaN for
    an empty row (as ``np.nanmedian``, without its per-row Python loop)."""
    s = np.sort(np.where(mask, values, values.dtype.type(np.inf)), axis=1)
    count = mask.sum(axis=1)
    rows = np.arange(s.shape[0])
    middle = 0.5 * (s[rows, np.maximum(count - 1, 0) // 2] + s[rows, count // 2])
    return np.where(count > 0, middle, np.nan)


def _glare_blobs(image: np.ndarray, sat: float) -> np.ndarray:
    full = image >= sat
    rows = np.flatnonzero(full.any(axis=1))
    if rows.size == 0:
        return np.zeros(0, REJECT_DTYPE)
    cols = np.flatnonzero(full.any(axis=0))
    r0, c0 = rows[0], cols[0]
    m = full[r0 : rows[-1] + 1, c0 : cols[-1] + 1].astype(np.uint8)
    n, _, stats, cents = _labelled(m)
    cents = cents + np.array([c0, r0], dtype=float)
    if n <= 1:
        return np.zeros(0, REJECT_DTYPE)
    area = stats[1:, cv2.CC_STAT_AREA]
    big = area >= 4
    return _records(cents[1:][big], 2 * np.sqrt(area[big] / np.pi), np.nan, "glare")


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
