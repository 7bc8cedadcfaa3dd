"""Synthetic particle images with known centres (Gaussian blobs integrated over the pixels, touching
neighbours, background, noise, 8-bit quantisation and saturation), for the centre-estimator test and
``benchmarks/bench_particle_centres.py``."""

from __future__ import annotations

import numpy as np
from scipy.special import erf


def particle_image(size=(256, 256), n=150, *, sigma_px=(0.7, 1.6), peak=(10.0, 200.0), background=37.0,
                   noise=1.5, pair_fraction=0.4, pair_distance_px=(2.5, 5.0), seed=0):
    """An 8-bit image ``(H, W)`` and the true centres ``(m, 2)`` (x, y, OpenCV px) of ``n`` particles plus a
    touching partner for ``pair_fraction`` of them (``pair_distance_px`` apart); widths uniform in
    ``sigma_px``, peak grey levels log-uniform in ``peak``, Gaussian noise ``noise`` grey levels."""
    rng = np.random.default_rng(seed)
    W, H = size
    c = rng.uniform(8, [W - 8, H - 8], (n, 2))
    k = rng.random(n) < pair_fraction
    ang = rng.uniform(0, 2 * np.pi, k.sum())
    d = rng.uniform(*pair_distance_px, k.sum())
    partner = c[k] + np.c_[np.cos(ang), np.sin(ang)] * d[:, None]
    c = np.concatenate([c, partner])
    m = len(c)
    s = rng.uniform(*sigma_px, m)
    a = np.exp(rng.uniform(np.log(peak[0]), np.log(peak[1]), m))
    img = np.full((H, W), background, float)
    r = 6
    for i in range(m):  # test data only: a loop is fine here
        x0, y0 = int(round(c[i, 0])), int(round(c[i, 1]))
        xs = np.arange(max(x0 - r, 0), min(x0 + r + 1, W))
        ys = np.arange(max(y0 - r, 0), min(y0 + r + 1, H))
        gx = _pixel_integral(xs, c[i, 0], s[i])
        gy = _pixel_integral(ys, c[i, 1], s[i])
        img[ys[0] : ys[-1] + 1, xs[0] : xs[-1] + 1] += a[i] * np.outer(gy, gx) * (2 * np.pi * s[i] ** 2)
    img += rng.normal(0, noise, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8), c


def _pixel_integral(u, c, s):
    """Mean over each pixel [u - 1/2, u + 1/2] of a unit 1-D Gaussian density at ``c`` of width ``s``."""
    return 0.5 * (erf((u + 0.5 - c) / (np.sqrt(2) * s)) - erf((u - 0.5 - c) / (np.sqrt(2) * s)))


def centre_errors(detected: np.ndarray, truth: np.ndarray, *, max_px: float = 1.5, touching_px: float = 5.0):
    """Errors (px) of the detections ``(k, 2)`` that have a true centre within ``max_px`` (nearest; each true
    centre once), and whether that particle has a true neighbour within ``touching_px``:
    ``(errors (j,), touching (j,) bool, truth index (j,))``."""
    from scipy.spatial import cKDTree

    d, i = cKDTree(truth).query(detected)
    keep = d <= max_px
    order = np.argsort(d)
    first = np.zeros(len(d), bool)
    seen = set()
    for j in order:  # test data only
        if keep[j] and i[j] not in seen:
            seen.add(i[j])
            first[j] = True
    nn = cKDTree(truth).query(truth, k=2)[0][:, 1]
    return d[first], nn[i[first]] <= touching_px, i[first]
