"""Sub-pixel centres of small particle images (a few px, often touching), vectorised over all blobs.

Estimators, each from the background-removed image ``top`` and the blob labels of
:func:`reconstruction.particles.detect_particles`:

- ``"centroid"``: grey-weighted centroid of the blob's pixels above half the threshold (the default;
  OpenPTV's ``targ_rec`` does the same). Biased towards the pixel centre for small images (peak locking)
  and, for touching particles split at their peaks, towards the side of the blob the split left it.
- ``"gauss3"``: three-point Gaussian peak fit per axis through the brightest pixel and its two
  neighbours (Willert & Gharib 1991; the standard sub-pixel estimator of PIV and PTV).
- ``"gauss3_smoothed"``: the same on the image correlated with a Gaussian of MATCHED_FILTER_PX (a matched
  filter: the peak of the correlation with the particle's shape, which averages the pixel noise).
- ``"gauss2d"``: least-squares fit of a round 2-D Gaussian (amplitude, centre, width) on the
  ``(2r+1)^2`` window around the brightest pixel; pixels of other blobs masked in a first fit, then each
  particle refitted on the image minus its neighbours' fitted Gaussians (touching particles fitted
  jointly by alternation). Falls back to ``gauss3`` where a fit does not converge.
- ``"hybrid"``: the centroid for particles alone in their blob, HYBRID_SPLIT for those split from a blob
  with others (where the split biases the centroid).

Pure functions over arrays; pixels as OpenCV (origin at the centre of the top-left pixel).
"""

from __future__ import annotations

import numpy as np

__all__ = ["CENTRE_ESTIMATORS", "peak_pixels", "gauss3_centres", "gauss2d_centres"]

CENTRE_ESTIMATORS = ("centroid", "gauss3", "gauss3_smoothed", "gauss2d", "hybrid")
#: ``hybrid``: the estimator of the particles split from a blob with others (the others keep the centroid)
HYBRID_SPLIT = "gauss2d"
#: Gaussian sigma (px) of the matched filter of ``gauss3_smoothed``
MATCHED_FILTER_PX = 1.0
#: half-width of the 2-D Gaussian fit window, px (5 x 5 window)
FIT_RADIUS_PX = 2
#: Gauss-Newton iterations of each 2-D fit round
FIT_ITERATIONS = 8
#: a 2-D fit is rejected (gauss3 kept) when its centre leaves the peak pixel by more than this, px,
#: or its width falls outside this range, px
FIT_MAX_SHIFT_PX = 1.5
FIT_SIGMA_RANGE_PX = (0.3, 3.0)


def peak_pixels(top: np.ndarray, labels: np.ndarray, n: int) -> np.ndarray:
    """Brightest pixel of each blob: ``top`` ``(H, W)``, ``labels`` ``(H, W)`` (0 = background, blobs
    1..n) -> ``(n, 2)`` int (x, y); the first in raster order on ties."""
    H, W = top.shape
    lab = labels.ravel()
    fg = np.flatnonzero(lab > 0)
    idx, val = lab[fg] - 1, top.ravel()[fg]
    order = np.lexsort((fg, -val, idx))  # per blob: brightest first, then raster order
    first = np.ones(order.size, bool)
    first[1:] = idx[order[1:]] != idx[order[:-1]]
    where = np.full(n, -1, np.int64)
    where[idx[order[first]]] = fg[order[first]]
    y, x = np.divmod(np.maximum(where, 0), W)
    return np.stack([x, y], axis=1)


