"""Issue 23: trusted by default, or a plain "doubtful" with its reason, on data from outside our simulator.

One test per case of the issue, on small independent closed-form tubes (rig_sim.simulate) with 0.1 % load noise,
imported without saying the ends or the wall. "Honest" means: a parameter marked trusted is within twice its
95 % half-width of the truth, and a doubtful one carries its reason.
"""

import json
from pathlib import Path

import numpy as np
import pytest

import identification
import vfmlab
from acquisition.markers_csv import write_markers_csv
from acquisition.session import open_session
from identification import DEFAULTS, identify
from identification.noise_weights import weights_from_noise
from rig_sim.mechanics import PAPER_PARAMETERS
from rig_sim.simulate import simulate_test
from vfmlab.cli import main
from vfmlab.pipeline import read_identification_inputs
from vfmlab.stages.settings import IdentifySettings, ReprocessSettings

MMHG = 133.322387415


def _loads_noise(sim, seed=5, level=1e-3):
    rng = np.random.default_rng(seed)
    p = sim.pressure * (1 + level * rng.standard_normal(sim.pressure.shape))
    f = sim.axial_force * (1 + level * rng.standard_normal(sim.pressure.shape))
    return p, f


def _honest(parameters, verdicts, reasons, interval, truth):
    """Every trusted parameter within twice its 95 % half-width of the truth; every doubtful one with a reason."""
    for name, value in parameters.items():
        if verdicts[name] == "doubtful":
            assert reasons[name], (name, reasons)
            continue
        lo, hi = interval[name]
        half = max(value - lo, hi - value)
        assert abs(value - truth[name]) <= 2 * half, (name, value, truth[name], (lo, hi))


def _import(tmp_path, sim, p, f, *, name="s"):
    """The CSV round trip a new user makes: markers and loads as CSV, import-markers without --ends."""
    markers, loads, out = tmp_path / f"{name}_m.csv", tmp_path / f"{name}_l.csv", tmp_path / f"{name}.h5"
    n_steps, n_markers = sim.positions.shape[:2]
    write_markers_csv(markers, np.array([f"M{m}" for m in range(n_markers)]), np.arange(n_steps), sim.positions,
                      units="mm")
    stretch = np.asarray(getattr(sim, "stretch", np.ones(n_steps)), float).reshape(-1)
    stretch = stretch if stretch.size == n_steps else np.ones(n_steps)
    loads.write_text("step,pressure_Pa,axial_force_N,stretch\n"
                     + "".join(f"{k},{p[k]:.9g},{f[k]:.9g},{stretch[k]:.6g}\n" for k in range(n_steps)))
    assert main(["import-markers", str(markers), str(loads), "--thickness-mm", f"{sim.thickness * 1e3:g}",
                 "-o", str(out)]) == 0
    return out


def test_the_stage_settings_take_the_library_defaults():
    s = IdentifySettings()
    assert (s.model, s.wall, s.ends, s.optimizer, s.smooth, s.uncertainty, s.weighting) == (
        DEFAULTS.model, DEFAULTS.wall, DEFAULTS.ends, DEFAULTS.optimizer, DEFAULTS.smoothing, DEFAULTS.uncertainty,
        DEFAULTS.weighting)
    assert ReprocessSettings().walls == DEFAULTS.wall and ReprocessSettings().ends == DEFAULTS.ends
    assert identification.defaults.DEFAULTS is DEFAULTS  # one module, however it was first imported


