"""Exact data from a clamped membrane tube (heterogeneous, solved independently in rig_sim/clamped_reference.py)."""

import numpy as np
import pytest

from identification import identify_prepared, prepare
from rig_sim.clamped_reference import clamped_tube
from rig_sim.homogeneous_tube import E0, PAPER

PRESSURES = np.array([30.0, 60.0, 90.0]) * 133.322387415
GENERIC = {"fung": {"beta": 10e3, "alpha11": 1.0, "alpha22": 1.0, "alpha12": 0.0},
           "delfino": {"beta": 10e3, "alpha": 1.0},
           "hgo": {"c": 5e3, "k1": 1e3, "k2": 1.0, "phi": 0.6}}


@pytest.fixture(scope="module", params=["fung", "delfino", "hgo"])
def clamped(request):
    model = request.param
    pos, p, f = clamped_tube(model, PAPER[model], PRESSURES)
    return model, pos, p, f


@pytest.mark.parametrize("start", ["default", "generic"])
def test_exact_clamped_data_gives_exact_parameters(clamped, start):
    model, pos, p, f = clamped
    data = prepare(pos, p, f, thickness=E0, ends="clamped")
    res = identify_prepared(data, model, initial=None if start == "default" else GENERIC[model], n_starts=1)
    # every parameter but the weakly identifiable alpha12 (Fung) and c (HGO, 0.4 kPa next to the fibres);
    # with only three pressure steps alpha22 may be flagged as weakly constrained, but must still be right
    for name, value in res.parameters.items():
        if name not in ("alpha12", "c"):
            assert value == pytest.approx(PAPER[model][name], rel=5e-3), (name, res.parameters, res.flags)


def test_ignoring_the_unmeasured_strip_biases_the_result(clamped):
    model, pos, p, f = clamped
    res = identify_prepared(prepare(pos, p, f, thickness=E0, ends="free"), model)
    worst = max(abs(res.parameters[n] / v - 1) for n, v in PAPER[model].items() if n not in ("alpha12", "c"))
    assert worst > 0.04


@pytest.mark.parametrize("model", ["fung", "delfino", "hgo"])
def test_rig_sim_clamped_tube_recovered(model):
    """rig_sim's clamped BVP (8 pressures to 150 mmHg at stretch 1.1, markers 4 mm clear of the cannulae)."""
    from rig_sim.mechanics import PAPER_PARAMETERS, simulate_test

    sim = simulate_test(model, PAPER_PARAMETERS[model], clamped=True)
    data = prepare(sim.positions, sim.pressure, sim.axial_force, thickness=sim.thickness, ends="clamped")
    res = identify_prepared(data, model)
    for name, value in res.parameters.items():
        if name not in ("alpha12", "c"):
            assert value == pytest.approx(PAPER_PARAMETERS[model][name], rel=5e-3), (name, res.parameters)
