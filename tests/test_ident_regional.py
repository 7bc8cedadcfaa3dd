"""identification.regional: parameters per axial band, against rig_sim's clamped tube with a material varying along
Z."""

import numpy as np
import pytest

from identification.mesh import build_mesh
from identification.regional import band_edges, band_fields, identify_regional, prepare_regional
from identification.virtual_fields import check_fields, paper_fields
from rig_sim.mechanics import PAPER_PARAMETERS, simulate_test
from rig_sim.regional import AxialProfile

FUNG = PAPER_PARAMETERS["fung"]
# a 40 % weakening over a quarter of the 35 mm specimen, centred in the top third of the marked region
WEAK = AxialProfile(depth=0.4, center=9e-3, width=35e-3 / 4)


def _fit(sim, n_bands, **options):
    rd = prepare_regional(sim.positions, sim.pressure, sim.axial_force, thickness=sim.thickness, n_bands=n_bands,
                          **options)
    res = identify_regional(rd, "fung")
    z_world = rd.world_points(rd.edges)[:, 2]  # band edges in the simulator's frame (axis along world z)
    return rd, res, z_world


@pytest.fixture(scope="module")
def weakened():
    return simulate_test("fung", FUNG, clamped=True, stress_scale=WEAK)


def test_band_fields_are_admissible_and_sum_to_the_paper_axial_field():
    sim = simulate_test("fung", FUNG, clamped=False)
    mesh = build_mesh(sim.positions[0])
    edges = band_edges(mesh, 4)
    fields = band_fields(mesh, edges)
    check_fields(fields, mesh)
    axial = fields.values[1::2, :, 2]
    np.testing.assert_allclose(np.diff(edges) @ axial / (edges[-1] - edges[0]), paper_fields(mesh).values[1, :, 2],
                               atol=1e-12)
    # each radial field lives on its own band only
    z = mesh.z
    for b in range(4):
        outside = (z < edges[b]) | (z > edges[b + 1])
        assert np.all(fields.values[2 * b, outside, 0] == 0) and np.any(fields.values[2 * b, ~outside, 0] > 0.5)
    with pytest.raises(ValueError, match="n_bands"):
        band_edges(mesh, 0)


def test_local_weakening_found_where_it_is(weakened):
    rd, res, z = _fit(weakened, 3)
    truth = FUNG["beta"] * WEAK.band_mean(z)  # band means of the true beta(Z)
    beta = res.profiles["beta"]
    weak = int(np.argmin(beta))
    assert z[weak] < WEAK.center < z[weak + 1]
    np.testing.assert_allclose(beta, truth, rtol=0.05)
    assert res.differs.tolist() == [b == weak for b in range(3)], res.flags
    assert any("band 2" in f and "differs" in f for f in res.flags)
    # the homogeneous fit misses the weak band by far more than the regional one
    gap_hom = res.homogeneous.parameters["beta"] / truth[weak] - 1
    assert gap_hom > 0.25 and abs(beta[weak] / truth[weak] - 1) < 0.05 < gap_hom / 5


def test_finer_bands_resolve_the_zone(weakened):
    rd, res, z = _fit(weakened, 6)
    truth = FUNG["beta"] * WEAK.band_mean(z)
    np.testing.assert_allclose(res.profiles["beta"], truth, rtol=0.05)
    inside = (0.5 * (z[1:] + z[:-1]) > WEAK.center - WEAK.width / 2)
    assert res.differs.tolist() == inside.tolist()


def test_homogeneous_tube_no_band_differs():
    sim = simulate_test("fung", FUNG, clamped=True)
    _, res, _ = _fit(sim, 3)
    np.testing.assert_allclose(res.profiles["beta"], FUNG["beta"], rtol=0.01)
    assert not res.differs.any(), res.flags


def test_homogeneous_noisy_tube_no_band_differs_beyond_its_uncertainty():
    """0.05 mm marker noise, displacements smoothed: bands scatter, but within their standard errors."""
    sim = simulate_test("fung", FUNG, clamped=True, noise_std=0.05e-3, seed=0)
    _, res, _ = _fit(sim, 3, smoothing=(4, 2))
    assert np.all(res.stderr["beta"] > 0)
    assert np.all(np.abs(res.z_score["beta"]) < 3.0), (res.profiles, res.stderr)
    assert not res.differs.any()
    np.testing.assert_allclose(res.profiles["beta"], FUNG["beta"], rtol=0.1)


def test_regional_names_are_checked(weakened):
    rd = prepare_regional(weakened.positions, weakened.pressure, weakened.axial_force,
                          thickness=weakened.thickness, n_bands=2)
    with pytest.raises(ValueError, match="regional"):
        identify_regional(rd, "fung", regional=("gamma",))
    with pytest.raises(ValueError, match="fields"):
        prepare_regional(weakened.positions, weakened.pressure, weakened.axial_force, thickness=1e-3, n_bands=2,
                         fields=None)


def test_cli_identify_regions_stores_profiles(tmp_path, capsys, weakened):
    import json

    from acquisition.session import SessionWriter, SpecimenInfo, StepRecord, open_session, write_result
    from vfmlab.cli import main

    sim = weakened
    path = tmp_path / "weak.h5"
    with SessionWriter.create(path, SpecimenInfo("W1", radius=sim.reference_radius, length=sim.length,
                                                 thickness=sim.thickness), load_cell_measures="wall") as w:
        for i, (lz, p, f) in enumerate(zip(sim.stretch, sim.pressure, sim.axial_force)):
            w.add_step(StepRecord(0, float(lz), float(p), float(p), float(f), float(i), 1.7e9 + i))
    n = sim.n_steps
    write_result(path, "markers", {"positions": sim.positions, "visible": np.ones((n, sim.n_markers), bool),
                                   "marker_id": np.arange(sim.n_markers), "step_index": np.arange(n)},
                 {"method": "synthetic"})
    assert main(["identify", str(path), "--regions", "3", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["units"]["beta"] == "Pa" and len(doc["profiles"]["beta"]) == 3
    assert doc["differs"] == [False, False, True]
    with open_session(path) as s:
        res = s.result(doc["result_group"])
    assert res["arrays"]["beta"] == pytest.approx(doc["profiles"]["beta"])
    assert res["arrays"]["band_edges"].shape == (4,)
    assert main(["identify", str(path), "--regions", "3"]) == 0
    out = capsys.readouterr().out
    assert "band" in out and "kPa" in out and "homogeneous fit" in out
    assert main(["identify", str(path), "--regions", "0"]) != 0


def test_stiffness_gradient_profile():
    """beta rising 30 % over the specimen length: four bands follow the band means of the truth."""
    grad = AxialProfile(gradient=0.3 / 35e-3)
    sim = simulate_test("fung", FUNG, clamped=True, stress_scale=grad)
    _, res, z = _fit(sim, 4)
    truth = FUNG["beta"] * grad.band_mean(z)
    np.testing.assert_allclose(res.profiles["beta"], truth, rtol=0.02)
    assert np.all(np.diff(res.profiles["beta"]) > 0)
