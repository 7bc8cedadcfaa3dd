"""Cylinder fit, surface normals and the marker-centre offset."""

import numpy as np
import pytest

from _recon_synth import tube_layout, tube_surface
from reconstruction.surface import fit_cylinder, marker_surface_points, surface_normals


def test_cylinder_fit_recovers_axis_and_radius():
    rng = np.random.default_rng(0)
    theta, Z = tube_layout(200, seed=1)
    s, _ = tube_surface(theta, Z)
    # tilt and shift the tube
    a = np.deg2rad(3.0)
    R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    p = s @ R.T + np.array([1e-3, -2e-3, 0.0]) + rng.normal(scale=1e-6, size=s.shape)
    cyl = fit_cylinder(p)
    assert cyl.radius == pytest.approx(4e-3, abs=2e-6)
    assert np.degrees(np.arccos(abs(cyl.axis_direction @ R[:, 2]))) < 0.05
    assert cyl.rms < 2e-6
    with pytest.raises(ValueError, match="at least 6"):
        fit_cylinder(p[:5])


@pytest.mark.parametrize("bulge", [0.0, 0.08])
def test_marker_offset_recovers_wall_points(bulge):
    """Local normals follow a bulged (non-cylindrical) wall; the cylinder radial direction does not."""
    theta, Z = tube_layout(300, seed=2)
    s, n = tube_surface(theta, Z, radial=1.2, axial=1.1, bulge=bulge, twist=0.1)
    rho = 2e-4
    centres = s + rho * n
    nl = surface_normals(centres, method="local")
    # edge markers have one-sided neighbourhoods: judge the interior and the whole set separately
    interior = np.abs(Z) < 6e-3
    err_local = np.linalg.norm(marker_surface_points(centres, rho, nl) - s, axis=1)
    err_cyl = np.linalg.norm(marker_surface_points(centres, rho, method="cylinder") - s, axis=1)
    assert np.max(err_local[interior]) < 1e-6  # well below the 5 um goal
    assert np.sqrt(np.mean(err_local**2)) < 1.5e-6  # edge markers: one-sided neighbourhoods
    if bulge:
        assert np.sqrt(np.mean(err_cyl**2)) > 5 * np.sqrt(np.mean(err_local**2))  # radial normals are wrong on a bulge
    # ignoring the offset would put the wall one marker radius too far out
    r_wall = np.hypot(s[:, 0], s[:, 1])
    r_c = np.hypot(centres[:, 0], centres[:, 1])
    assert np.mean(r_c - r_wall) > 0.9 * rho


def test_normals_validation_and_nan_rows():
    theta, Z = tube_layout(60, seed=3)
    s, _ = tube_surface(theta, Z)
    s[3] = np.nan
    nrm = surface_normals(s)
    assert np.isnan(nrm[3]).all() and np.isfinite(np.delete(nrm, 3, axis=0)).all()
    with pytest.raises(ValueError, match="method"):
        surface_normals(s, method="spline")
    with pytest.raises(ValueError, match="marker_radius"):
        marker_surface_points(s, -1.0)


def test_surface_residuals_flag_a_depth_error():
    from reconstruction.surface import surface_residuals

    theta, Z = tube_layout(300, seed=2)
    s, n = tube_surface(theta, Z, radial=1.2, axial=1.1, bulge=0.08, twist=0.1)
    c = s + 2e-4 * n + np.random.default_rng(0).normal(scale=1.5e-6, size=s.shape)
    c[10] += 60e-6 * n[10]
    r, nrm = surface_residuals(c)
    assert r[10] == pytest.approx(60e-6, abs=10e-6)
    assert np.argmax(np.abs(r)) == 10
    assert np.percentile(np.abs(np.delete(r, 10)), 90) < 15e-6
    assert np.all(np.sum(nrm * n, axis=1) > 0.99)
