"""The window refined in the board bundle adjustment (issue 14): exact projections through a flat window, a wrong
start (plane 2 mm off, normal 2 deg off) recovered; planes that the board views cannot fix are flagged ILL-POSED."""

import numpy as np
import pytest

from rig_sim.window_boards import board_views, exact_views, wall_rig, wrong_window
from reconstruction.calibration import CalibrationError, calibrate_cameras, reprojection_errors
from vfmlab.cli import main

OBJ = np.array([[i * 5e-3, j * 5e-3, 0] for j in range(6) for i in range(8)])  # 8 x 6 corners, 5 mm


def window_scene(*, per_camera=False, n_views=9):
    """Three cameras through one wall (or one window each), board at 170/200/230 mm tilted up to 30 deg; exact
    refracted projections (``rig_sim/window_boards.py``)."""
    cams = wall_rig(per_camera=per_camera)
    rv, tv = board_views(n_views, extent=(0.035, 0.025))
    return cams, OBJ, exact_views(cams, OBJ, rv, tv)


_wrong = wrong_window


def _angle_deg(a, b):
    return float(np.rad2deg(np.arccos(np.clip(a @ b, -1, 1))))


def test_shared_wall_recovered_from_a_wrong_start():
    cams, obj, uv = window_scene()
    truth = cams[0].window
    res = calibrate_cameras(uv, obj, [c.image_size for c in cams], [c.name for c in cams], windows=_wrong(truth),
                            refine_window=True)
    fit = res.window_fit
    assert fit.cameras == [["cam0", "cam1", "cam2"]]  # one plane: the cameras were given the same window
    got = fit.refined[0]
    assert abs(got.offset - truth.offset) <= 0.05e-3  # measured 1e-12 m
    assert _angle_deg(got.normal, truth.normal) <= 0.1  # measured 0
    assert res.rms_total < 1e-3  # exact projections: reprojection at noise level (measured 2e-13 px)
    assert fit.well_posed and "ILL-POSED" not in fit.message
    assert fit.offset_std[0] < 0.5e-3 and np.rad2deg(fit.normal_std[0]) < 0.3  # 0.05 px noise floor: measured 0.22 mm, 0.09 deg
    assert all(c.window is not None and c.window.offset == got.offset for c in res.cameras)
    row = fit.summary()[0]
    assert row["plane_distance_mm"] == pytest.approx(90.0, abs=0.05) and row["plane_shift_mm"] == pytest.approx(-2, abs=0.05)
    assert row["normal_change_deg"] == pytest.approx(2.0, abs=0.1)
    for c, t in zip(res.cameras, cams):
        assert np.linalg.norm(c.center - t.center) < 1e-6 and c.K[0, 0] == pytest.approx(t.K[0, 0], rel=1e-6)


def test_one_window_per_camera_is_flagged_ill_posed():
    # refused before anything moves (1-sigma from the Jacobian at the start), even from the true windows
    cams, obj, uv = window_scene(per_camera=True, n_views=6)
    res = calibrate_cameras(uv, obj, [c.image_size for c in cams], [c.name for c in cams],
                            windows=[c.window for c in cams], refine_window=True, world_view=1)
    fit = res.window_fit
    # the cameras and their windows re-expressed in board 1's frame reproject as in the adjustment's frame
    e = reprojection_errors(res.cameras, res.board_rvecs, res.board_tvecs, uv, obj)
    assert np.sqrt(np.nanmean(np.sum(e**2, -1))) == pytest.approx(res.rms_total, rel=1e-6)
    assert len(fit.refined) == 3 and fit.cameras == [["cam0"], ["cam1"], ["cam2"]]
    assert not fit.well_posed and "ILL-POSED" in fit.message
    assert np.max(fit.offset_std) > 2e-3  # measured 3.7-11 mm
    assert not np.any(fit.max_correlation < 0) and np.max(fit.max_correlation) > 0.99  # plane vs camera distance
    for got, start, cam in zip(fit.refined, fit.nominal, res.cameras):  # refused: the planes stay where given
        assert np.allclose(got.normal, start.normal, atol=1e-12) and got.offset == pytest.approx(start.offset, abs=1e-12)
        assert cam.window.offset == pytest.approx(got.offset, abs=1e-12)
    assert "refused" in fit.message and res.cameras[1].window.offset == fit.refined[1].offset


def test_refine_window_needs_a_window():
    cams, obj, uv = window_scene(n_views=4)
    with pytest.raises(CalibrationError, match="refine_window needs"):
        calibrate_cameras(uv, obj, [c.image_size for c in cams], refine_window=True)


def test_cli_refine_window_needs_the_rig_window(tmp_path, capsys):
    from acquisition.session import CameraSpec, SessionWriter, SpecimenInfo

    path = tmp_path / "s.h5"
    with SessionWriter.create(path, SpecimenInfo("t", 0.01, 0.035, 0.001), cameras=[CameraSpec("cam0", "sim", 64, 48)]):
        pass
    assert main(["calibrate", str(path), "--refine-window"]) == 2
    assert "--refine-window: no window to refine" in capsys.readouterr().err
    (tmp_path / "imgs" / "cam0").mkdir(parents=True)
    assert main(["calibrate", "--images", str(tmp_path / "imgs"), "--refine-window"]) == 2
    assert "give the SESSION whose rig file states it" in capsys.readouterr().err
