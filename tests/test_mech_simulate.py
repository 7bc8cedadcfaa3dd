"""rig_sim.simulate: simulated tests, marker layout, exact surface access."""

import math

import numpy as np
import pytest

from rig_sim.markers import min_marker_spacing
from rig_sim.materials import PAPER_PARAMETERS
from rig_sim.simulate import PAPER_PRESSURES, simulate_test
from rig_sim.tube import inflate_membrane, inflate_thick

FUNG = PAPER_PARAMETERS["fung"]


def _homog(**kw):
    return simulate_test("fung", FUNG, clamped=False, **kw)


def test_shapes_and_step_order():
    s = _homog(stretches=(1.1, 1.2), n_markers=120)
    n = 1 + 2 * 8
    assert s.positions.shape == (n, 120, 3) and s.exact_positions.shape == (n, 120, 3)
    for a in (s.pressure, s.axial_force, s.transducer_force, s.stretch, s.lumen_radius):
        assert a.shape == (n,)
    assert s.pressure[0] == 0 and s.stretch[0] == 1 and s.axial_force[0] == 0
    np.testing.assert_array_equal(s.pressure[1:9], PAPER_PRESSURES)
    np.testing.assert_array_equal(s.stretch[1:9], 1.1)
    np.testing.assert_array_equal(s.stretch[9:], 1.2)
    np.testing.assert_array_equal(s.marker_ids, np.arange(120))
    # reference step: markers on the undeformed cylinder of radius R, z = Z
    r0 = np.hypot(s.positions[0, :, 0], s.positions[0, :, 1])
    np.testing.assert_allclose(r0, 10e-3, rtol=1e-14)
    np.testing.assert_allclose(s.positions[0, :, 2], s.marker_Z, atol=1e-18)


def test_homogeneous_kinematics_and_force():
    s = _homog(stretches=(1.2,), n_markers=50)
    ref = inflate_membrane("fung", FUNG, PAPER_PRESSURES, 1.2, radius=10e-3, thickness=1.3e-3)
    r = np.hypot(s.positions[1:, :, 0], s.positions[1:, :, 1])
    np.testing.assert_allclose(r, np.broadcast_to((ref.lam_theta * 10e-3)[:, None], r.shape), rtol=1e-13)
    np.testing.assert_allclose(s.positions[1:, :, 2], np.broadcast_to(1.2 * s.marker_Z, (8, 50)), rtol=1e-13, atol=1e-18)
    np.testing.assert_allclose(s.axial_force[1:], ref.wall_force, rtol=1e-13)
    np.testing.assert_allclose(s.transducer_force[1:], ref.wall_force - PAPER_PRESSURES * np.pi * ref.radius**2,
                               rtol=1e-12, atol=1e-12)


def test_thick_wall_markers_on_outer_surface():
    s = simulate_test("hgo", PAPER_PARAMETERS["hgo"], clamped=False, wall="thick", n_markers=40)
    ref = inflate_thick("hgo", PAPER_PARAMETERS["hgo"], PAPER_PRESSURES, 1.1, radius=10e-3, thickness=1.3e-3)
    r = np.hypot(s.positions[1:, :, 0], s.positions[1:, :, 1])
    np.testing.assert_allclose(r, np.broadcast_to(ref.outer_radius[:, None], r.shape), rtol=1e-13)
    np.testing.assert_allclose(s.lumen_radius[1:], ref.inner_radius, rtol=1e-13)
    np.testing.assert_allclose(s.axial_force[1:], ref.wall_force, rtol=1e-13)


def test_determinism_and_noise():
    a = _homog(n_markers=300, seed=3)
    b = _homog(n_markers=300, seed=3)
    np.testing.assert_array_equal(a.positions, b.positions)
    c = _homog(n_markers=300, seed=4)
    assert not np.allclose(a.marker_theta, c.marker_theta)
    sigma = 0.17e-3
    n = _homog(n_markers=300, seed=3, noise_std=sigma)
    np.testing.assert_array_equal(n.exact_positions, a.positions)  # noise does not move the layout
    d = (n.positions - n.exact_positions).ravel()
    # 9 steps x 300 markers x 3 = 8100 samples: sample std within ~4 standard errors
    assert abs(d.std() / sigma - 1) < 4 / math.sqrt(2 * d.size)
    assert abs(d.mean()) < 4 * sigma / math.sqrt(d.size)


def test_marker_layout_quasi_uniform():
    s = _homog(n_markers=300, marker_margin=4e-3)
    half = 35e-3 / 2 - 4e-3
    assert np.all(np.abs(s.marker_Z) <= half)
    assert np.all((s.marker_theta >= 0) & (s.marker_theta < 2 * np.pi))
    mean_spacing = math.sqrt(2 * math.pi * 10e-3 * 2 * half / 300)
    assert min_marker_spacing(s.marker_theta, s.marker_Z, 10e-3) > 0.45 * mean_spacing
    # every angular sextant and every axial third is populated roughly evenly
    counts = np.histogram2d(s.marker_theta, s.marker_Z, bins=(6, 3), range=((0, 2 * np.pi), (-half, half)))[0]
    assert counts.min() > 0.6 * 300 / 18


def test_surface_and_normal():
    s = _homog(stretches=(1.1,), n_markers=20)
    th = np.linspace(0, 2 * np.pi, 7)
    Z = np.linspace(-10e-3, 10e-3, 7)
    n = s.normal(5, th, Z)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1, rtol=1e-14)
    p = s.surface(5, th, Z)
    np.testing.assert_allclose(n[:, :2], p[:, :2] / np.hypot(p[:, 0], p[:, 1])[:, None], rtol=1e-12)
    np.testing.assert_allclose(s.surface(5, s.marker_theta, s.marker_Z), s.exact_positions[5])
    with pytest.raises(ValueError, match="Z must lie within"):
        s.surface(1, [0.0], [0.03])


def test_validation_messages():
    with pytest.raises(ValueError, match="wall must be"):
        _homog(wall="shell")
    with pytest.raises(ValueError, match="pressures"):
        _homog(pressures=[-1.0])
    with pytest.raises(NotImplementedError, match="membrane"):
        simulate_test("fung", FUNG, clamped=True, wall="thick")
