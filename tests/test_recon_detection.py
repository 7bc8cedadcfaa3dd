"""Sub-pixel marker detection on synthetic images with known centres, and rejection reasons."""

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

from _recon_synth import render_discs
from reconstruction.detection import REJECT_DTYPE, detect_markers, detect_markers_near


def _grid(n, W, H, sep, seed):
    rng = np.random.default_rng(seed)
    c = []
    while len(c) < n:
        p = rng.uniform([40, 40], [W - 40, H - 40])
        if all(np.hypot(*(p - q)) > sep for q in c):
            c.append(p)
    return np.array(c)


@pytest.mark.parametrize(
    "noise, blur, texture, tol_rms",
    [
        (0.0, 0.8, 0.0, 0.01),  # clean (float image): limited by the 8x8 supersampled rendering
        (1.5, 0.8, 0.0, 0.015),  # 8-bit with ~1 % noise: measured 0.007 px
        (1.5, 1.5, 0.01, 0.03),  # blur + smooth illumination texture: measured ~0.015 px
    ],
)
def test_centres_subpixel(noise, blur, texture, tol_rms):
    W, H = 640, 480
    c = _grid(45, W, H, 40, seed=1)
    img = render_discs((W, H), c, 16.0, noise=noise, blur=blur, texture=texture, gradient=0.3,
                       dtype=np.float32 if noise == 0 else np.uint8, seed=2)
    det = detect_markers(img)
    assert len(det) == len(c)
    d, i = cKDTree(det.centres).query(c)
    rms = np.sqrt(np.mean(d**2))
    assert rms < tol_rms, rms
    assert np.median(det.diameter) == pytest.approx(16.0, abs=0.6)
    assert np.all(det.quality > 0.9)
    assert det.contrast.min() > 0.7


def test_plain_blob_centroid_would_fail():
    """The refinement matters: the integer-pixel centroid of the thresholded blob is far worse."""
    W, H = 640, 480
    c = _grid(45, W, H, 40, seed=3)
    img = render_discs((W, H), c, 16.0, noise=1.5, blur=0.8, gradient=0.3, seed=4)
    det = detect_markers(img)
    mask = (img < 100).astype(np.uint8)
    _, _, _, cents = cv2.connectedComponentsWithStats(mask)
    d_plain = cKDTree(cents[1:]).query(c)[0]
    d_ref = cKDTree(det.centres).query(c)[0]
    assert np.sqrt(np.mean(d_ref**2)) < 0.25 * np.sqrt(np.mean(d_plain**2))


def _reject_scene():
    """8-bit 640x480 image: eight good markers, one cut by the border, a merged pair, a speck, debris, a grey
    disc and two glare spots (one touching the marker at (500, 100)); returns (image, good centres)."""
    W, H = 640, 480
    good = np.array([[100.0, 100], [200, 100], [300, 100], [400, 100], [500, 100], [100, 300], [200, 300], [300, 300]])
    extra = {
        "edge": [[4.0, 240]],  # cut by the left border
        "merged": [[450.0, 300], [462, 300]],  # two touching discs
        "too_small": [[560.0, 400]],
    }
    centres = np.vstack([good, extra["edge"], extra["merged"]])
    img = render_discs((W, H), centres, 16.0, noise=1.0, blur=0.8, gradient=0.0, seed=5, dtype=np.float32)
    img = img.copy()
    yy, xx = np.mgrid[0:H, 0:W]
    small = np.hypot(xx - 560, yy - 400) <= 2.5
    img[small] = 25
    # elongated debris
    deb = np.zeros((H, W), np.uint8)
    cv2.ellipse(deb, (150, 420), (18, 4), 30, 0, 360, 1, -1)
    img[deb > 0] = 25
    # grey (low-contrast) disc of marker size
    grey = np.hypot(xx - 300, yy - 420) <= 8
    img[grey] *= 0.6
    # glare: a saturated spot touching one marker, and one on its own
    img[np.hypot(xx - 508, yy - 96) <= 3] = 255
    img[np.hypot(xx - 560, yy - 200) <= 4] = 255
    return np.clip(np.rint(img), 0, 255).astype(np.uint8), good


