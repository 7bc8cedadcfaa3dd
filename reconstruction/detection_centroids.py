"""Marker detection, step 3: centres. Merged pairs split by a two-disc fit, and the iterated windowed
centroid of every accepted blob.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.optimize import leastsq
from scipy.special import erfc

from .detection_measure import _Measures
from .detection_records import _records


class _Split(NamedTuple):
    """Centres recovered from merged blobs (two per fitted blob)."""

    centres: np.ndarray  # (m, 2) px
    diameter: np.ndarray  # (m,) px
    contrast: np.ndarray  # (m,)
    precision: np.ndarray  # (m,) px


_NO_SPLIT = _Split(np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(0))


def _split_groups(groups: list, reason: np.ndarray, dref: float, lo: float, hi: float) -> _Split:
    """Step 2c per patch-size group (``reason`` of all blobs, updated in place)."""
    parts = []
    for idx, mg in groups:
        r = reason[idx]
        parts.append(_split_merged(mg, r, dref, lo, hi))
        reason[idx] = r
    return _Split(*(np.concatenate([p[k] for p in parts]) for k in range(4)))


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
