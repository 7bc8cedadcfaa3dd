"""Achieved against reachable (issue 24): the bound of a session's own test (vfmlab.stages.reachable) is design's
for its steps, markers, marker noise and specimen; the report, `vfmlab results` and the live panel show it beside
the achieved half-widths, and say "n/a" (never fail) when it cannot be computed."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
from rich.console import Console

from acquisition.session import CameraSpec, SessionWriter, SpecimenInfo, StepRecord, open_session, write_result
from identification import DesignSpecimen, MeasurementNoise, TubeSteps, design
from rig_sim.mechanics import PAPER_PARAMETERS, simulate_test
from vfmlab.cli import main
from vfmlab.display import num
from vfmlab.stages.reachable import protocol_reachable, session_reachable

R, H, L, SIGMA, N_MARKERS = 10e-3, 1.3e-3, 35e-3, 0.1e-3, 200
STRETCHES, PRESSURES = (1.1, 1.2), tuple(np.array([0, 40, 80, 120, 150]) * 133.322387415)
FUNG = PAPER_PARAMETERS["fung"]


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A free membrane tube at two stretches, markers with 0.1 mm noise, and a stored Fung result that used every
    step but the first loaded one."""
    sim = simulate_test("fung", FUNG, radius=R, length=L, thickness=H, stretches=STRETCHES, pressures=PRESSURES,
                        n_markers=N_MARKERS, clamped=False, wall="membrane", marker_margin=0.0)
    x = sim.exact_positions + SIGMA * np.random.default_rng(3).standard_normal(sim.exact_positions.shape)
    path = tmp_path_factory.mktemp("reach") / "s.h5"
    cams = [CameraSpec("cam0", "simulated", 8, 6)]
    blocks = np.concatenate([[0], np.repeat(np.arange(1, len(STRETCHES) + 1), len(PRESSURES))])
    with SessionWriter.create(path, SpecimenInfo("tube", R, L, H, ""), cameras=cams, protocol_text="", rig={},
                              instruments={"pressure": {"identity": "sim", "settings": {}},
                                           "load_cell": {"identity": "sim", "settings": {}}}) as w:
        for k in range(x.shape[0]):
            w.add_step(StepRecord(block=int(blocks[k]), stretch=float(sim.stretch[k]),
                                  target_pressure=float(sim.pressure[k]), pressure=float(sim.pressure[k]),
                                  force=float(sim.axial_force[k]), t_monotonic=float(k), t_wall=1.7e9 + k),
                       images={"cam0": np.zeros((6, 8), np.uint8)})
    rows = np.arange(x.shape[0])
    write_result(path, "markers", {"positions": x, "visible": np.ones(x.shape[:2], bool), "marker_id": np.arange(
        N_MARKERS), "step_index": rows}, {"source": "test"}, units={"positions": "m"})
    used = np.delete(rows, 1)  # the first loaded step left out: the bound must follow the result's steps
    names = list(FUNG)
    values = np.array([FUNG[n] for n in names])
    write_result(path, "identification", {"parameters": values, "stderr": 0.02 * values,
                                          "parameter_names": np.array(names), "step_index": used},
                 {"model": "fung", "wall": "membrane", "markers_result": "markers_001"},
                 attrs={"model": "fung", "wall": "membrane", "cost": 1e-3, "converged": True, "flags": []})
    # a result that is not a law's (its parameters are not the model's): no bound, never a failure
    write_result(path, "identification", {"parameters": np.array([1.0]), "stderr": np.array([0.1]),
                                          "parameter_names": np.array(["q"]), "step_index": used},
                 {"model": "delfino", "wall": "membrane"},
                 attrs={"model": "delfino", "wall": "membrane", "cost": 1e-3, "converged": True, "flags": []})
    return path, sim, used


