"""Marker detection, step 1: candidate blobs. The candidate mask (local darkness against the image noise),
its connected components within the diameter range, and the saturated glare blobs.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .detection_records import REJECT_DTYPE, _records


@dataclass(frozen=True)
class _Blobs:
    """Candidate connected components (n of them) of one image."""

    labels: np.ndarray  # (h, w) int32 label image of the mask's bounding box
    origin: tuple[int, int]  # (x0, y0) of that box in the image, px
    ids: np.ndarray  # (n,) their labels
    box: np.ndarray  # (n, 4) int: left, top, width, height, px
    cxy: np.ndarray  # (n, 2) centroid of the thresholded pixels, px


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


def _smooth3(a: np.ndarray) -> np.ndarray:
    """3x3 box mean over the last two axes (edges replicated), as two separable 3-sums."""
    p = np.pad(a, ((0, 0), (1, 1), (1, 1)), mode="edge")
    rows = p[:, :-2] + p[:, 1:-1] + p[:, 2:]
    return (rows[:, :, :-2] + rows[:, :, 1:-1] + rows[:, :, 2:]) / a.dtype.type(9.0)


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
