"""N-view triangulation: exactness on noise-free data, Jacobian, covariance calibration."""

import numpy as np
import pytest

from _recon_synth import camera_ring
from reconstruction.triangulation import _jacobian, triangulate, triangulate_linear, undistort_views


@pytest.fixture(scope="module")
def cams():
    return camera_ring(6)


def test_triangulate_project_roundtrip(cams):
    rng = np.random.default_rng(0)
    X = rng.normal(size=(400, 3)) * 4e-3
    px = np.stack([c.project(X) for c in cams])
    missing = rng.random(px.shape[:2]) < 0.5
    px[missing] = np.nan
    n_views = (~missing).sum(axis=0)
    tri = triangulate(px, cams)
    ok = n_views >= 2
    assert np.all(np.isfinite(tri.points[ok])) and np.all(np.isnan(tri.points[~ok]))
    assert np.max(np.abs(tri.points[ok] - X[ok])) < 1e-9
    assert np.nanmax(tri.reprojection_rms) < 1e-6
    np.testing.assert_array_equal(tri.n_views, n_views)
    # residuals are NaN exactly where a view is missing
    assert np.array_equal(np.isnan(tri.residuals[..., 0]), missing | ~ok[None, :])


def test_linear_solution_is_close_and_refinement_is_exact(cams):
    rng = np.random.default_rng(1)
    X = rng.normal(size=(50, 3)) * 4e-3
    px = np.stack([c.project(X) for c in cams])
    lin = triangulate_linear(undistort_views(px, cams), cams)
    assert np.max(np.abs(lin - X)) < 1e-9  # DLT on undistorted coordinates is exact without noise


def test_jacobian_matches_finite_differences(cams):
    rng = np.random.default_rng(2)
    X = rng.normal(size=(20, 3)) * 4e-3
    J = _jacobian(X, cams)
    h = 1e-8
    for i in range(3):
        d = np.zeros(3)
        d[i] = h
        fd = (np.stack([c.project(X + d) for c in cams]) - np.stack([c.project(X - d) for c in cams])) / (2 * h)
        np.testing.assert_allclose(J[..., i], fd, rtol=1e-5, atol=1e-3)


def test_covariance_matches_monte_carlo(cams):
    rng = np.random.default_rng(3)
    X0 = np.array([3e-3, -1e-3, 2e-3])
    n = 3000
    X = np.tile(X0, (n, 1))
    px = np.stack([c.project(X) for c in cams[:3]])
    sigma = 0.05
    px = px + rng.normal(scale=sigma, size=px.shape)
    tri = triangulate(px, cams[:3], sigma_px=sigma)
    emp = np.cov((tri.points - X0).T)
    pred = tri.covariance[0]
    # total variance and the largest principal variance agree to within Monte Carlo error
    assert np.trace(emp) == pytest.approx(np.trace(pred), rel=0.1)
    assert np.linalg.eigvalsh(emp)[-1] == pytest.approx(np.linalg.eigvalsh(pred)[-1], rel=0.1)
    # the default sigma estimate from the pooled residuals is close to the true noise
    assert triangulate(px, cams[:3]).sigma_px == pytest.approx(sigma, rel=0.1)


def test_shape_validation(cams):
    with pytest.raises(ValueError, match="pixels must have shape"):
        triangulate(np.zeros((5, 3, 2)), cams)
    empty = triangulate(np.zeros((6, 0, 2)), cams)
    assert empty.points.shape == (0, 3) and empty.covariance.shape == (0, 3, 3)
