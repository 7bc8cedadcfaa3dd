"""rig_sim.tube: homogeneous membrane (Laplace law) and thick-walled tube."""

import math

import numpy as np
import pytest
from scipy.integrate import quad

from rig_sim.materials import MODELS, PAPER_PARAMETERS, membrane_cauchy
from rig_sim.simulate import PAPER_PRESSURES
from rig_sim.tube import (
    MechanicsError,
    inflate_membrane,
    inflate_thick,
    membrane_pressure,
    midwall_membrane_state,
    thick_tube_state,
    transducer_force,
    wall_force_from_transducer,
)

R, H = 10e-3, 1.3e-3


@pytest.mark.parametrize("model", sorted(MODELS))
@pytest.mark.parametrize("lam_z", [1.1, 1.2])
def test_laplace_law(model, lam_z):
    par = PAPER_PARAMETERS[model]
    s = inflate_membrane(model, par, PAPER_PRESSURES, lam_z, radius=R, thickness=H)
    # Laplace law p r = sigma_tt h with sigma_tt recomputed from the closed form
    stt, szz = membrane_cauchy(model, par, s.lam_theta, lam_z)
    h = H / (s.lam_theta * lam_z)
    np.testing.assert_allclose(stt * h, PAPER_PRESSURES * s.lam_theta * R, rtol=1e-9, atol=1e-9 * stt.max() * H)
    np.testing.assert_allclose(s.wall_force, szz * 2 * np.pi * R * H / lam_z, rtol=1e-12)
    assert np.all(np.diff(s.lam_theta) > 0)  # stable branch: stretch grows with pressure
    # p = 0: hoop stress vanishes
    assert abs(stt[0]) < 1e-9 * stt.max()


def test_neohookean_limit_point_raises():
    mu = 20e3
    p_max = mu * H / (R * 1.1)  # membrane limit point of the neo-Hookean tube
    s = inflate_membrane("neohookean", {"mu": mu}, 0.9 * p_max, 1.1, radius=R, thickness=H)
    assert s.lam_theta[0] > 1
    with pytest.raises(MechanicsError, match="limit point"):
        inflate_membrane("neohookean", {"mu": mu}, 1.05 * p_max, 1.1, radius=R, thickness=H)


def _thick_reference(model, par, lam_o, lam_z):
    """Independent thick-wall solution: quad integration over the deformed radius."""
    ro = lam_o * R
    ri = math.sqrt(ro**2 - (R**2 - (R - H) ** 2) / lam_z)

    def lam_t(r):
        rho = math.sqrt((r * r - ri * ri) * lam_z + (R - H) ** 2)
        return r / rho

    def stt(r):
        return float(membrane_cauchy(model, par, lam_t(r), lam_z)[0])

    def szz(r):
        return float(membrane_cauchy(model, par, lam_t(r), lam_z)[1])

    def srr(r):
        return -quad(lambda x: stt(x) / x, r, ro, epsabs=0, epsrel=1e-13)[0]

    p = -srr(ri)
    n = 2 * math.pi * quad(lambda r: (szz(r) + srr(r)) * r, ri, ro, epsabs=0, epsrel=1e-12)[0]
    return p, n


@pytest.mark.parametrize("model", ["neohookean", "fung"])
def test_thick_wall_against_direct_quadrature(model):
    par = PAPER_PARAMETERS[model]
    lam_o = 1.15
    st = thick_tube_state(model, par, lam_o, 1.1, radius=R, thickness=H)
    p_ref, n_ref = _thick_reference(model, par, lam_o, 1.1)
    assert st.pressure[0] == pytest.approx(p_ref, rel=1e-9)
    assert st.wall_force[0] == pytest.approx(n_ref, rel=1e-9)
    assert -st.pressure[0] < st.mean_sigma_rr[0] < 0


@pytest.mark.parametrize("model", sorted(MODELS))
def test_thick_wall_tends_to_membrane(model):
    """As H/R -> 0 the thick wall and the membrane agree to O(H/R)."""
    par = PAPER_PARAMETERS[model]
    h = 1e-4 * R
    p = np.array([5e3, 15e3]) * (h / H)  # same hoop stress level as the real tube
    th = inflate_thick(model, par, p, 1.1, radius=R, thickness=h)
    me = inflate_membrane(model, par, p, 1.1, radius=R, thickness=h)
    np.testing.assert_allclose(th.lam_outer, me.lam_theta, rtol=5e-4)
    np.testing.assert_allclose(th.wall_force, me.wall_force, rtol=5e-3)


def test_thick_inflate_roundtrip_and_midwall():
    par = PAPER_PARAMETERS["fung"]
    th = inflate_thick("fung", par, PAPER_PRESSURES, 1.1, radius=R, thickness=H)
    np.testing.assert_allclose(thick_tube_state("fung", par, th.lam_outer, 1.1, radius=R, thickness=H).pressure,
                               PAPER_PRESSURES, rtol=1e-9, atol=1e-9)
    mw = midwall_membrane_state("fung", par, th.lam_outer, 1.1, radius=R, thickness=H)
    assert np.all((th.inner_radius < mw.radius) & (mw.radius < th.outer_radius))
    np.testing.assert_allclose(mw.radius, th.midwall_radius, rtol=1e-14)
    # the mid-wall membrane is much closer to the thick truth than the outer-surface membrane (pressure)
    outer = membrane_pressure("fung", par, th.lam_outer, 1.1, radius=R, thickness=H)
    err_mid = np.abs(mw.pressure[1:] / PAPER_PRESSURES[1:] - 1)
    err_out = np.abs(outer[1:] / PAPER_PRESSURES[1:] - 1)
    assert np.all(err_mid < err_out)


def test_transducer_roundtrip():
    f = transducer_force(2.0, 10e3, 9e-3)
    assert f == pytest.approx(2.0 - 10e3 * math.pi * 81e-6)
    assert wall_force_from_transducer(f, 10e3, 9e-3) == pytest.approx(2.0)
