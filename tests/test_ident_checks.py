"""Setting checks (issue 10): the data tell a wrong end condition or wall form, in plain words."""

import numpy as np
import pytest

from identification.optimize import identify
from identification.checks import CHECK_LIMITS, check_setup, end_taper, with_ends
from rig_sim.mechanics import MMHG, PAPER_PARAMETERS, simulate_test

PRESSURES = np.linspace(0, 150, 6) * MMHG


@pytest.fixture(scope="module")
def clamped_tube():
    return simulate_test("fung", PAPER_PARAMETERS["fung"], clamped=True, n_markers=200, pressures=PRESSURES)


@pytest.fixture(scope="module")
def free_tube():
    return simulate_test("fung", PAPER_PARAMETERS["fung"], clamped=False, n_markers=200, pressures=PRESSURES)


def _check(sim, ends, wall="membrane", check_wall=False):
    r = identify(sim.positions, sim.pressure, sim.axial_force, thickness=sim.thickness, model="fung", ends=ends,
                 wall=wall)
    return r, check_setup(r, sim.positions, check_wall=check_wall)


@pytest.mark.parametrize("truth,wrong", [("clamped", "free"), ("free", "clamped")])
def test_wrong_end_condition_is_flagged_right_one_is_not(request, truth, wrong):
    sim = request.getfixturevalue(f"{truth}_tube")
    _, right = _check(sim, truth)
    assert right.flags == (), right.flags
    _, bad = _check(sim, wrong)
    assert any(f"assuming {truth} ends closes the virtual-work gap" in f for f in bad.flags), bad.flags
    assert bad.gap_other_ends < CHECK_LIMITS["gap_ratio"] * bad.gap


def test_with_ends_only_changes_the_end_force(clamped_tube):
    sim = clamped_tube
    r, _ = _check(sim, "clamped")
    free = with_ends(r.data, "free")
    assert np.allclose(free.end_force, sim.axial_force)
    back = with_ends(free, "clamped")
    assert np.allclose(back.evw, r.data.evw, rtol=1e-12, atol=1e-15)


def test_uniform_tube_has_no_taper(free_tube):
    r, _ = _check(free_tube, "free")
    assert np.all(np.abs(end_taper(r.data, free_tube.positions)) < 1e-6)


def test_membrane_form_on_thick_wall_is_flagged():
    sim = simulate_test("fung", PAPER_PARAMETERS["fung"], clamped=False, wall="thick", n_markers=200,
                        pressures=PRESSURES)
    _, membrane = _check(sim, "free", "membrane", check_wall=True)
    assert any("--wall thick closes the virtual-work gap" in f for f in membrane.flags), membrane.flags
    _, thick = _check(sim, "free", "thick", check_wall=True)
    assert thick.flags == (), thick.flags
