"""rig_sim.clamped: the clamped-end membrane tube solved as a BVP."""

import math

import numpy as np
import pytest

from rig_sim.clamped import solve_clamped
from rig_sim.materials import PAPER_PARAMETERS, membrane_cauchy
from rig_sim.simulate import MMHG, simulate_test
from rig_sim.tube import inflate_membrane

R, H, L = 10e-3, 1.3e-3, 35e-3
P3 = np.array([0.0, 75.0, 150.0]) * MMHG


@pytest.fixture(scope="module")
def fung_sols():
    return solve_clamped("fung", PAPER_PARAMETERS["fung"], P3, 1.2, radius=R, thickness=H, length=L)


def test_boundary_conditions_and_symmetry(fung_sols):
    Z = np.linspace(-L / 2, L / 2, 41)
    for s in fung_sols:
        assert s.max_rms_residual < 1e-8
        r, z, a, b = s.evaluate(Z)
        assert r[0] == pytest.approx(R, rel=1e-10) and r[-1] == pytest.approx(R, rel=1e-10)
        assert z[-1] == pytest.approx(1.2 * L / 2, rel=1e-10) and z[0] == pytest.approx(-1.2 * L / 2, rel=1e-10)
        np.testing.assert_allclose(r, r[::-1], rtol=1e-7)
        np.testing.assert_allclose(z, -z[::-1], rtol=0, atol=1e-9 * L)
        np.testing.assert_allclose(a, -a[::-1], rtol=0, atol=1e-6)
    # pressure makes the tube bulge between the cannulae
    r_mid = [s.evaluate([0.0])[0][0] for s in fung_sols]
    assert r_mid[0] < R < r_mid[1] < r_mid[2]


def test_equilibrium_residuals(fung_sols):
    """Axial: N(Z) - p pi r(Z)^2 is constant (the transducer force). Radial: d/dZ(r T_s sin psi) = ..."""
    par = PAPER_PARAMETERS["fung"]
    for s in fung_sols[1:]:
        Z = s.Z
        r, _, a, b = s.y
        n_wall = s.wall_force(Z)
        ft = n_wall - s.pressure * np.pi * r**2
        assert np.ptp(ft) < 1e-6 * np.max(np.abs(n_wall))
        assert s.transducer_force == pytest.approx(np.mean(ft), rel=1e-9)
        assert s.end_wall_force == pytest.approx(s.transducer_force + s.pressure * np.pi * R**2, rel=1e-6)
        # radial equilibrium, independent finite-difference check on the BVP mesh
        ls = np.hypot(a, b)
        st, ss = membrane_cauchy("fung", par, r / R, ls)
        h = H / (r / R * ls)
        t_t, t_s = st * h, ss * h
        q_r = r * t_s * a / ls
        lhs = np.gradient(q_r, Z, edge_order=2)
        rhs = ls * t_t - s.pressure * r * b
        scale = np.max(np.abs(s.pressure * r * b))
        inner = slice(5, -5)
        assert np.max(np.abs(lhs - rhs)[inner]) < 2e-3 * scale


def test_reduces_to_homogeneous_when_clamp_matches():
    par = PAPER_PARAMETERS["delfino"]
    p = 100 * MMHG
    hom = inflate_membrane("delfino", par, [0.0, p], 1.15, radius=R, thickness=H)
    sols = solve_clamped("delfino", par, [0.0, p], 1.15, radius=R, thickness=H, length=L,
                         clamp_radius=float(hom.radius[1]))
    s = sols[1]
    Z = np.linspace(-L / 2, L / 2, 21)
    r, z, a, b = s.evaluate(Z)
    np.testing.assert_allclose(r, np.full_like(Z, hom.radius[1]), rtol=1e-9)
    np.testing.assert_allclose(z, 1.15 * Z, rtol=1e-9, atol=1e-12)
    assert s.end_wall_force == pytest.approx(float(hom.wall_force[1]), rel=1e-8)


@pytest.mark.parametrize("model", ["fung", "hgo"])
def test_long_tube_midspan_is_homogeneous(model):
    """Far from the cannulae (L = 20 R) the state is the homogeneous one at the mid-span axial stretch."""
    par = PAPER_PARAMETERS[model]
    p = 120 * MMHG
    length = 20 * R
    s = solve_clamped(model, par, [0.0, p], 1.2, radius=R, thickness=H, length=length)[1]
    r, _, a, b = s.evaluate([0.0])
    assert abs(a[0]) < 1e-9
    hom = inflate_membrane(model, par, p, float(b[0]), radius=R, thickness=H)
    assert r[0] == pytest.approx(float(hom.radius[0]), rel=1e-7)
    assert float(b[0]) == pytest.approx(1.2, rel=2e-2)  # the ends take a little of the stretch
    # the wall force at mid-span is the homogeneous one at that stretch
    assert s.wall_force([0.0])[0] == pytest.approx(float(hom.wall_force[0]), rel=1e-6)


