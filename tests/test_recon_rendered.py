"""End to end on rendered images: ChArUco calibration estimated from rendered board views, then
detection, correspondence, triangulation and tracking of 300 rendered sphere markers on a deforming
tube through 8 steps, with glare, debris, sensor noise, blur, a missing camera and a marker that
disappears for one step. Half resolution (1224 x 1024) keeps the test inside its time budget."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from rig_sim.rendered_scene import HIDDEN_MARKER, HIDDEN_STEP, MISSING_STEP, N_STEPS, rendered_scene
from reconstruction.pipeline import ReconstructionSettings, reconstruct_series
from reconstruction.surface import fit_cylinder


@pytest.fixture(scope="module")
def rendered():
    cams, calib, frames, images, (R, t) = rendered_scene()
    settings = ReconstructionSettings(marker_diameter=0.4e-3, specimen_radius=0.010)
    res = reconstruct_series(images, calib.cameras, settings)
    centres = res.centres @ R.T + t
    positions = res.positions @ R.T + t
    return cams, calib, frames, res, centres, positions, images, (R, t)


def test_calibration_is_good(rendered):
    cams, calib, *_ = rendered
    assert calib.rms_total < 0.1


def test_identity_completeness_and_accuracy(rendered):
    cams, calib, frames, res, centres, positions, *_ = rendered
    truth = np.array([f.truth.sphere_centres for f in frames])
    surf = np.array([f.truth.surface_points for f in frames])
    gt = cKDTree(truth[0]).query(centres[0])[1]
    assert len(set(gt)) == len(gt)
    errs, serrs = [], []
    for k in range(N_STEPS):
        v = res.visible[k]
        nearest = cKDTree(truth[k][np.isfinite(truth[k]).all(1)]).query(centres[k, v])[1]
        assert np.array_equal(np.flatnonzero(np.isfinite(truth[k]).all(1))[nearest], gt[v]), f"identity swap in step {k}"
        seen2 = frames[k].truth.visible.sum(axis=0) >= 2
        right = np.zeros(truth.shape[1], bool)
        right[gt[v]] = True
        # with a camera missing, many markers are left with a second view beyond the limb (partly
        # occluded, biased by tens of um) or merged with a neighbour: those are refused, so the
        # bar is lower in that step (measured 0.95)
        need = 0.9 if k == MISSING_STEP else 0.99
        assert right[seen2].mean() >= need, f"step {k}: completeness {right[seen2].mean():.3f}"
        errs.append(np.linalg.norm(centres[k, v] - truth[k][gt[v]], axis=1))
        serrs.append(np.linalg.norm(positions[k, v] - surf[k][gt[v]], axis=1))
    assert res.diagnostics["swaps"].sum() == 0
    e = np.concatenate(errs)
    rms = np.sqrt(np.mean(e**2))
    assert rms < 5e-6, f"3-D RMS {rms * 1e6:.2f} um"  # target 10 um, goal 5 um; measured 2.9 um
    assert np.percentile(e, 99) < 15e-6
    assert np.sqrt(np.mean(np.concatenate(serrs) ** 2)) < 5e-6  # wall points under the markers
    # the reported uncertainty is the right order of magnitude
    u = res.uncertainty[res.visible]
    assert 0.2 < np.median(u) / np.median(e) < 5


def test_hidden_marker_and_missing_camera(rendered):
    cams, calib, frames, res, centres, positions, *_ = rendered
    truth0 = frames[0].truth.sphere_centres
    track = int(np.argmin(np.linalg.norm(centres[0] - truth0[HIDDEN_MARKER], axis=1)))
    assert not res.visible[HIDDEN_STEP, track] and np.isnan(positions[HIDDEN_STEP, track]).all()
    assert res.visible[HIDDEN_STEP + 1 :, track].all()
    assert res.diagnostics["detected"][MISSING_STEP, 4] == 0
    # glare and debris were rejected with reasons
    rej = dict(zip(res.diagnostics["reject_reasons"], res.diagnostics["rejects"].sum(axis=(0, 1))))
    assert rej["glare"] > 0


def test_specimen_frame(rendered):
    """frame='specimen' puts z on the fitted axis with the origin at the markers' mid-length."""
    cams, calib, frames, res, centres, positions, *_ = rendered
    cyl = fit_cylinder(centres[0])
    z_axis_in_truth = cyl.axis_direction
    assert abs(z_axis_in_truth[2]) > 0.9999  # sanity: truth axis is z
    from reconstruction.surface import specimen_frame

    R, origin = specimen_frame(res.centres[0], calib.cameras[0].center)
    c0 = (res.centres[0] - origin) @ R.T
    fit = fit_cylinder(c0)
    assert abs(abs(fit.axis_direction[2]) - 1) < 1e-8 and np.linalg.norm(fit.axis_point) < 1e-6
    assert abs(0.5 * (c0[:, 2].min() + c0[:, 2].max())) < 1e-9


def test_cli_import_images_then_reconstruct(rendered, tmp_path, capsys):
    """vfmlab import-images (PNG folders + calibration.toml + loads CSV) then vfmlab reconstruct."""
    import cv2

    from acquisition.session import open_session
    from reconstruction.calibration_io import cameras_to_toml
    from vfmlab.cli import main

    cams, calib, frames, res, centres, positions, images, (R, t) = rendered
    n = 3
    for k in range(n):
        for name, img in images[k].items():
            (tmp_path / "img" / name).mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(tmp_path / "img" / name / f"{k}.png"), img)
    (tmp_path / "calibration.toml").write_text(cameras_to_toml(calib.cameras, units="mm"))
    (tmp_path / "loads.csv").write_text("step,pressure_kPa,axial_force_N,stretch\n0,0,0.1,1.0\n1,5,0.2,1.02\n2,10,0.3,1.04\n")
    out = tmp_path / "s.h5"
    rc = main(["import-images", str(tmp_path / "img"), "--calibration", str(tmp_path / "calibration.toml"),
               "--loads", str(tmp_path / "loads.csv"), "-o", str(out), "--marker-diameter-mm", "0.4",
               "--thickness-mm", "1.0"])
    assert rc == 0, capsys.readouterr().err
    with open_session(out) as s:
        assert s.n_steps == n and sorted(s.camera_names) == sorted(c.name for c in cams)
        assert s.specimen.radius == pytest.approx(0.010, rel=0.03)  # from step-0 markers (3 % bulge)
        np.testing.assert_allclose(s.steps["pressure"], [0, 5e3, 10e3])
    rc = main(["reconstruct", str(out), "--frame", "calibration", "--json"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    assert '"stored_as": "markers_001"' in captured.out
    with open_session(out) as s:
        m = s.latest("markers")
    a = m["arrays"]
    assert a["positions"].shape == (n, a["marker_id"].size, 3) and a["visible"].shape == (n, a["marker_id"].size)
    assert m["units"]["positions"] == "m" and m["parameters"]["marker_diameter_mm"] == 0.4
    # same tracks as the library run on the same images
    np.testing.assert_allclose(a["centres"], res.centres[:n], atol=1e-9, equal_nan=True)


def test_cli_errors(rendered, tmp_path, capsys):
    from vfmlab.cli import main

    rc = main(["reconstruct", str(tmp_path / "missing.h5")])
    assert rc == 2  # bad input (decision 0007)
    rc = main(["import-images", str(tmp_path), "--calibration", str(tmp_path / "c.json"), "--loads",
               str(tmp_path / "l.csv"), "-o", str(tmp_path / "o.h5"), "--marker-diameter-mm", "0.4"])
    assert rc == 2 and "--calibration must be a .toml" in capsys.readouterr().err
