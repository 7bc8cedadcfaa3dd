"""Results while the test runs never leave a step half-seen silently: a step that fails in the
tracker leaves it as it was (all or nothing), a step the worker could not reconstruct is named in
the estimates' flags, and a step seen only in part is said in the live view and the log."""

import logging
from types import SimpleNamespace

import numpy as np
import pytest

from _recon_synth import camera_ring, projected_series
from reconstruction.pipeline import ReconstructionSettings, SeriesTracker
from vfmlab.live_results import LiveResults


def test_a_step_that_fails_leaves_the_tracker_unchanged():
    cams = camera_ring(6)
    dets, *_ = projected_series(cams, n_steps=3, n=120, seed=3)
    settings = ReconstructionSettings(marker_diameter=0.4e-3, specimen_radius=4e-3)
    clean = SeriesTracker(cams, settings)
    for d in dets:
        clean.add(d)
    tracker = SeriesTracker(cams, settings)
    tracker.add(dets[0])
    tracker.add(dets[1])
    before = (tracker.n_steps, len(tracker._carried), tracker._prior, list(tracker._levels))
    broken = [SimpleNamespace(rejects=None, threshold=np.nan)] * len(cams)  # the reject counts raise, after tracking
    with pytest.raises(Exception):
        tracker.add(dets[2], found=broken)
    assert (tracker.n_steps, len(tracker._carried), tracker._prior, list(tracker._levels)) == before
    tracker.add(dets[2])  # the same step again: as if the failure had never happened
    assert tracker.n_steps == 3 and len(tracker._carried) == 3
    np.testing.assert_array_equal(tracker.result().centres, clean.result().centres)
    assert np.isfinite(clean.result().centres[2]).all(axis=1).sum() >= 0.9 * 120


def test_failed_and_partial_steps_are_said(caplog):
    live = LiveResults("unused.h5", thickness=1e-3, radius=5e-3, cameras=[object()])
    try:
        rows = iter(range(100))

        def step(row, images, pressure, force):
            if row == 2:
                raise RuntimeError("detection exploded")
            live._check_partial(row, tracked=50 if row == 3 else 100, reference=100)

        live._step = step
        record = SimpleNamespace(block=0, supersedes=-1, pressure=0.0, force=0.0)
        with caplog.at_level(logging.WARNING, logger="vfmlab.live_results"):
            for _ in range(5):
                live.on_step(next(rows), {}, record)
            status = live.close(timeout=30)
    finally:
        live.close(timeout=1, cancel=True)
    assert status.skipped_rows == (2,) and status.partial_rows == (3,)
    flags = live._missing_flags(rows=[0, 1, 3])  # an estimate from rows 0, 1, 3 (row 4 not reached)
    assert len(flags) == 1 and "step rows [2, 4] were left out" in flags[0] and "1 failed" in flags[0], flags
    assert live._missing_flags(rows=[0, 1, 2, 3, 4]) == []
    assert "step row 2 failed" in caplog.text and "only 50 of the reference's 100 markers tracked" in caplog.text


def test_cancel_drops_the_queued_steps():
    live = LiveResults("unused.h5", thickness=1e-3, radius=5e-3, cameras=[object()])
    done = []
    live._step = lambda row, *a: done.append(row) or __import__("time").sleep(0.2)
    record = SimpleNamespace(block=0, supersedes=-1, pressure=0.0, force=0.0)
    for row in range(20):
        live.on_step(row, {}, record)
    live.close(timeout=30, cancel=True)
    assert not live._thread.is_alive() and len(done) < 20