def test_simulate_clamped_markers_on_profile():
    sim = simulate_test("fung", PAPER_PARAMETERS["fung"], stretches=(1.2,), pressures=P3, n_markers=80)
    assert sim.clamped and sim.positions.shape == (4, 80, 3)
    r = np.hypot(sim.exact_positions[..., 0], sim.exact_positions[..., 1])
    for k in range(1, 4):
        rp, zp, _, _ = sim.profile(k, sim.marker_Z)
        np.testing.assert_allclose(r[k], rp, rtol=1e-12)
        np.testing.assert_allclose(sim.exact_positions[k, :, 2], zp, rtol=1e-12)
    # clamps hold the radius at the ends; transducer = wall force at the cannula - p pi R^2
    np.testing.assert_allclose(sim.profile_r[1:, [0, -1]], R, rtol=1e-10)
    np.testing.assert_allclose(sim.transducer_force, sim.axial_force - sim.pressure * math.pi * R**2, rtol=1e-12,
                               atol=1e-12)
    # heterogeneous: the circumferential stretch varies along the measured region
    rk = r[3] / R
    assert rk.max() - rk.min() > 0.02
    # a second simulation (other layout, cached BVP) sees the same tube
    other = simulate_test("fung", PAPER_PARAMETERS["fung"], stretches=(1.2,), pressures=P3, n_markers=80, seed=1)
    np.testing.assert_array_equal(other.profile_r, sim.profile_r)
    assert not np.array_equal(other.marker_Z, sim.marker_Z)


def test_stretch_must_exceed_one():
    with pytest.raises(ValueError, match="stretch must exceed 1"):
        solve_clamped("fung", PAPER_PARAMETERS["fung"], [0.0], 1.0)


# --- axially varying material (rig_sim.regional) -------------------------------------------------------------------

def test_weakened_zone_equilibrium_with_local_law():
    """With m(Z) the ring equilibrium holds pointwise with the local law (independent finite-difference check)."""
    from rig_sim.regional import AxialProfile

    prof = AxialProfile(depth=0.4, center=4e-3, width=L / 4, gradient=6.0)
    par = PAPER_PARAMETERS["fung"]
    s = solve_clamped("fung", par, P3, 1.1, radius=R, thickness=H, length=L, stress_scale=prof)[2]
    Z, (r, _, a, b) = s.Z, s.y
    ft = s.wall_force(Z) - s.pressure * np.pi * r**2
    assert np.ptp(ft) < 1e-6 * np.max(np.abs(s.wall_force(Z)))
    ls = np.hypot(a, b)
    st, ss = (prof(Z) * c for c in membrane_cauchy("fung", par, r / R, ls))
    h = H / (r / R * ls)
    lhs = np.gradient(r * ss * h * a / ls, Z, edge_order=2)
    rhs = ls * st * h - s.pressure * r * b
    assert np.max(np.abs(lhs - rhs)[5:-5]) < 2e-3 * np.max(np.abs(s.pressure * r * b))
    # the weak zone bulges: the radius peaks inside it, not at mid-span
    assert abs(Z[np.argmax(r)] - 4e-3) < 2e-3


def test_long_weak_zone_is_locally_homogeneous():
    """A weak zone 8 R long in a 20 R tube: at its centre the state is the homogeneous tube with beta * 0.6."""
    from rig_sim.regional import AxialProfile

    par = PAPER_PARAMETERS["fung"]
    p = 120 * MMHG
    prof = AxialProfile(depth=0.4, center=0.0, width=8 * R, edge=R)
    s = solve_clamped("fung", par, [0.0, p], 1.2, radius=R, thickness=H, length=20 * R, stress_scale=prof)[1]
    r, _, a, b = s.evaluate([0.0])
    weak = dict(par, beta=par["beta"] * float(prof(np.array([0.0]))[0]))
    hom = inflate_membrane("fung", weak, p, float(b[0]), radius=R, thickness=H)
    assert abs(a[0]) < 1e-9
    assert r[0] == pytest.approx(float(hom.radius[0]), rel=2e-4)
    strong = inflate_membrane("fung", par, p, float(b[0]), radius=R, thickness=H)
    assert abs(float(strong.radius[0]) / r[0] - 1) > 10 * abs(float(hom.radius[0]) / r[0] - 1)


def test_simulated_heterogeneous_test_records_its_profile():
    from rig_sim.regional import AxialProfile

    prof = AxialProfile(depth=0.4, center=5e-3)
    with pytest.raises(ValueError, match="clamped"):
        simulate_test("fung", PAPER_PARAMETERS["fung"], clamped=False, stress_scale=prof)
    with pytest.raises(ValueError, match="depth"):
        AxialProfile(depth=1.2)
    m = prof(np.array([-15e-3, 5e-3]))
    assert m[0] == pytest.approx(1.0, abs=1e-6) and m[1] == pytest.approx(0.6, abs=1e-6)
    assert prof.band_mean([2e-3, 8e-3, 11e-3, 17e-3])[[0, 2]] == pytest.approx([0.6, 1.0], abs=0.01)
