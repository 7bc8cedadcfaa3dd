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
import warnings
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.special import erfc

__all__ = ["Detections", "REJECT_DTYPE", "REJECT_REASONS", "detect_markers"]

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
    """

    centres: np.ndarray
    diameter: np.ndarray
    contrast: np.ndarray
    quality: np.ndarray
    precision: np.ndarray
    rejects: np.ndarray
    noise: float

    def __len__(self) -> int:
        return int(self.centres.shape[0])

    def reject_counts(self) -> dict[str, int]:
        """Number of rejected candidates per reason."""
        return {r: int(np.count_nonzero(self.rejects["reason"] == r)) for r in REJECT_REASONS}


def _empty(noise: float, rejects: np.ndarray | None = None) -> Detections:
    z = np.zeros(0)
    return Detections(
        np.zeros((0, 2)), z, z.copy(), z.copy(), z.copy(),
        np.zeros(0, REJECT_DTYPE) if rejects is None else rejects, float(noise),
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

    Returns
    -------
    Detections
    """
    image = np.asarray(image)
    if image.ndim != 2:
        raise ValueError(f"image must be a 2-D grey-level array (H, W); got shape {image.shape}")
    image, saturation = _apply_polarity(image, polarity, saturation)
    H, W = image.shape
    sat = _saturation_level(image, saturation)
    img = image.astype(np.float32)
    dmin, dmax = (3.0, 80.0) if diameter_range is None else map(float, diameter_range)
    if not 0 < dmin < dmax:
        raise ValueError(f"diameter_range must be (min, max) with 0 < min < max px; got {diameter_range}")

    # 1. candidates
    k = int(np.ceil(1.3 * dmax)) | 1
    closed = cv2.morphologyEx(img, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_RECT, (k, k)))
    tophat = closed - img
    sample = tophat[:: max(1, H // 256), :: max(1, W // 256)].ravel()
    med = float(np.median(sample))
    mad = float(np.median(np.abs(sample - med))) * 1.4826
    noise_img = img[:: max(1, H // 256), :: max(1, W // 256)]
    lap = noise_img[1:-1, 1:-1] - 0.25 * (noise_img[:-2, 1:-1] + noise_img[2:, 1:-1] + noise_img[1:-1, :-2] + noise_img[1:-1, 2:])
    noise = float(np.median(np.abs(lap - np.median(lap)))) * 1.4826 / np.sqrt(1.25) if lap.size else 0.0
    floor = 0.03 * float(np.median(closed[:: max(1, H // 256), :: max(1, W // 256)]))
    thr = med + max(threshold_sigma * mad, floor)
    # relative darkness against the local upper envelope: markers are nearly black, texture and
    # shading are not; the absolute threshold keeps noise in dark regions (bath) out
    rel = tophat / np.maximum(closed, 1e-6 * max(1.0, float(closed.max())))
    mask = ((tophat > thr) & (rel > min_darkness)).astype(np.uint8)
    n_lab, labels, stats, cents = cv2.connectedComponentsWithStats(mask, connectivity=8)
    areas = stats[1:, cv2.CC_STAT_AREA].astype(float)
    ids = np.arange(1, n_lab)
    # ignore specks that are a fraction of the smallest accepted marker (noise, texture)
    min_area = max(3.0, 0.25 * np.pi * (0.5 * dmin) ** 2)
    keep = areas >= min_area
    ids = ids[keep]
    if diameter_range is None and ids.size:
        # working size limit from the typical compact candidate (speeds up the patch stage)
        bwh = np.maximum(stats[ids, cv2.CC_STAT_WIDTH], stats[ids, cv2.CC_STAT_HEIGHT])
        compact = areas[keep] >= 0.5 * bwh**2
        if np.count_nonzero(compact) >= 3:
            dmax = min(dmax, max(2.0 * float(np.median(2 * np.sqrt(areas[keep][compact] / np.pi))), 4.0 * dmin))
    rejects: list[np.ndarray] = []
    if sat is not None:
        rejects.append(_glare_blobs(image, sat))
    if ids.size == 0:
        return _empty(noise, _concat(rejects))
    bw = stats[ids, cv2.CC_STAT_WIDTH]
    bh = stats[ids, cv2.CC_STAT_HEIGHT]
    bx = stats[ids, cv2.CC_STAT_LEFT]
    by = stats[ids, cv2.CC_STAT_TOP]
    cxy = cents[ids]
    big = (np.maximum(bw, bh) > 2.2 * dmax) | (areas[keep] > 2.6 * np.pi * (0.5 * dmax) ** 2)
    if np.any(big):
        rejects.append(_records(cxy[big], np.sqrt(4 * areas[keep][big] / np.pi), np.nan, "too_large"))
    ids, bw, bh, bx, by, cxy = ids[~big], bw[~big], bh[~big], bx[~big], by[~big], cxy[~big]
    if ids.size == 0:
        return _empty(noise, _concat(rejects))

    # 2. patch measurements (vectorised over candidates)
    P = int(2 * np.ceil(max(np.max(np.maximum(bw, bh)) * 0.5 + window_margin + 3, 0.5 * dmax + window_margin + 3)) + 1)
    half = P // 2
    pad_mode = cv2.BORDER_REFLECT
    img_p = cv2.copyMakeBorder(img, half, half, half, half, pad_mode)
    lab_p = cv2.copyMakeBorder(labels.astype(np.int32), half, half, half, half, cv2.BORDER_CONSTANT, value=0)
    ci = np.rint(cxy).astype(int)  # patch centre, integer pixel (x, y)
    off = np.arange(P) - half
    rows = ci[:, 1, None] + off[None, :] + half
    cols = ci[:, 0, None] + off[None, :] + half
    patch = img_p[rows[:, :, None], cols[:, None, :]]  # (n, P, P)
    plab = lab_p[rows[:, :, None], cols[:, None, :]]
    own = plab == ids[:, None, None]
    other = (plab != 0) & ~own
    yy, xx = np.meshgrid(off.astype(float), off.astype(float), indexing="ij")
    bg_plane = _annulus_plane(patch, own | other, xx, yy, r_in=0.5 * np.maximum(bw, bh) + 2.0, r_out=half - 0.5, order=background_order)
    with np.errstate(divide="ignore", invalid="ignore"):
        dark = 1.0 - patch / np.maximum(bg_plane, 1e-12)
    dark_s = _smooth3(dark)
    peak = np.max(np.where(own, dark_s, -np.inf), axis=(1, 2))
    halfmask = own & (dark > 0.5 * peak[:, None, None])
    a_half = halfmask.sum(axis=(1, 2)).astype(float)
    diam = 2.0 * np.sqrt(a_half / np.pi)
    # second moments of the half-contrast area
    with np.errstate(invalid="ignore", divide="ignore"):
        mx = (halfmask * xx).sum((1, 2)) / a_half
        my = (halfmask * yy).sum((1, 2)) / a_half
        sxx = (halfmask * (xx - mx[:, None, None]) ** 2).sum((1, 2)) / a_half
        syy = (halfmask * (yy - my[:, None, None]) ** 2).sum((1, 2)) / a_half
        sxy = (halfmask * (xx - mx[:, None, None]) * (yy - my[:, None, None])).sum((1, 2)) / a_half
    tr = sxx + syy
    disc = np.sqrt(np.maximum((sxx - syy) ** 2 / 4 + sxy**2, 0.0))
    l1 = tr / 2 + disc
    l2 = np.maximum(tr / 2 - disc, 1e-12)
    elong = np.sqrt(l1 / l2)
    near_edge = (bx < edge_margin) | (by < edge_margin) | (bx + bw > W - edge_margin) | (by + bh > H - edge_margin)
    glare = np.zeros(ids.size, dtype=bool)
    if sat is not None:
        rr = np.hypot(xx, yy)
        glare = np.any((patch >= sat) & (rr[None] <= (0.5 * diam + window_margin)[:, None, None]), axis=(1, 2))

    reason = np.full(ids.size, "", dtype="U12")
    reason[glare] = "glare"
    reason[(reason == "") & near_edge] = "edge"
    reason[(reason == "") & ~np.isfinite(peak)] = "low_contrast"
    if diameter_range is None:
        plausible = (reason == "") & (elong < max_elongation) & (diam >= dmin)
        if np.any(plausible):
            dmed = float(np.median(diam[plausible]))
            lo, hi = 0.6 * dmed, 1.5 * dmed
        else:
            lo, hi = dmin, dmax
    else:
        lo, hi = dmin, dmax
    dref = 0.5 * (lo + hi) if diameter_range is not None else (lo + hi) / 2.1
    area_ratio = a_half / (np.pi * (0.5 * dref) ** 2)
    merged = (elong > max_elongation) & (area_ratio > 1.4)
    reason[(reason == "") & merged] = "merged"
    reason[(reason == "") & (elong > max_elongation)] = "not_round"
    reason[(reason == "") & (diam < lo)] = "too_small"
    reason[(reason == "") & (diam > hi)] = "too_large"
    good = reason == ""
    if np.any(good):
        cref = float(np.median(peak[good]))
        reason[good & (peak < min_relative_contrast * cref)] = "low_contrast"
    split_c, split_d, split_a, split_p = np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(0)
    if split_merged:
        cand = np.flatnonzero(reason == "merged")
        parts = []
        for i in cand:  # merged blobs are few; each is a small 8-parameter fit
            fit = _fit_two_discs(dark[i], other[i], xx, yy, (mx[i], my[i]), (sxx[i], syy[i], sxy[i]), 0.5 * dref, lo, hi)
            if fit is not None:
                parts.append((i, fit))
                reason[i] = "split"
        if parts:
            split_c = np.concatenate([ci[i].astype(float) + f[0] for i, f in parts])
            split_d = np.concatenate([2 * f[1] for _, f in parts])
            split_a = np.concatenate([np.full(2, f[2]) for _, f in parts])
            split_p = np.concatenate([f[3] for _, f in parts])
    bad = (reason != "") & (reason != "split")
    if np.any(bad):
        rec = _records(cxy[bad], diam[bad], peak[bad], "")
        rec["reason"] = reason[bad]
        rejects.append(rec)
    good = reason == ""
    if not np.any(good) and split_c.shape[0] == 0:
        return _empty(noise, _concat(rejects))

    # 3. sub-pixel centroid of normalised darkness in a soft circular window
    g = np.flatnonzero(good)
    centres, prec, q, ok = np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(0, bool)
    if g.size:
        d_g = dark[g]
        d_g = np.where(other[g], 0.0, d_g)
        if centroid_threshold > 0:
            d_g = np.maximum(d_g - centroid_threshold * peak[g][:, None, None], 0.0)
        rw = 0.5 * diam[g] + window_margin
        c = np.stack([mx[g], my[g]], axis=1)  # relative to the patch centre pixel
        for _ in range(max(1, iterations)):
            rr = np.hypot(xx[None] - c[:, 0, None, None], yy[None] - c[:, 1, None, None])
            win = np.clip(rw[:, None, None] + 0.5 - rr, 0.0, 1.0)
            wgt = d_g * win
            s = wgt.sum((1, 2))
            c = np.stack([(wgt * xx).sum((1, 2)) / s, (wgt * yy).sum((1, 2)) / s], axis=1)
        # noise-limited precision: var(cx) = sigma_rel^2 sum(win (x - cx)^2) / s^2
        sigma_rel = noise / np.maximum(np.median(bg_plane[g], axis=(1, 2)), 1e-12)
        prec = sigma_rel * np.sqrt((win * ((xx[None] - c[:, 0, None, None]) ** 2)).sum((1, 2))) / np.abs(s)
        centres = ci[g].astype(float) + c
        ok = np.all(np.isfinite(centres), axis=1)
        if not np.all(ok):
            rejects.append(_records(cxy[g][~ok], diam[g][~ok], peak[g][~ok], "low_contrast"))
        q = np.sqrt(l2 / np.maximum(l1, 1e-12))[g]
    centres = np.concatenate([centres[ok], split_c])
    diameter = np.concatenate([diam[g][ok], split_d])
    contrast = np.concatenate([peak[g][ok], split_a])
    quality = np.concatenate([q[ok], np.full(split_c.shape[0], 0.5)])
    precision = np.concatenate([prec[ok], split_p])
    order = np.lexsort((centres[:, 0], centres[:, 1]))
    return Detections(
        centres=centres[order],
        diameter=diameter[order],
        contrast=contrast[order],
        quality=quality[order],
        precision=precision[order],
        rejects=_concat(rejects),
        noise=noise,
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

    def parts(p):
        dx1, dy1 = X - p[0], Y - p[1]
        dx2, dy2 = X - p[2], Y - p[3]
        d1 = np.hypot(dx1, dy1) + 1e-12
        d2 = np.hypot(dx2, dy2) + 1e-12
        s = abs(p[7]) + 0.3
        z1 = (d1 - p[4]) / (np.sqrt(2) * s)
        z2 = (d2 - p[5]) / (np.sqrt(2) * s)
        u1, u2 = 0.5 * erfc(z1), 0.5 * erfc(z2)
        return dx1, dy1, dx2, dy2, d1, d2, s, z1, z2, u1, u2

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

    try:
        sol = least_squares(resid, x0, jac=jac, method="lm", max_nfev=100)
    except ValueError:  # pragma: no cover - too few pixels
        return None
    p = sol.x
    r = np.abs(p[4:6])
    cen = p[:4].reshape(2, 2)
    sep = np.linalg.norm(cen[0] - cen[1])
    rms = np.sqrt(np.mean(sol.fun**2))
    # both spheres are the same size at about the same distance: radii must agree with each other
    # and with the expected marker radius
    if not (sol.success and np.all(2 * r >= dmin) and np.all(2 * r <= dmax) and sep > 0.6 * r.sum()
            and abs(r[0] - r[1]) < 0.12 * r.mean() and abs(r.mean() - r0) < 0.3 * r0
            and rms < 0.05 * abs(p[6]) and np.all(np.isfinite(p))):
        return None
    J = sol.jac
    try:
        cov_p = np.linalg.inv(J.T @ J) * (np.sum(sol.fun**2) / max(sol.fun.size - p.size, 1))
        prec = np.sqrt(np.abs(np.diag(cov_p)[[0, 2]]))
    except np.linalg.LinAlgError:
        return None
    return cen, r, float(abs(p[6])), prec


def _apply_polarity(image: np.ndarray, polarity: str, saturation):
    """Invert bright-on-dark images so that the dark-marker detector sees dark blobs."""
    if polarity not in ("dark", "bright"):
        raise ValueError(f"polarity must be 'dark' (dark markers on a bright background) or 'bright'; got {polarity!r}")
    if polarity == "dark":
        return image, saturation
    top = np.iinfo(image.dtype).max if np.issubdtype(image.dtype, np.integer) else float(np.nanmax(image))
    return (top - image).astype(image.dtype), (None if saturation == "auto" else saturation)


def _smooth3(a: np.ndarray) -> np.ndarray:
    """3x3 box mean over the last two axes (edges replicated)."""
    p = np.pad(a, ((0, 0), (1, 1), (1, 1)), mode="edge")
    s = sum(p[:, i : i + a.shape[1], j : j + a.shape[2]] for i in range(3) for j in range(3))
    return s / 9.0


def _annulus_plane(patch, exclude, xx, yy, r_in, r_out, order=1) -> np.ndarray:
    """Robust plane fit ``B = a + b x + c y`` to an annulus of each patch; returns B on the patch grid."""
    rr = np.hypot(xx, yy)
    ring = (rr[None] >= np.asarray(r_in)[:, None, None]) & (rr[None] <= r_out) & ~exclude
    sc = max(float(r_out), 1.0)
    u, v = xx / sc, yy / sc
    terms = [np.ones_like(xx), u, v]
    if order >= 2:
        terms += [u * u, u * v, v * v]
    if order >= 3:
        terms += [u**3, u * u * v, u * v * v, v**3]
    A = np.stack(terms, axis=-1).reshape(-1, len(terms))  # (P*P, m)
    m = A.shape[1]
    AA = (A[:, :, None] * A[:, None, :]).reshape(-1, m * m)
    n = patch.shape[0]
    flat = patch.reshape(n, -1)
    ring_f = ring.reshape(n, -1)
    w = ring_f.astype(float)
    coef = np.zeros((n, m))
    for it in range(3):
        AtA = (w @ AA).reshape(n, m, m) + 1e-9 * np.eye(m)
        Atb = (w * flat) @ A
        coef = np.linalg.solve(AtA, Atb[..., None])[..., 0]
        if it == 2:
            break
        # robust: drop annulus pixels more than 3 MAD from the plane (texture, neighbours)
        res = np.abs(flat - coef @ A.T)
        rabs = np.where(ring_f, res, np.nan)
        with warnings.catch_warnings():  # a blob whose annulus is entirely excluded: keep its plain fit
            warnings.simplefilter("ignore", RuntimeWarning)
            mad = np.nanmedian(rabs, axis=1) * 1.4826 + 1e-9
        mad = np.where(np.isfinite(mad), mad, np.inf)
        w = (ring_f & (res <= 3.0 * mad[:, None])).astype(float)
    return (coef @ A.T).reshape(patch.shape)


def _glare_blobs(image: np.ndarray, sat: float) -> np.ndarray:
    full = image >= sat
    rows = np.flatnonzero(full.any(axis=1))
    if rows.size == 0:
        return np.zeros(0, REJECT_DTYPE)
    cols = np.flatnonzero(full.any(axis=0))
    r0, c0 = rows[0], cols[0]
    m = full[r0 : rows[-1] + 1, c0 : cols[-1] + 1].astype(np.uint8)
    n, _, stats, cents = cv2.connectedComponentsWithStats(m, connectivity=8)
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
