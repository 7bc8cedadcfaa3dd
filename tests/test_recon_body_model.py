"""Calibration-body model selection: a body confined to a band of the image must not free terms it cannot determine."""

import numpy as np

from reconstruction.calibration_body import body_models, calibrate_from_body, coverage_points, select_body_model
from reconstruction.cameras import Camera


def _band_body():
    """Two planes 20 mm apart, 200 x 80 mm (the band x ~ 290-990, y ~ 370-650 px of a 1280 x 1024 image at 0.4 m), m."""
    x, y = np.meshgrid(np.linspace(-100e-3, 100e-3, 9), np.linspace(-40e-3, 40e-3, 3))
    plane = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    return np.concatenate([plane, plane + [10e-3, 10e-3, 20e-3]])


def test_band_body_keeps_undetermined_distortion_at_the_seed():
    K = np.array([[1400.0, 0, 640], [0, 1400, 512], [0, 0, 1]])
    truth = Camera("cam", K, np.zeros(5), np.array([0.02, -0.03, 0.01]), np.array([0.002, 0.001, 0.4]), (1280, 1024))
    seed = Camera("cam", K, np.zeros(5), np.array([0.025, -0.02, 0.012]), np.array([0.004, -0.001, 0.41]), (1280, 1024))
    body = _band_body()
    rng = np.random.default_rng(1)
    px = truth.project(body) + rng.normal(0, 0.3, (len(body), 2))
    models = body_models(max_groups=3)
    sel = select_body_model(px, body, seed, models=models)
    cover = coverage_points(truth, body)
    err = np.linalg.norm(sel.calibration.camera.project(cover) - truth.project(cover), axis=1).max()
    rich = calibrate_from_body(px, body, seed, terms=models["pose+k1+k2,p1,p2+k3,aspect"])
    err_rich = np.linalg.norm(rich.camera.project(cover) - truth.project(cover), axis=1).max()
    assert sel.calibration.rms < 0.5
    assert not any(t in sel.chosen for t in ("k2", "k3")), sel.table
    assert sel.table["pose"]["admissible"] and not sel.table["pose+k1+k2,p1,p2+k3,aspect"]["admissible"]
    assert err < 1.0, (sel.chosen, err)  # the whole image, not only the band (measured 0.28 px)
    assert err_rich > 5 * err, (err_rich, err)  # freeing everything: 843 px (the overfit this guards against)
