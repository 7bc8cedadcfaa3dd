"""match_step on a step whose points cover only part of the tube (markers out of view on one side):
the initial map from the points' axial percentiles is then far off, and the markers must still be
matched (the previous positions are the second start)."""

import numpy as np
import pytest

from _recon_synth import tube_layout, tube_surface
from reconstruction.tracking import match_step


@pytest.mark.parametrize("covered", [0.5, 0.7])
def test_a_step_seen_on_one_side_is_matched(covered):
    theta, Z = tube_layout(250, seed=1)
    before, _ = tube_surface(theta, Z, radial=1.10, axial=1.10)
    after, _ = tube_surface(theta, Z, radial=1.11, axial=1.10)  # one pressure increment
    seen = np.flatnonzero(after[:, 2] < np.quantile(after[:, 2], covered))
    m = match_step(before, after[seen])
    # every seen marker gets its own point, nothing else is assigned (main's code: 19 and 29 right)
    np.testing.assert_array_equal(m.assignment[seen], np.arange(seen.size))
    assert np.all(m.assignment[np.setdiff1d(np.arange(250), seen)] == -1)