def test_rejects_with_reasons():
    img, good = _reject_scene()
    det = detect_markers(img, diameter_range=(10, 24), split_merged=False)
    assert det.rejects.dtype == REJECT_DTYPE
    expected = np.delete(good, 4, axis=0)  # every good marker except the one touched by glare
    assert len(det) == 7 and np.all(cKDTree(expected).query(det.centres)[0] < 0.1)
    reasons = {}
    for r in det.rejects:
        reasons.setdefault(str(r["reason"]), []).append((r["x"], r["y"]))
    def near(reason, p, tol=6.0):
        return any(np.hypot(x - p[0], y - p[1]) < tol for x, y in reasons.get(reason, []))
    assert near("edge", (4, 240), tol=8)
    assert near("merged", (456, 300))
    assert near("too_small", (560, 400))
    assert near("not_round", (150, 420))
    assert near("low_contrast", (300, 420))
    assert near("glare", (500, 100), tol=10)  # the marker under the glare
    assert near("glare", (560, 200))  # the glare blob itself
    counts = det.reject_counts()
    assert counts["glare"] == 3 and sum(counts.values()) == len(det.rejects)


def test_merged_pairs_are_split():
    """Two markers overlapping in projection (oblique views) are recovered by a two-disc fit."""
    rng = np.random.default_rng(0)
    pairs = []
    for k in range(12):
        c = np.array([60 + 100 * (k % 6), 80 + 140 * (k // 6)], float) + rng.uniform(-0.5, 0.5, 2)
        sep, a = rng.uniform(11, 17), rng.uniform(0, np.pi)  # 16 px discs overlapping by up to 5 px
        pairs += [c, c + sep * np.array([np.cos(a), np.sin(a)])]
    pairs = np.array(pairs)
    img = render_discs((640, 360), pairs, 16.0, noise=1.5, blur=1.0, gradient=0.2, seed=3)
    det = detect_markers(img, diameter_range=(10, 24))
    assert len(det) == 24 and det.reject_counts()["merged"] == 0
    assert np.all(det.quality == 0.5)
    d = cKDTree(det.centres).query(pairs)[0]
    assert np.sqrt(np.mean(d**2)) < 0.06  # measured 0.035 px
    off = detect_markers(img, diameter_range=(10, 24), split_merged=False)
    assert len(off) == 0 and off.reject_counts()["merged"] == 12


def test_empty_image_keeps_shapes():
    img = np.full((120, 160), 180, np.uint8)
    det = detect_markers(img)
    assert det.centres.shape == (0, 2) and det.diameter.shape == (0,) and len(det.rejects) == 0
    with pytest.raises(ValueError, match="2-D grey-level"):
        detect_markers(np.zeros((4, 4, 3)))
    with pytest.raises(ValueError, match="diameter_range"):
        detect_markers(img, diameter_range=(10, 5))


def test_windowed_search_reports_as_the_whole_image():
    """detect_markers_near (the guided search) finds the same centres and gives the same reject
    reasons, near its points, as the whole-image detection with the same levels."""
    img, _ = _reject_scene()
    kw = dict(diameter_range=(10, 24), split_merged=False)
    full = detect_markers(img, **kw)
    points = np.array([[100.0, 100], [100, 300], [150, 420], [4, 240], [200, 300]])
    radius = 25.0
    near = detect_markers_near(img, points, radius, levels=(full.threshold, full.noise), max_fraction=1.0, **kw)
    assert len(near.rejects) < len(full.rejects)  # a window, not the whole image

    def close(xy):
        return cKDTree(points).query(xy)[0] <= radius

    want = full.centres[close(full.centres)]
    assert len(want) == 3 and len(near) == len(want)
    assert np.abs(near.centres - want).max() < 1e-9
    assert np.abs(near.diameter - full.diameter[close(full.centres)]).max() < 1e-9

    def reasons(det):
        xy = np.stack([det.rejects["x"], det.rejects["y"]], axis=1)
        keep = close(xy)
        return sorted((str(r), round(x), round(y)) for r, (x, y) in zip(det.rejects["reason"][keep], xy[keep]))

    assert reasons(near) == reasons(full) and {r[0] for r in reasons(full)} == {"edge", "not_round"}
