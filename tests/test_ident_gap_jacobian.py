"""The gap derivatives of the efficient weighting (``identification.gap_jacobian``) against plain re-preparation.

Simulated seed-paper tube (``rig_sim.simulate_test``, one stretch 1.1, 300 markers) with 0.17 mm marker noise, smoothed
on a fixed basis with harmonics (so the axis fits and the harmonic modes matter): the lean re-preparation gives
``prepare``'s data set, the readings' closed form gives ``prepare``'s finite difference, and the rigid modes leave
the gaps unchanged.
"""

import numpy as np
import pytest

from identification.gap_jacobian import Reprepare, reading_sensitivities, rigid_columns
from identification.kinematics import align_steps
from identification.resimulation import remeasured_mesh
from identification.smoothing import smoothing_basis
from identification.virtual_fields import paper_fields
from identification.vfm import PrepareSettings, internal_virtual_work, prepare
from rig_sim.mechanics import PAPER_PARAMETERS, simulate_test

H = 1.3e-3
SMOOTHING = ((0, 1), (0, 1), (1, 1))
EPS = 1e-6


def _case(ends: str, wall: str = "membrane"):
    sim = simulate_test("fung", PAPER_PARAMETERS["fung"], clamped=ends == "clamped", wall=wall, stretches=(1.1,),
                        n_markers=300, marker_margin=4e-3 if ends == "clamped" else 0.0, radius=10e-3, thickness=H,
                        length=35e-3)
    rng = np.random.default_rng(7)
    x = sim.exact_positions + 0.17e-3 * rng.standard_normal(sim.exact_positions.shape)
    aligned, _, _ = align_steps(x, x[0])
    options = dict(wall=wall, ends=ends, smoothing=SMOOTHING, reject_outliers=False, estimate_noise=False)
    data = prepare(aligned, np.array(sim.pressure), np.array(sim.axial_force), thickness=H, **options)
    return data, aligned, PrepareSettings.from_options(**options)


@pytest.fixture(scope="module")
def free():
    return _case("free")


def _prepare(data, settings, positions, mesh=None, pressure=None, force=None):
    return prepare(positions, data.pressure if pressure is None else pressure,
                   data.axial_force if force is None else force, thickness=H, mesh=mesh or data.mesh,
                   settings=settings)


def _moved(data, aligned, steps, component=0, column=1):
    """The markers of ``steps`` moved by EPS along a smoothing basis function, radially (component 0) or axially (2)
    about the reference axis."""
    B, _ = smoothing_basis(data.mesh, SMOOTHING[component])
    axis = data.mesh.axis
    local = (aligned - axis.origin) @ axis.basis.T
    th = np.arctan2(local[..., 1], local[..., 0])
    radial = np.stack([np.cos(th), np.sin(th), np.zeros_like(th)], -1) @ axis.basis
    direction = radial if component == 0 else np.broadcast_to(axis.basis[2], radial.shape)
    pos = aligned.copy()
    pos[steps] += EPS * B[:, column, None] * direction[steps]
    return pos


def _assert_same_data(a, b, rtol=1e-8):
    """The same data set to the axis fits' convergence (their stopping test: ~1e-10 relative on C)."""
    for name in ("c", "work_density", "evw"):
        x, y = getattr(a, name), getattr(b, name)
        assert np.max(np.abs(x - y)) <= rtol * np.max(np.abs(y)), name


@pytest.mark.parametrize("wall, ends", [("membrane", "free"), ("thick", "free"), ("membrane", "clamped")])
def test_reprepare_gives_prepares_data_for_moved_loaded_steps_and_a_moved_reference(wall, ends, free):
    data, aligned, settings = free if (wall, ends) == ("membrane", "free") else _case(ends, wall)
    again = Reprepare(data, aligned, settings)
    assert again.lean
    loaded = _moved(data, aligned, slice(1, None))
    _assert_same_data(again(loaded), _prepare(data, settings, loaded))
    reference = _moved(data, aligned, slice(0, 1), component=2)
    mesh = remeasured_mesh(data.mesh, reference[0])
    _assert_same_data(again(reference, m=mesh), _prepare(data, settings, reference, mesh=mesh))


@pytest.mark.parametrize("ends", ["free", "clamped"])
def test_readings_closed_form_equals_the_reprepared_difference(ends, free):
    data, aligned, settings = free if ends == "free" else _case(ends)
    p = data.pressure
    assert p[1] == 0.0  # the stretched step before the first pressure level: its unit pressure's work re-prepared
    unit = _prepare(data, settings, aligned, pressure=np.where(p == 0, 1.0, p))
    d_pressure, d_force = reading_sensitivities(data, paper_fields(data.mesh).load_end, unit)
    dp = EPS * np.maximum(np.abs(p), 100.0)
    df = EPS * np.maximum(np.abs(data.axial_force), 0.1)
    fd_p = (_prepare(data, settings, aligned, pressure=p + dp).evw - data.evw) / dp
    fd_f = (_prepare(data, settings, aligned, force=data.axial_force + df).evw - data.evw) / df
    np.testing.assert_allclose(d_pressure[:, 1:], fd_p[:, 1:], rtol=1e-6, atol=1e-9 * np.abs(fd_p).max())
    np.testing.assert_allclose(d_force[:, 1:], fd_f[:, 1:], rtol=1e-6, atol=1e-9 * np.abs(fd_f).max())


def test_reading_sensitivities_ask_for_the_unit_pressure_set_at_a_zero_reading(free):
    data, _, _ = free
    with pytest.raises(ValueError, match="zero pressure"):
        reading_sensitivities(data, paper_fields(data.mesh).load_end)


def test_rigid_modes_leave_the_gaps_unchanged(free):
    data, aligned, settings = free
    B, ok = smoothing_basis(data.mesh, SMOOTHING[2])
    assert rigid_columns(B, ok).tolist() == [True] + [False] * (B.shape[1] - 1)

    def gaps(moved):
        d = _prepare(data, settings, moved)
        return internal_virtual_work(d, "fung", PAPER_PARAMETERS["fung"]) - d.evw

    base = gaps(aligned)
    radial = gaps(_moved(data, aligned, slice(1, None), component=0, column=0)) - base
    axial = gaps(_moved(data, aligned, slice(1, None), component=2, column=0)) - base
    assert np.abs(axial).max() < 1e-6 * np.abs(radial).max()


def test_stacked_loaded_steps_are_each_sets_own_preparation(free):
    data, aligned, settings = free
    again = Reprepare(data, aligned, settings)
    sets = [_moved(data, aligned, slice(1, None), component=c, column=1) for c in (0, 2)]
    stacked = again.stacked(np.stack([s[1:] for s in sets]))
    n = data.n_steps - 1
    assert stacked.n_steps == 1 + 2 * n
    for i, moved in enumerate(sets):
        own = again(moved)
        part = slice(1 + i * n, 1 + (i + 1) * n)
        for name, steps_axis in (("c", 0), ("work_density", 1), ("evw", 1)):
            x, y = getattr(stacked, name), getattr(own, name)
            x, y = np.moveaxis(x, steps_axis, 0)[part], np.moveaxis(y, steps_axis, 0)[1:]
            assert np.max(np.abs(x - y)) <= 1e-10 * np.max(np.abs(y)), name