def test_reachable_is_designs_bound_for_the_sessions_steps_markers_and_noise(session):
    path, sim, used = session
    with open_session(path) as s:
        r = session_reachable(s, s.result("identification_001"))
        bad = session_reachable(s, s.result("identification_002"))
    assert r.available and r.n_markers == N_MARKERS and r.n_steps == len(used) - 1 and r.stretches == STRETCHES
    assert r.wall == "membrane"
    # the marker noise the data show: prepare's neighbour-mismatch estimate, within 15 % of the simulated one
    assert abs(r.marker_noise_m / SIGMA - 1) < 0.15, r.marker_noise_m
    loaded = used[1:]
    steps = TubeSteps(sim.pressure[loaded], sim.stretch[loaded], np.where(sim.stretch[loaded] < 1.15, 0, 1))
    spec = DesignSpecimen(R, H, L, "membrane")
    same = design(steps, spec, "fung", FUNG, r.n_markers, MeasurementNoise(r.marker_noise_m)).half_width
    assert r.half_width == pytest.approx(same, rel=1e-9)
    # and, at the simulated noise, the prediction of the test as designed within 15 %
    planned = design(steps, spec, "fung", FUNG, N_MARKERS, MeasurementNoise(SIGMA)).half_width
    for p in ("beta", "alpha11", "alpha22"):
        assert r.half_width[p] == pytest.approx(planned[p], rel=0.15), p
    assert not bad.available and "not those of model 'delfino'" in bad.reason and "n/a" in bad.describe()


def test_report_and_results_show_achieved_against_reachable(session, capsys):
    from vfmlab.report import summary
    from vfmlab.report.context import Context

    path, _, _ = session
    with open_session(path) as s:
        reach = session_reachable(s, s.result("identification_001"))
        html = summary._side_by_side(Context(s), {})
    beta = f"±{num(1.96 * 2.0, 3)} % achieved / ±{num(reach.half_width['beta'], 3)} % reachable"
    assert beta in html, html
    assert "achieved / n/a reachable" in html and "reachable n/a: the result&#x27;s parameters" in html
    assert main(["results", str(path)]) == 0
    out = capsys.readouterr().out
    assert f"beta ±3.92 % / ±{num(reach.half_width['beta'], 3)} %" in out, out
    assert main(["results", str(path), "--kind", "identification", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert rows[0]["reachable"]["half_width_95_percent"]["alpha22"] == pytest.approx(reach.half_width["alpha22"])
    assert rows[1]["reachable"]["half_width_95_percent"] == {} and "n/a" in rows[1]["reachable"]["note"]


def test_live_panel_shows_the_protocols_reachable_half_widths(tmp_path):
    from acquisition.protocol import load_protocol, load_specimen
    from vfmlab.live import render_live_results
    from vfmlab.live_results import LiveEstimate, LiveStatus
    from vfmlab.stages.design import protocol_blocks
    from test_run_session_sim import ROOT

    protocol = load_protocol(ROOT / "examples" / "paper-protocol.toml")
    specimen = load_specimen(ROOT / "examples" / "specimen.toml")
    reach = protocol_reachable(protocol, specimen, ("fung", "nosuchlaw"), wall="membrane")
    expected = design(protocol_blocks(protocol), DesignSpecimen(specimen.radius, specimen.thickness, specimen.length),
                      "fung").half_width  # vfmlab design's defaults: 300 markers, 0.17 mm, Table 1
    assert reach["fung"].half_width == pytest.approx(expected, rel=1e-12)
    assert not reach["nosuchlaw"].available
    est = LiveEstimate("fung", ("beta", "alpha11"), np.array([5000.0, 14.5]), np.array([60.0, 0.07]), np.arange(4),
                       1e-3, ())
    console = Console(file=io.StringIO(), width=140)
    console.print(render_live_results(LiveStatus(estimates={"fung": est}, reachable=reach)))
    text = console.file.getvalue()
    assert "reachable" in text and f"{num(expected['beta'], 3)} %" in text and f"{num(196 * 60 / 5000, 3)} %" in text
    console = Console(file=io.StringIO(), width=140)
    console.print(render_live_results(LiveStatus(estimates={"fung": est})))  # no prediction: n/a
    assert "n/a" in console.file.getvalue()