def _at(top: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    H, W = top.shape
    inside = (x >= 0) & (x < W) & (y >= 0) & (y < H)
    return np.where(inside, top[np.clip(y, 0, H - 1), np.clip(x, 0, W - 1)], 0.0)


def gauss3_centres(top: np.ndarray, peaks: np.ndarray, floor: float = 0.5) -> np.ndarray:
    """Three-point Gaussian peak per axis: ``top`` ``(H, W)`` (background removed), ``peaks`` ``(n, 2)``
    int (x, y) -> centres ``(n, 2)`` px. Values are floored at ``floor`` grey levels before the log; an
    axis whose three values are not log-concave keeps the peak pixel; the offset is clipped to +-1 px."""
    x, y = peaks[:, 0], peaks[:, 1]
    c = np.log(np.maximum(_at(top, x, y), floor))
    out = peaks.astype(float)
    for k, (dx, dy) in enumerate(((1, 0), (0, 1))):
        lo = np.log(np.maximum(_at(top, x - dx, y - dy), floor))
        hi = np.log(np.maximum(_at(top, x + dx, y + dy), floor))
        den = 2.0 * (lo - 2.0 * c + hi)
        with np.errstate(divide="ignore", invalid="ignore"):
            off = np.where(den < 0, (lo - hi) / den, 0.0)
        out[:, k] += np.clip(off, -1.0, 1.0)
    return out


def _windows(img: np.ndarray, labels: np.ndarray | None, peaks: np.ndarray, r: int):
    """Pixel offsets ``(m,)`` x/y, values ``(n, m)`` and masks ``(n, m)`` (pixel inside the image and, with
    ``labels``, of this blob or of the background) of the windows around ``peaks``."""
    H, W = img.shape
    oy, ox = (a.ravel() for a in np.mgrid[-r : r + 1, -r : r + 1])
    X, Y = peaks[:, :1] + ox, peaks[:, 1:] + oy
    inside = (X >= 0) & (X < W) & (Y >= 0) & (Y < H)
    Xc, Yc = np.clip(X, 0, W - 1), np.clip(Y, 0, H - 1)
    vals = np.where(inside, img[Yc, Xc], 0.0)
    mask = inside
    if labels is not None:
        own = labels[peaks[:, 1], peaks[:, 0]][:, None]
        lab = labels[Yc, Xc]
        mask = inside & ((lab == 0) | (lab == own))
    return ox.astype(float), oy.astype(float), vals.astype(float), mask


def _fit_gaussians(ox, oy, vals, mask, p0: np.ndarray, iterations: int) -> np.ndarray:
    """Batched Levenberg-Marquardt of ``A exp(-((x - x0)^2 + (y - y0)^2) / (2 s^2))`` on window pixels at
    offsets (ox, oy) ``(m,)`` from each peak; ``vals``/``mask`` ``(n, m)``; ``p0`` ``(n, 4)`` (A, x0, y0, s),
    centre relative to the peak -> fitted ``(n, 4)``."""
    p = p0.copy()
    w = mask.astype(float)
    lam = np.full(len(p), 1e-3)

    def model(q):
        dx, dy = ox - q[:, 1:2], oy - q[:, 2:3]
        s2 = q[:, 3:4] ** 2
        g = np.exp(-(dx * dx + dy * dy) / (2 * s2))
        return g, dx, dy, s2

    g, dx, dy, s2 = model(p)
    cost = np.sum(w * (p[:, :1] * g - vals) ** 2, axis=1)
    for _ in range(iterations):
        Ag = p[:, :1] * g
        J = np.stack([g, Ag * dx / s2, Ag * dy / s2, Ag * (dx * dx + dy * dy) / (s2 * p[:, 3:4])], axis=2)
        res = vals - Ag
        JtJ = np.einsum("nmi,nm,nmj->nij", J, w, J)
        Jtr = np.einsum("nmi,nm,nm->ni", J, w, res)
        D = np.einsum("nii->ni", JtJ)
        step = np.linalg.solve(JtJ + (lam[:, None] * (D + 1e-9))[:, :, None] * np.eye(4), Jtr[:, :, None])[:, :, 0]
        q = p + step
        q[:, 3] = np.clip(q[:, 3], 0.2, 5.0)
        gq, dxq, dyq, s2q = model(q)
        cq = np.sum(w * (q[:, :1] * gq - vals) ** 2, axis=1)
        better = np.isfinite(cq) & (cq < cost)
        p[better], cost[better] = q[better], cq[better]
        g[better], dx[better], dy[better], s2[better] = gq[better], dxq[better], dyq[better], s2q[better]
        lam = np.where(better, lam * 0.3, lam * 10.0)
    return p


def _render(shape, peaks: np.ndarray, params: np.ndarray, r: int) -> np.ndarray:
    """Sum of the fitted Gaussians ``params`` ``(n, 4)`` (centres relative to ``peaks``) on ``(H, W)``, each
    over its ``(2r+1)^2`` window."""
    H, W = shape
    oy, ox = (a.ravel() for a in np.mgrid[-r : r + 1, -r : r + 1])
    X, Y = peaks[:, :1] + ox, peaks[:, 1:] + oy
    v = params[:, :1] * np.exp(-((ox - params[:, 1:2]) ** 2 + (oy - params[:, 2:3]) ** 2) / (2 * params[:, 3:4] ** 2))
    inside = (X >= 0) & (X < W) & (Y >= 0) & (Y < H)
    out = np.zeros(H * W)
    np.add.at(out, (Y * W + X)[inside], v[inside])
    return out.reshape(H, W)


def gauss2d_centres(top: np.ndarray, labels: np.ndarray, peaks: np.ndarray, *, valid: np.ndarray | None = None,
                    radius: int = FIT_RADIUS_PX, iterations: int = FIT_ITERATIONS,
                    joint: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares round 2-D Gaussian per particle.

    Parameters
    ----------
    top : ndarray, shape (H, W)
        Background-removed image (particles positive).
    labels : ndarray, shape (H, W)
        Blob labels (0 = background, blob i + 1 for ``peaks[i]``).
    peaks : ndarray of int, shape (n, 2)
        Brightest pixel (x, y) of each blob (:func:`peak_pixels`).
    valid : ndarray of bool, shape (H, W), optional
        Pixels the fit may use (e.g. not saturated); default all.
    radius : int
        Half-width of the fit window, px.
    iterations : int
        Levenberg-Marquardt iterations per round.
    joint : bool
        After the masked fit, refit every particle on the image minus its neighbours' fitted Gaussians
        (no mask): touching particles fitted jointly by alternation.

    Returns
    -------
    centres : ndarray, shape (n, 2)
        px; ``gauss3`` where the fit failed (centre > FIT_MAX_SHIFT_PX from the peak, width outside
        FIT_SIGMA_RANGE_PX).
    sigma : ndarray, shape (n,)
        Fitted width, px (NaN where the fit failed).
    """
    top = np.asarray(top, float)
    start = gauss3_centres(top, peaks) - peaks
    p0 = np.c_[np.maximum(top[peaks[:, 1], peaks[:, 0]], 1.0), start, np.ones(len(peaks))]
    ox, oy, vals, mask = _windows(top, labels, peaks, radius)
    usable = np.ones(len(peaks), bool)[:, None]
    if valid is not None:
        usable = _windows(np.asarray(valid, float), None, peaks, radius)[2] > 0.5
    p = _fit_gaussians(ox, oy, vals, mask & usable, p0, iterations)
    if joint:
        ok = _fit_ok(p)
        model_sum = _windows(_render(top.shape, peaks[ok], p[ok], radius + 1), None, peaks, radius)[2]
        own = _render_each(ox, oy, p) * ok[:, None]
        inside = _windows(top, None, peaks, radius)[3]
        p = _fit_gaussians(ox, oy, vals - (model_sum - own), inside & usable, p, iterations)
    ok = _fit_ok(p)
    centres = np.where(ok[:, None], peaks + p[:, 1:3], start + peaks)
    return centres, np.where(ok, p[:, 3], np.nan)


def _render_each(ox, oy, p) -> np.ndarray:
    return p[:, :1] * np.exp(-((ox - p[:, 1:2]) ** 2 + (oy - p[:, 2:3]) ** 2) / (2 * p[:, 3:4] ** 2))


def _fit_ok(p: np.ndarray) -> np.ndarray:
    return (np.all(np.isfinite(p), axis=1) & (np.hypot(p[:, 1], p[:, 2]) <= FIT_MAX_SHIFT_PX)
            & (p[:, 3] >= FIT_SIGMA_RANGE_PX[0]) & (p[:, 3] <= FIT_SIGMA_RANGE_PX[1]) & (p[:, 0] > 0))