def test_library_defaults_are_the_commands(tmp_path, capsys):
    """The numbers of ``vfmlab identify S.h5`` are those of ``identification.identify`` called as its docstring
    shows, and of ``vfmlab.identify``: bit for bit."""
    sim = simulate_test("fung", PAPER_PARAMETERS["fung"], clamped=False, wall="thick", n_markers=100,
                        noise_std=0.01e-3, seed=2)
    path = _import(tmp_path, sim, *_loads_noise(sim))
    capsys.readouterr()
    assert main(["identify", str(path), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    d = read_identification_inputs(path)
    lib = identify(d["positions"], d["pressure"], d["force"], thickness=d["thickness"], model="fung")
    with open_session(path) as s:
        stored = s.result(doc["result_group"])
    names = [str(n) for n in stored["arrays"]["parameter_names"]]
    assert np.array_equal(stored["arrays"]["parameters"], [lib.parameters[n] for n in names])
    assert np.array_equal(stored["arrays"]["interval_high"], [lib.uncertainty.interval[n][1] for n in names])
    assert doc["verdict"] == lib.verdict and doc["parameter_verdicts"] == lib.parameter_verdicts
    front = vfmlab.identify(path)
    assert front.parameters == lib.parameters
    # the stored verdict (the storage contract of the verdict)
    attrs = stored["attrs"]
    assert attrs["verdict"] == doc["verdict"]
    assert json.loads(attrs["parameter_verdicts"]) == doc["parameter_verdicts"]
    assert isinstance(json.loads(attrs["verdict_reasons"]), list)
    assert set(json.loads(attrs["parameter_reasons"])) == set(names)


def test_csv_round_trip_without_ends_is_right_or_says_why(tmp_path, capsys):
    """The issue's first case: a clamped tube's markers and loads as CSV, imported without --ends."""
    sim = simulate_test("fung", PAPER_PARAMETERS["fung"], clamped=True, wall="membrane", n_markers=200,
                        noise_std=0.01e-3, seed=3)
    path = _import(tmp_path, sim, *_loads_noise(sim))
    capsys.readouterr()
    assert main(["identify", str(path), "--model", "fung", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["verdict"] in ("trusted", "doubtful")
    assert doc["ends_source"] != "assumed" and doc["ends"] == "clamped"  # decided by the data, not assumed
    _honest(doc["parameters"], doc["parameter_verdicts"], doc["parameter_reasons"], doc["interval_95"],
            PAPER_PARAMETERS["fung"])
    assert main(["results", str(path)]) == 0
    assert "verdict: " in capsys.readouterr().out


@pytest.mark.parametrize("seed", [0, 1])
def test_papers_case_is_right_or_doubtful(seed):
    """Table 1 parameters, one stretch 1.1, 8 levels 0-150 mmHg, 300 markers, 0.17 mm, free ends, nothing said."""
    sim = simulate_test("fung", PAPER_PARAMETERS["fung"], clamped=False, wall="membrane", noise_std=0.17e-3,
                        seed=seed)
    r = identify(sim.positions, *_loads_noise(sim, seed), thickness=sim.thickness, model="fung")
    _honest(r.parameters, r.parameter_verdicts, r.parameter_reasons, r.uncertainty.interval, PAPER_PARAMETERS["fung"])
    if r.verdict == "doubtful":
        assert r.verdict_reasons and all(isinstance(x, str) and x for x in r.verdict_reasons)


def test_a_thick_wall_by_default():
    """The issue: at 0.05 mm the wall-form check fired in 0 of 5 fits and the membrane default was 39-45 % off."""
    sim = simulate_test("fung", PAPER_PARAMETERS["fung"], clamped=False, wall="thick", n_markers=200,
                        noise_std=0.05e-3, seed=4)
    r = identify(sim.positions, *_loads_noise(sim), thickness=sim.thickness, model="fung")
    assert r.data.wall == "thick"
    _honest(r.parameters, r.parameter_verdicts, r.parameter_reasons, r.uncertainty.interval, PAPER_PARAMETERS["fung"])
    # on the thick wall the membrane form is off: the data say so at this noise
    membrane = [h for h in r.hypotheses if h["wall"] == "membrane" and h["ends"] == r.data.ends][0]
    assert membrane["gap_noise_units"] > [h for h in r.hypotheses if h["chosen"]][0]["gap_noise_units"]


def test_a_wrong_law_does_not_look_fine():
    """HGO fitted to a Fung specimen at one stretch: never a trusted result."""
    sim = simulate_test("fung", PAPER_PARAMETERS["fung"], clamped=False, wall="thick", n_markers=150,
                        noise_std=0.01e-3, seed=5)
    r = identify(sim.positions, *_loads_noise(sim), thickness=sim.thickness, model="hgo")
    assert r.verdict == "doubtful"
    assert any("poor fit" in x or "contradicted" in x for x in r.verdict_reasons), r.verdict_reasons
    assert all(v == "doubtful" for v in r.parameter_verdicts.values())
    assert all(r.parameter_reasons.values())


def test_noise_weights_survive_a_gap_without_spread():
    """The crash 'weights must be positive and finite, shape (2, 9) ...; got shape (2, 9)': a gap whose spread
    was not finite (a replicate that overflowed) or zero."""
    sd = np.abs(np.random.default_rng(0).normal(1e-3, 2e-4, (2, 9)))
    sd[0, 3], sd[1, 0] = np.nan, 0.0
    w = weights_from_noise(sd)
    assert w.shape == (2, 9) and np.all(np.isfinite(w) & (w > 0))
    with pytest.raises(identification.IdentificationError, match="gap noise could not be measured"):
        weights_from_noise(np.full((2, 9), np.nan))


def test_noise_weighting_is_judged_too():
    sim = simulate_test("fung", PAPER_PARAMETERS["fung"], clamped=False, wall="membrane", n_markers=200,
                        noise_std=0.05e-3, seed=6)
    r = identify(sim.positions, *_loads_noise(sim), thickness=sim.thickness, model="fung", weighting="noise",
                 wall="membrane", ends="free")
    assert r.verdict in ("trusted", "doubtful") and set(r.parameter_verdicts) == set(r.parameters)
    _honest(r.parameters, r.parameter_verdicts, r.parameter_reasons, r.uncertainty.interval, PAPER_PARAMETERS["fung"])


def test_no_alpha12_advice_when_the_data_have_two_stretches():
    sim = simulate_test("fung", PAPER_PARAMETERS["fung"], clamped=False, wall="membrane", n_markers=200,
                        stretches=(1.05, 1.1), noise_std=0.01e-3, seed=7)
    r = identify(sim.positions, *_loads_noise(sim), thickness=sim.thickness, model="fung", wall="membrane",
                 ends="free")
    assert not any("two or more axial stretches" in f for f in r.flags), r.flags
    one = simulate_test("fung", PAPER_PARAMETERS["fung"], clamped=False, wall="membrane", n_markers=200,
                        noise_std=0.01e-3, seed=7)
    r1 = identify(one.positions, one.pressure, one.axial_force, thickness=one.thickness, model="fung",
                  wall="membrane", ends="free", uncertainty="gauss-newton")
    assert any("two or more axial stretches" in f for f in r1.flags), r1.flags


def test_a_total_force_reading_given_as_the_wall_force_is_contradicted():
    """What the load cell measures is an assumption too: a total reading (behind a closed cannula) given as the
    wall force is caught by the gaps in noise units, with the option to pass."""
    sim = simulate_test("fung", PAPER_PARAMETERS["fung"], clamped=False, wall="thick", n_markers=150,
                        noise_std=0.05e-3, seed=8)
    total = sim.axial_force - sim.pressure * np.pi * (sim.reference_radius - sim.thickness) ** 2
    r = identify(sim.positions, sim.pressure, total, thickness=sim.thickness, model="fung", uncertainty="gauss-newton")
    assert r.verdict == "doubtful"
    assert any("total reading" in x and "--force-is" in x for x in r.verdict_reasons), r.verdict_reasons


def _paper_protocol_tube(wall):
    """The shipped paper protocol's tube (one stretch 1.1, 8 levels, reference captured 4 times, 300 markers)."""
    from benchmarks.bench_protocols import protocol_case

    examples = Path(__file__).resolve().parents[1] / "examples"
    case = protocol_case(examples / "paper-protocol.toml", examples / "specimen.toml")
    sim = simulate_test("fung", PAPER_PARAMETERS["fung"], radius=case["radius"], length=case["length"],
                        thickness=case["thickness"], stretches=case["stretches"], pressures=case["pressures"],
                        n_markers=300, clamped=False, wall=wall, marker_margin=0.0)
    return case, sim


@pytest.mark.parametrize("seed", [14, 23])
def test_the_wall_form_is_judged_over_the_full_covariance(seed):
    """A membrane-law tube at 0.17 mm, one stretch: with per-gap spreads (which ignore the reference's error shared
    by every step) these seeds were judged "thick wall" and had a trusted alpha11 ~27 % off
    (benchmarks/bench_wall_decision.py); over the full covariance the data say membrane, and the result is honest."""
    from benchmarks.bench_protocols import noisy_data

    case, sim = _paper_protocol_tube("membrane")
    x, p, f = noisy_data(sim, 0.17e-3, np.random.default_rng([20261127, seed]), case["repeats"])
    r = identify(x, p, f, thickness=case["thickness"], model="fung", reference_repeats=case["repeats"])
    assert (r.data.wall, r.data.ends) == ("membrane", "free")
    _honest(r.parameters, r.parameter_verdicts, r.parameter_reasons, r.uncertainty.interval, PAPER_PARAMETERS["fung"])
    assert r.parameter_verdicts["alpha11"] == "trusted"


def test_the_other_ends_covariance_comes_from_the_same_moved_sets():
    """``GapCovariance.for_ends`` equals a covariance built afresh on the other end condition's data (the clamped
    ends' strip force changes it by ~90 % here), without re-preparing the moved sets."""
    from benchmarks.bench_protocols import noisy_data
    from identification.efficient import EfficientSettings, GapCovariance
    from identification.optimize import identify as fit_stated

    case, sim = _paper_protocol_tube("thick")
    x, p, f = noisy_data(sim, 0.17e-3, np.random.default_rng(3))
    fits = {e: fit_stated(x, p, f, thickness=case["thickness"], wall="thick", ends=e, smoothing="auto")
            for e in ("clamped", "free")}
    params = fits["free"].parameters
    fresh = GapCovariance(fits["free"].data, x, EfficientSettings())
    derived = GapCovariance(fits["clamped"].data, x, EfficientSettings()).for_ends(fits["free"].data)
    c_fresh, c_derived = fresh.at("fung", params), derived.at("fung", params)
    clamped = GapCovariance(fits["clamped"].data, x, EfficientSettings()).at("fung", params)
    assert np.abs(clamped - c_fresh).max() > 0.1 * np.abs(c_fresh).max()  # the ends do matter
    assert np.abs(c_derived - c_fresh).max() <= 1e-9 * np.abs(c_fresh).max()


@pytest.mark.parametrize("law, ends, stretches, noise", [
    ("delfino", "clamped", (1.1,), 0.01e-3),  # alpha +0.44 %, the markers alone claimed +-0.22 %
    ("hgo", "free", (1.05, 1.1, 1.15), 0.17e-3),  # phi -1.9 %, the first order claimed +-0.88 %
])
def test_the_intervals_hold_where_the_first_order_claimed_too_much(law, ends, stretches, noise):
    """Seed 1 of the must-hold table (benchmarks/bench_trust.py): a trusted parameter just beyond twice its
    half-width with the efficient default's first-order intervals. The intervals are now read over the covariance
    floored for the balance's discretisation (low noise) and HGO phi is widened as measured on these tubes."""
    sim = simulate_test(law, PAPER_PARAMETERS[law], clamped=ends == "clamped", wall="membrane", stretches=stretches,
                        noise_std=noise, seed=1)
    rng = np.random.default_rng([1, 23])
    p = np.asarray(sim.pressure) * (1 + 1e-3 * rng.standard_normal(np.shape(sim.pressure)))
    f = np.asarray(sim.axial_force) * (1 + 1e-3 * rng.standard_normal(np.shape(sim.pressure)))
    r = identify(sim.positions, p, f, thickness=sim.thickness, model=law)
    assert (r.data.ends, r.data.wall) == (ends, "membrane")
    _honest(r.parameters, r.parameter_verdicts, r.parameter_reasons, r.uncertainty.interval, PAPER_PARAMETERS[law])
    assert sum(v == "trusted" for v in r.parameter_verdicts.values()) >= 2


def test_without_a_covariance_the_floor_alone_judges_the_gaps():
    """Where the gaps' covariance cannot be built, the settings are judged on the discretisation floor alone (0.1 %
    of the external work per loaded gap, gaps rescaled to the data's own scale); the reference step carries none."""
    from identification.efficient import NOISE_FLOOR
    from identification.setting_noise import SettingNoise

    W = SettingNoise(None, np.array([2.0, 4.0]), 3).whitening("fung", {}, np.array([2.0, 4.0]))
    loaded = np.array([False, True, True, False, True, True])
    assert np.allclose(np.diag(W)[loaded], 1.0 / NOISE_FLOOR) and not np.diag(W)[~loaded].any()
    assert np.count_nonzero(W - np.diag(np.diag(W))) == 0
