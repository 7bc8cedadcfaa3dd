"""What the live identification during `vfmlab run` stores is reproducible from the session: its calibration and
its marker tracks are stored with it and named in its settings."""

from __future__ import annotations

import numpy as np

from acquisition.session import open_session
from identification import identify
from reconstruction import cameras_from_arrays
from rig_sim.cameras import camera_ring
from rig_sim.synthetic_session import THICKNESS, make_session, synthetic_tube
from vfmlab.live_results import LiveEstimate, LiveResults


def test_live_store_keeps_markers_and_calibration(tmp_path):
    session = make_session(tmp_path / "s.h5", with_results=False)
    positions, _, _, _ = synthetic_tube(seed=0)
    positions = positions.copy()
    positions[3, :5] = np.nan  # markers the live tracker lost
    with open_session(session) as s:
        pressure, force = np.asarray(s.steps["pressure"]), np.asarray(s.steps["force"])
    rows = np.arange(len(pressure))
    res = identify(positions, pressure, force, thickness=THICKNESS, model="delfino", ends="free", smoothing="auto")
    names = tuple(res.parameters)
    est = LiveEstimate("delfino", names, np.array([res.parameters[k] for k in names]),
                       np.array([res.stderr[k] for k in names]), rows, float(res.cost), tuple(res.flags), res,
                       positions, np.arange(positions.shape[1]))
    cams = camera_ring(2, image_size=(640, 480), seed=0)
    live = LiveResults(session, thickness=THICKNESS, models=("delfino",), cameras=cams, ends="free")
    try:
        live._set(estimates={"delfino": est})
        stored = live.store()
    finally:
        live.close()
    assert stored == ["identification_001"] and live.stored_inputs == ["calibration_001", "markers_001"]
    with open_session(session) as s:
        ident = s.result("identification_001")
        markers = s.result(ident["parameters"]["markers_result"])
        calibration = s.result(ident["parameters"]["calibration_result"])
        assert ident["parameters"]["thickness_m"] == THICKNESS
        again_rows = np.asarray(markers["arrays"]["step_index"])
        again = np.where(np.asarray(markers["arrays"]["visible"], bool)[..., None], markers["arrays"]["positions"],
                         np.nan)
        p, f = np.asarray(s.steps["pressure"])[again_rows], np.asarray(s.steps["force"])[again_rows]
    back = cameras_from_arrays(calibration["arrays"])
    assert [c.name for c in back] == [c.name for c in cams]
    np.testing.assert_array_equal(back[1].K, cams[1].K)
    np.testing.assert_array_equal(again, positions)
    # the identification again, from the session alone: the very same parameters
    res2 = identify(again, p, f, thickness=ident["parameters"]["thickness_m"], model="delfino",
                    ends=ident["parameters"]["ends"], smoothing=ident["parameters"]["smoothing"])
    np.testing.assert_array_equal([res2.parameters[k] for k in names], ident["arrays"]["parameters"])
