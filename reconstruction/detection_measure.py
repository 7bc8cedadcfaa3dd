"""Marker detection, step 2: measure each candidate blob on its image patch (background plane fitted on an
annulus, darkness, moments, contrast) and classify it (too small, too large, merged, not round, ...).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .detection_blobs import _Blobs, _smooth3


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
