"""Volume self-calibration on particles (reconstruction/volume_selfcal.py): synthetic known answer."""


import numpy as np
import pytest

from _data import data_path
from _window_rig import window_rig
from reconstruction.volume_selfcal import bundle_adjust, disparity_map, loose_candidates, self_calibrate

BOUNDS = (np.array([-0.03, -0.03, -0.02]), np.array([0.03, 0.03, 0.02]))


def _perturbed(cams, rng, rot=3e-4, shift=100e-6):
    from dataclasses import replace

    return [replace(c, rvec=c.rvec + rng.normal(0, rot, 3), tvec=c.tvec + rng.normal(0, shift, 3)) for c in cams]


def _scene(cams, rng, n=700, noise=0.05):
    """Particles in BOUNDS seen by every camera (shuffled detections, 0.05 px noise, 10 % missing per camera)
    and a two-plane calibration body seen by every camera."""
    X = rng.uniform(*BOUNDS, (n, 3))
    dets = []
    for c in cams:
        px = c.project(X) + rng.normal(0, noise, (n, 2))
        px = px[rng.random(n) > 0.1]
        dets.append(px[rng.permutation(len(px))])
    g = np.linspace(-0.025, 0.025, 8)
    body = np.array([[x, y, z] for x in g for y in g for z in (-0.004, 0.004)])
    body_px = np.stack([c.project(body) + rng.normal(0, noise, (len(body), 2)) for c in cams])
    return X, dets, body, body_px


def _volume_error(cams, truth, rng):
    Y = rng.uniform(*BOUNDS, (500, 3))
    return max(float(np.sqrt(np.mean(np.sum((a.project(Y) - b.project(Y)) ** 2, axis=1)))) for a, b in zip(cams, truth))


def test_self_calibration_recovers_perturbed_cameras():
    rng = np.random.default_rng(7)
    truth = window_rig()
    cams = _perturbed(truth, rng)
    _, dets, body, body_px = _scene(truth, rng)
    before = _volume_error(cams, truth, rng)
    sc = self_calibrate([dets], cams, BOUNDS, body, body_px, schedule=((4.0, 3.0, 1.0), (1.5, 1.0, 0.4)),
                        grid=(1, 1, 1))
    after = _volume_error(sc.cameras, truth, rng)
    assert before > 1.0  # px: the perturbation matters (measured 1.6 px)
    assert after < 0.05, f"{before:.2f} px -> {after:.3f} px"  # measured 0.016 px
    assert sc.maps[0].max_peak_offset_px > 0.3 and sc.check_map.max_peak_offset_px < 0.1  # measured 1.2 -> 0.002 px
    assert np.all(sc.body_rms_px < 0.1)  # 0.05 px noise per coordinate: 0.07 px


def test_body_seen_from_its_other_side_offset_recovered():
    # cameras 3-4 see the body's dots 2 mm further along its normal (a body seen from both faces, the file giving
    # one): body_sides refines that offset with the cameras; one body for all leaves the cameras pulled apart
    from reconstruction.volume_selfcal import body_normal, far_side

    rng = np.random.default_rng(11)
    truth = window_rig()
    cams = _perturbed(truth, rng)
    _, dets, body, _ = _scene(truth, rng)
    far = far_side(truth, body)
    assert far.tolist() == [False, False, True, True]  # a tie: the first camera's side is the near one
    dots = np.full((4, len(body), 2), 100.0)
    dots[:2, :10] = np.nan  # cameras 1-2 miss 10 dots: cameras 3-4 see the face the coordinates describe
    assert far_side(truth, body, dots).tolist() == [True, True, False, False]
    np.testing.assert_allclose(body_normal(body), [0, 0, 1], atol=1e-9)
    body_px = np.stack([c.project(body + (0.002 * body_normal(body) if f else 0.0)) + rng.normal(0, 0.05, (len(body), 2))
                        for c, f in zip(truth, far)])
    kw = dict(schedule=((4.0, 3.0, 1.0), (1.5, 1.0, 0.4)), grid=(1, 1, 1))
    sides = self_calibrate([dets], cams, BOUNDS, body, body_px, body_sides=True, **kw)
    one = self_calibrate([dets], cams, BOUNDS, body, body_px, **kw)
    assert sides.far_side.tolist() == [False, False, True, True] and one.far_side is None and one.body_offset_m == 0
    assert abs(sides.body_offset_m - 0.002) < 0.1e-3, sides.body_offset_m  # measured 2.000 mm
    assert np.all(sides.body_rms_px < 0.1), sides.body_rms_px  # 0.05 px noise per coordinate
    assert np.max(one.body_rms_px) > 3 * np.max(sides.body_rms_px), one.body_rms_px  # measured 2.27 vs 0.07 px
    assert _volume_error(sides.cameras, truth, rng) < 0.05 < _volume_error(one.cameras, truth, rng)  # 0.009, 3.8 px


