"""Mapping correction in 3-D (benchmarks/research/mapping_correction.py): a camera whose error depends on the depth
along its line of sight, which a correction of the pixel alone cannot represent."""

import numpy as np
import pytest

from _window_rig import window_rig
from benchmarks.research.mapping_correction import MappingCorrection, corrected_cameras, fit_mapping_correction
from benchmarks.research.temporal_matching import apply_pixel_correction, fit_pixel_correction
from reconstruction.triangulation import triangulate

BOUNDS = (np.array([-0.03, -0.03, -0.02]), np.array([0.03, 0.03, 0.02]))


def _depth_error(X):
    """Camera 1's error (px) at world points ``(n, 3)``: 1 px per half-depth of the box, sheared with x."""
    z = X[:, 2] / 0.02
    x = X[:, 0] / 0.03
    return np.stack([1.0 * z + 0.4 * x * z, -0.6 * z], axis=1)


def _observations(cams, X, rng, noise=0.1):
    px = np.stack([c.project(X) for c in cams]) + rng.normal(0, noise, (len(cams), len(X), 2))
    px[0] += _depth_error(X)
    return px


def _rms(tri):
    return float(np.sqrt(np.nanmean(tri.reprojection_rms**2)))


def test_3d_correction_recovers_a_depth_dependent_error_the_pixel_correction_cannot():
    rng = np.random.default_rng(5)
    cams = window_rig()
    train = rng.uniform(*BOUNDS, (1500, 3)) * 0.95
    groups = np.arange(len(train)) % 5
    px = _observations(cams, train, rng)
    tri = triangulate(px, cams, covariance=False)
    corr = fit_mapping_correction(cams, tri.points, tri.residuals, BOUNDS, groups=groups)
    sizes = [c.image_size for c in cams]
    coef = fit_pixel_correction(px, tri.residuals, sizes, degree=3)
    # held-out particles
    test = rng.uniform(*BOUNDS, (500, 3)) * 0.95
    obs = _observations(cams, test, rng)
    none = _rms(triangulate(obs, cams, covariance=False))
    moved = np.stack(apply_pixel_correction(list(obs), coef, sizes))
    two_d = _rms(triangulate(moved, cams, covariance=False))
    three_d = _rms(triangulate(obs, corrected_cameras(cams, corr, BOUNDS), covariance=False))
    # the noise alone: 0.1 px per coordinate, 4 views (8 coordinates) of 3 unknowns per point
    floor = np.sqrt(2 * 0.1**2 * 5 / 8)
    # measured: 0.295 px without, 0.290 px with the pixel correction (degree 3), 0.111 px with the 3-D one (a pixel
    # map of degree 1 and a depth slope of degree 1 chosen by the held-out groups in every camera); floor 0.112 px
    assert none > 2.3 * floor and two_d > 2.3 * floor, (none, two_d)
    assert three_d < 1.1 * floor, (three_d, floor)
    assert corr[0].depth_degree >= 1, (corr[0].degree, corr[0].depth_degree)  # the slope varies with x


def test_corrected_rays_project_back_onto_their_pixels():
    cams = window_rig()
    coef = np.array([[0.0, 0.0], [1.0, -0.6]])  # 1 px per half-depth of the box
    depth = (BOUNDS[0][2], BOUNDS[1][2])
    zero = MappingCorrection(np.zeros((2, 2)), (1280, 1024), 2, depth, 0, 0)
    cc = corrected_cameras(cams, [MappingCorrection(coef, (1280, 1024), 2, depth, 0, 0), zero, zero, zero], BOUNDS)
    X = np.random.default_rng(1).uniform(*BOUNDS, (300, 3)) * 0.9
    px = cc[0].project(X)
    assert np.max(np.abs(px - cams[0].project(X))) > 0.5  # the correction moves the projection
    o, d = cc[0].rays(px)
    t = np.sum((X - o) * d, axis=1)
    for s in (-0.01, 0.0, 0.01):  # along the line of sight, within the box
        back = cc[0].project(o + (t + s)[:, None] * d)
        inside = np.all((o + (t + s)[:, None] * d >= BOUNDS[0]) & (o + (t + s)[:, None] * d <= BOUNDS[1]), axis=1)
        assert np.max(np.abs(back - px)[inside]) < 0.02  # measured 0.014 px
    pix = np.stack([c.project(X) for c in cc])
    assert np.max(np.linalg.norm(triangulate(pix, cc, covariance=False).points - X, axis=1)) < 1e-9


def test_bad_input_is_named():
    cams = window_rig()
    with pytest.raises(ValueError, match="model or the cross-validation groups"):
        fit_mapping_correction(cams, np.zeros((10, 3)), np.zeros((4, 10, 2)), BOUNDS)
    with pytest.raises(ValueError, match="points must be"):
        fit_mapping_correction(cams, np.zeros((10, 2)), np.zeros((4, 10, 2)), BOUNDS, model=(1, 0))
    with pytest.raises(ValueError, match="needs the measurement box"):
        corrected_cameras(cams[:1], [MappingCorrection(np.zeros((1, 2)), (1280, 1024), 2, (0.0, 1.0), 0, -1)], None)
