"""Step- and series-level marker reconstruction: detection -> correspondence -> triangulation
-> tracking -> marker-centre offset.

All functions are pure (images and cameras in, arrays out); progress is reported through an
optional callback ``progress(step, n_steps, stage)`` and nothing is printed.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from reconstruction.cameras import Camera
from reconstruction.detection import Detections
from reconstruction.series_tracking import SeriesResult, SeriesTracker, track_series
from reconstruction.settings import Progress, ReconstructionSettings
from reconstruction.step_points import (
    StepPoints,
    convergence_point,
    detect_all,
    expected_diameter_px,
    points_from_detections,
    reconstruct_step,
)

__all__ = [
    "ReconstructionSettings",
    "SeriesTracker",
    "StepPoints",
    "SeriesResult",
    "detect_all",
    "detect_step",
    "convergence_point",
    "expected_diameter_px",
    "points_from_detections",
    "reconstruct_step",
    "reconstruct_series",
    "track_series",
]

log = logging.getLogger(__name__)


def detect_step(
    images: Mapping[str, np.ndarray],
    cameras: list[Camera],
    settings: ReconstructionSettings,
    tracker: SeriesTracker | None = None,
) -> list[Detections | None]:
    """Detections of one step, guided by ``tracker`` when ``settings.guided_detection``.

    From the second loaded step on (the motion of the markers in the image is then known), each
    camera is searched only near the predicted projections of the tracked markers
    (:meth:`SeriesTracker.search_regions`); a camera where that finds fewer than
    ``settings.guided_min_fraction`` of its previous step's detections (a large jump, markers
    out of their regions) is searched again over the whole image.
    """
    regions = None
    if tracker is not None and settings.guided_detection and tracker.n_steps >= 2:
        target = convergence_point(cameras)
        d = np.median([expected_diameter_px(c, settings.marker_diameter, target) for c in cameras])
        regions = tracker.search_regions(settings.guided_radius * d)
    found = detect_all(images, cameras, settings, regions=regions)
    previous = tracker.detected_counts() if tracker is not None else None
    if regions is None or previous is None:
        return found
    redo = [c for c, f in enumerate(found)
            if f is not None and len(f) < settings.guided_min_fraction * previous[c]]
    if redo:
        log.debug("guided detection found too few markers in cameras %s: searching the whole images", redo)
        again = detect_all(images, cameras, settings, only=redo)
        for c in redo:
            found[c] = again[c]
    return found


def reconstruct_series(
    images: Sequence[Mapping[str, np.ndarray]] | Callable[[int], Mapping[str, np.ndarray]],
    cameras: list[Camera],
    settings: ReconstructionSettings | None = None,
    *,
    n_steps: int | None = None,
    axial_ratios: Sequence[float] | None = None,
    progress: Progress | None = None,
    frame: str = "calibration",
    axis_sign: int = 1,
) -> SeriesResult:
    """Full reconstruction of a session's images: detection, correspondence, tracking, offset.

    Steps are processed in order (detection of step k is guided by the markers tracked up to
    step k - 1, see :func:`detect_step`).

    Parameters
    ----------
    images : sequence of mappings camera name -> image (H, W), or a callable ``step -> mapping``
        (with ``n_steps``) so that images are loaded one step at a time.
    cameras : list of Camera
    settings : ReconstructionSettings
    n_steps : int, required when ``images`` is a callable
    axial_ratios, progress, frame, axis_sign : see :func:`track_series`

    Returns
    -------
    SeriesResult
    """
    settings = settings or ReconstructionSettings()
    if frame not in ("calibration", "specimen"):
        raise ValueError(f"frame must be 'calibration' or 'specimen'; got {frame!r}")
    if callable(images):
        if n_steps is None:
            raise ValueError("n_steps is required when images is a callable")
        get = images
    else:
        n_steps = len(images) if n_steps is None else n_steps
        seq = images
        get = lambda k: seq[k]  # noqa: E731
    if n_steps == 0:
        raise ValueError("images must contain at least the reference step; got 0 steps")
    tracker = SeriesTracker(cameras, settings)
    for k in range(n_steps):
        if progress:
            progress(k, n_steps, "detection")
        found = detect_step(get(k), cameras, settings, tracker if k else None)
        if progress:
            progress(k, n_steps, "correspondence")
        ratio = None if axial_ratios is None or k == 0 else float(axial_ratios[k])
        tracker.add([d.centres if d is not None else np.zeros((0, 2)) for d in found],
                    quality=[d.quality if d is not None else None for d in found], axial_ratio=ratio, found=found)
    return tracker.result(frame=frame, axis_sign=axis_sign, progress=progress)
