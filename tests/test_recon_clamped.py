"""Rendered clamped tube (both ends on cannulae): next to the cannulae the wall bulges and slopes
steeply, the neighbours predict a marker's motion poorly, and the views left for a lost marker are
the grazing ones (near the silhouette, partly hidden by the wall) whose blob centres are biased.

Before the fix, a good 2-view point near an end was rejected as a tracking outlier and replaced by a
guided point built from two grazing views: 140-270 um off with a reported uncertainty of 4-6 um, and
the error carried on through the later steps. Every reconstructed marker must now be either accurate
or report an uncertainty of the order of its error, and almost all markers must stay tracked.
"""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from reconstruction.pipeline import ReconstructionSettings, reconstruct_series
from rig_sim import SurfaceOfRevolution, camera_ring, render_markers
from rig_sim.mechanics import PAPER_PARAMETERS, simulate_test

MMHG = 133.322
RHO = 0.2e-3  # marker radius, m


@pytest.fixture(scope="module")
def clamped_series():
    sim = simulate_test("fung", PAPER_PARAMETERS["fung"], stretches=(1.1, 1.2), pressures=(0.0, 20 * MMHG, 150 * MMHG),
                        n_markers=300, clamped=True, seed=0)
    cams = camera_ring(6, image_size=(1224, 1024), seed=0, name_format="{}")
    th, Z = sim.marker_theta, sim.marker_Z
    images, centres = [], []
    for k in range(sim.exact_positions.shape[0]):
        dr = np.interp(Z, sim.profile_Z, sim.profile_drdZ[k])
        dz = np.interp(Z, sim.profile_Z, sim.profile_dzdZ[k])
        nrm = np.stack([dz * np.cos(th), dz * np.sin(th), -dr], -1)
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        pts = sim.exact_positions[k]
        frame = render_markers(cams, pts, nrm, SurfaceOfRevolution(sim.profile_z[k], sim.profile_r[k]),
                               marker_radius=RHO, seed=k)
        images.append({c.name: im for c, im in zip(cams, frame.images)})
        centres.append(pts + RHO * nrm)
    settings = ReconstructionSettings(marker_diameter=2 * RHO, specimen_radius=sim.reference_radius)
    res = reconstruct_series(images, cams, settings)  # true cameras: the world frame is the truth's
    return res, np.array(centres)


def test_clamped_markers_accurate_or_honestly_uncertain(clamped_series):
    res, truth = clamped_series
    ok0 = res.visible[0]
    _, j = cKDTree(truth[0]).query(res.centres[0, ok0])
    assert np.unique(j).size == j.size  # identities are one-to-one in the reference
    for k in range(truth.shape[0]):
        v = res.visible[k, ok0]
        err = np.linalg.norm(res.centres[k, ok0] - truth[k, j], axis=1)[v]
        unc = res.uncertainty[k, ok0][v]
        # measured: rms 1.2-2.4 um; one reference point 28 um off reports 250 um
        assert np.sqrt(np.mean(err**2)) < 4e-6, f"step {k}"
        wrong = (err > 20e-6) & (err > 3 * unc)
        assert not np.any(wrong), f"step {k}: errors {err[wrong] * 1e6} um with uncertainties {unc[wrong] * 1e6} um"
        # measured: 296-297 of 300 tracked (before the fix 278-283)
        assert v.sum() >= 290, f"step {k}: only {v.sum()} markers tracked"