def test_disparity_map_finds_the_peak_among_ghosts():
    rng = np.random.default_rng(1)
    true = rng.normal([0.6, -0.3], 0.08, (300, 2))
    ghosts = rng.uniform(-3, 3, (900, 2))
    res = np.concatenate([true, ghosts])[None]
    pts = np.zeros((1200, 3))
    m = disparity_map(res, pts, BOUNDS, grid=(1, 1, 1), half_width_px=4.0)
    np.testing.assert_allclose(m.peak_px[0, 0], [0.6, -0.3], atol=0.05)
    assert m.peak_height[0, 0] > 20


def test_bad_arguments_are_named():
    cams = window_rig()
    with pytest.raises(ValueError, match="min_views"):
        loose_candidates([np.zeros((0, 2))] * 4, cams, BOUNDS, min_views=5)
    with pytest.raises(ValueError, match="free"):
        bundle_adjust(cams, np.zeros((4, 0, 2)), np.zeros((0, 3)), np.zeros((4, 3)), np.zeros((4, 4, 2)),
                      free=("focal",))
    with pytest.raises(ValueError, match="body_pixels"):
        bundle_adjust(cams, np.zeros((4, 0, 2)), np.zeros((0, 3)), np.zeros((4, 3)), np.zeros((3, 4, 2)))


DATA = data_path("openptv-test-cavity")


def test_volume_self_calibration_on_real_particles(monkeypatch):
    """OpenPTV test_cavity, frame 1, imported calibration, one pass: the disparity peaks of the same loose
    candidates move towards zero and the calibration body does not get worse. (What it does NOT do on this
    data: make the >= 3-view matches real; bench_real_data.py's decoy figures, docs/validation/reconstruction.md.)"""
    from reconstruction.calibration_body import match_body_points
    from reconstruction.particles import detect_particles
    from reconstruction.volume_selfcal import body_rms
    from vfmlab import openptv

    from benchmarks import _common
    from benchmarks._common import selfcal_bounds

    monkeypatch.setattr(_common, "DATA", DATA)  # the benchmark's own copy is outside the repository

    cams = openptv.load_cameras(DATA)
    _, pts = openptv.read_target_file(DATA / "cal" / "target_on_a_side.txt")
    body_px = np.stack([match_body_points(detect_particles(openptv.read_image(DATA / "cal" / f"cam{i + 1}.tif"),
                                                           **openptv.BODY_DOT_SETTINGS).centres, c, pts)
                        for i, c in enumerate(cams)])
    sc = self_calibrate([openptv.detect_frame(DATA, 1)], cams, selfcal_bounds(), pts, body_px,
                        schedule=((4.0, 3.0, 1.5),), grid=(1, 1, 1))
    before, after = sc.maps[0], sc.check_map
    assert before.counts.min() > 150  # measured 202-263 loose 3-view candidates per camera
    assert np.all(before.peak_height > 10)  # a peak stands out of the chance candidates: measured 19-25x the mean
    assert after.rms_peak_offset_px < 0.85 * before.rms_peak_offset_px  # measured 0.50 -> 0.36 px
    assert np.all(sc.body_rms_px < body_rms(cams, pts, body_px) + 0.1)  # measured 0.66-1.09 -> 0.71-1.09 px
