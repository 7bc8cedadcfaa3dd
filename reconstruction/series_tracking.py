"""Markers tracked over a series of steps: :class:`SeriesTracker` (one step at a time, with guided recovery of
lost markers near their prediction) and :func:`track_series`, giving :class:`SeriesResult`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from reconstruction.cameras import Camera
from reconstruction.correspondence import CylinderPrior, observed_pixels
from reconstruction.detection import REJECT_REASONS, Detections
from reconstruction.settings import Progress, ReconstructionSettings
from reconstruction.step_points import (
    StepPoints,
    _strong_points,
    _view_cosines,
    _weak_view_uncertainty,
    points_from_detections,
)
from reconstruction.surface import marker_surface_points, specimen_frame, surface_normals, surface_residuals
from reconstruction.tracking import marker_spacing, match_step
from reconstruction.triangulation import triangulate

__all__ = ["SeriesResult", "SeriesTracker", "track_series"]


@dataclass(frozen=True)
class SeriesResult:
    """Tracked markers through all steps.

    Attributes
    ----------
    positions : ndarray, shape (n_steps, n_markers, 3)
        Wall (surface) points under the markers, m; NaN where not reconstructed.
    centres : ndarray, shape (n_steps, n_markers, 3)
        Sphere centres, m; NaN where not reconstructed.
    visible : ndarray of bool, shape (n_steps, n_markers)
    uncertainty : ndarray, shape (n_steps, n_markers)
        RMS 3-D uncertainty of the centre, m (NaN where not visible).
    n_views : ndarray of int, shape (n_steps, n_markers)
    reprojection_rms : ndarray, shape (n_steps, n_markers)
        px.
    marker_id : ndarray of int, shape (n_markers,)
    world_to_rig : ndarray, shape (4, 4)
        Homogeneous transform applied to the calibration-world points to give the returned
        positions (identity with ``frame="calibration"``).
    diagnostics : dict of ndarray
        ``detected`` (n_steps, n_cameras), ``rejects`` (n_steps, n_cameras, n_reasons) with
        ``reject_reasons``, ``reconstructed``, ``tracked``, ``lost``, ``recovered``,
        ``unassigned``, ``swaps``, ``ambiguous``, ``outliers`` (n_steps,), ``sigma_px`` (n_steps,),
        ``reprojection_rms_median`` (n_steps,) px.
    """

    positions: np.ndarray
    centres: np.ndarray
    visible: np.ndarray
    uncertainty: np.ndarray
    n_views: np.ndarray
    reprojection_rms: np.ndarray
    marker_id: np.ndarray
    world_to_rig: np.ndarray
    diagnostics: dict


def _guided_recovery(pred, lost, step: StepPoints, cameras, settings, gate3d):
    """Find lost markers in image space near their predicted projections; returns (idx, X, unc, rms, nv, obs)."""
    n_cams = len(cameras)
    li = np.flatnonzero(lost)
    if li.size == 0:
        return None
    used = [np.zeros(len(d), bool) for d in step.detections]
    for c in range(n_cams):
        o = step.observations[:, c]
        used[c][o[o >= 0]] = True
    obs = np.full((li.size, n_cams), -1, dtype=np.int64)
    P = pred[li]
    for c, cam in enumerate(cameras):
        free = np.flatnonzero(~used[c])
        if free.size == 0:
            continue
        px = cam.project(P)
        fin = np.all(np.isfinite(px), axis=1)
        if step.prior is not None:
            fin &= step.prior.facing(P, cam)
        d, j = cKDTree(step.detections[c][free]).query(np.where(fin[:, None], px, -1e9), distance_upper_bound=settings.guided_gate_px)
        hit = np.flatnonzero(fin & np.isfinite(d))
        # two lost markers claiming one detection: the closer keeps it
        hit = hit[np.argsort(d[hit], kind="stable")]
        _, first = np.unique(j[hit], return_index=True)
        hit = hit[first]
        obs[hit, c] = free[j[hit]]
    ok = (obs >= 0).sum(axis=1) >= 2
    if not np.any(ok):
        return None
    li, obs = li[ok], obs[ok]
    weak = np.zeros(obs.shape, bool)
    if step.prior is not None and settings.min_view_cos > -1:
        # grazing views (near the silhouette, often partly hidden by the wall) give biased centres:
        # leave them out when two better views remain, else keep them and say so in the uncertainty
        weak = (obs >= 0) & (_view_cosines(pred[li], step.prior, cameras) < settings.min_view_cos)
        strong = (obs >= 0) & ~weak
        drop = weak & (strong.sum(axis=1) >= 2)[:, None]
        obs = np.where(drop, -1, obs)
        weak &= ~drop
    tri = triangulate(observed_pixels(step.detections, obs), cameras, sigma_px=step.sigma_px)
    good = (tri.reprojection_rms <= settings.max_reprojection_px) & (np.linalg.norm(tri.points - pred[li], axis=1) <= gate3d)
    if not np.any(good):
        return None
    unc = _weak_view_uncertainty(tri.uncertainty, weak.any(axis=1), tri.sigma_px, settings)
    return li[good], tri.points[good], unc[good], tri.reprojection_rms[good], tri.n_views[good], obs[good]


class SeriesTracker:
    """Marker identities built one step at a time: what :func:`track_series` does in one go, for
    callers that get the steps one by one (guided detection, results while a test runs).

    ``add`` the reference step first, then each later step; ``search_regions`` gives where each
    camera should look for the markers of the next step; ``result`` assembles the
    :class:`SeriesResult` of the steps added so far (it can be called at any time).
    """

    def __init__(self, cameras: list[Camera], settings: ReconstructionSettings | None = None) -> None:
        self.cameras = list(cameras)
        self.settings = settings or ReconstructionSettings()
        self._steps: list[dict] = []  # per step: centres, uncertainty, n_views, rms (n,) arrays + diagnostics
        self._carried: list[np.ndarray] = []  # per step: (n, 3) latest positions (measured or predicted), m
        self._prior: CylinderPrior | None = None
        self._levels: list[tuple[float, float] | None] = [None] * len(self.cameras)  # per camera (threshold, noise)

    @property
    def n_steps(self) -> int:
        return len(self._steps)

    def add(self, detections: Sequence[np.ndarray], *, quality: Sequence[np.ndarray | None] | None = None,
            axial_ratio: float | None = None, found: Sequence[Detections | None] | None = None) -> None:
        """Add one step: per camera pixel centres ``(n_i, 2)``; ``quality`` per camera as
        :attr:`Detections.quality`; ``axial_ratio`` = expected axial length ratio to the previous
        step; ``found`` = the per-camera :class:`Detections` (for the reject counts)."""
        if not self._steps:
            step, carried, prior = self._reference(detections, quality)
        else:
            step, carried, prior = self._next(detections, quality, axial_ratio)
        step["detected"] = np.array([len(d) for d in detections], dtype=np.int64)
        step["rejects"] = _reject_counts(found, len(self.cameras))
        levels = list(self._levels)
        for c, d in enumerate(found or []):
            if d is not None and np.isfinite(d.threshold):
                levels[c] = (d.threshold, d.noise)
        # all or nothing: a step that raised above left the tracker as it was (never half-added)
        self._steps.append(step)
        self._carried.append(carried)
        self._prior, self._levels = prior, levels

    def _reference(self, detections, quality) -> tuple[dict, np.ndarray, CylinderPrior | None]:
        """The reference step's arrays, the positions carried to the next step (n, 3) m and the prior."""
        settings = self.settings
        ref = points_from_detections(detections, self.cameras, settings, quality=quality)
        n = ref.centres.shape[0]
        if n == 0:
            raise ValueError("no markers were reconstructed in the reference step (step 0)")
        step = _empty_step(n, ref, tracked=n)
        step["centres"] = ref.centres.copy()
        step["uncertainty"], step["n_views"], step["rms"] = ref.uncertainty.copy(), ref.n_views.copy(), ref.reprojection_rms.copy()
        # the reference has no prediction to check against: a point standing out of the smooth wall
        # of its neighbours (a depth error of a 2-view point) is NaN in step 0; its position projected
        # on the neighbours' surface is carried so that it is still tracked in later steps
        carried = ref.centres.copy()
        r0, n0 = surface_residuals(ref.centres)
        fin = np.isfinite(r0)
        if fin.sum() >= 10:
            scale = 1.4826 * np.median(np.abs(r0[fin] - np.median(r0[fin]))) + np.median(np.abs(r0[fin]))
            bad = fin & (np.abs(r0) > max(settings.reference_outlier_factor * scale, settings.reference_outlier_floor))
            if np.any(bad):
                carried[bad] = ref.centres[bad] - r0[bad, None] * n0[bad]
                step["centres"][bad] = np.nan
                step["uncertainty"][bad] = step["rms"][bad] = np.nan
                step["n_views"][bad] = 0
                step["outliers"], step["tracked"] = int(bad.sum()), n - int(bad.sum())
        return step, carried, ref.prior

    def _next(self, detections, quality, axial_ratio) -> tuple[dict, np.ndarray, CylinderPrior | None]:
        """A later step's arrays, the positions carried to the next step (n, 3) m and the prior."""
        settings, prior = self.settings, self._prior
        carried = self._carried[-1]
        n = carried.shape[0]
        loose = None
        if prior is not None:
            loose = CylinderPrior(radius=prior.radius, tolerance=settings.prior_tolerance * prior.radius,
                                  axis_point=prior.axis_point, axis_direction=prior.axis_direction,
                                  min_facing=settings.min_facing)
        pts = points_from_detections(detections, self.cameras, settings, loose_prior=loose, quality=quality)
        step = _empty_step(n, pts)
        a, pred, gate = self._assign(carried, pts, axial_ratio, step)
        ok = a >= 0
        step["centres"][ok] = pts.centres[a[ok]]
        step["uncertainty"][ok] = pts.uncertainty[a[ok]]
        step["n_views"][ok] = pts.n_views[a[ok]]
        step["rms"][ok] = pts.reprojection_rms[a[ok]]
        step["unassigned"] = pts.centres.shape[0] - int(ok.sum())
        rec = _guided_recovery(pred, ~ok, pts, self.cameras, settings, gate)
        if rec is not None:
            idx, X, u, r, v, _ = rec
            step["centres"][idx], step["uncertainty"][idx], step["rms"][idx], step["n_views"][idx] = X, u, r, v
            step["recovered"] = idx.size
        vis = np.all(np.isfinite(step["centres"]), axis=1)
        step["tracked"], step["lost"] = int(vis.sum()), n - int(vis.sum())
        return step, np.where(vis[:, None], step["centres"], pred), (pts.prior if pts.prior is not None else prior)

    def _assign(self, carried: np.ndarray, pts: StepPoints, axial_ratio, step: dict):
        """Tracked marker -> point index (-1 = none), predicted positions (n, 3) m and the 3-D gate (m).

        A point far from where its neighbours say it should be is a bad measurement (a partly
        occluded or merged view in a 2-view point): left unassigned rather than a wrong position.
        """
        settings = self.settings
        n = carried.shape[0]
        if pts.centres.shape[0] < 6:
            return np.full(n, -1, np.int64), carried.copy(), 0.35 * marker_spacing(carried)
        axis = None if self._prior is None else self._prior.axis_direction
        m = match_step(carried, pts.centres, axial_ratio=axial_ratio, axis_guess=axis)
        a = m.assignment
        step["swaps"], step["ambiguous"] = m.swaps.shape[0], int(m.ambiguous.sum())
        r = m.residual[np.isfinite(m.residual)]
        if r.size >= 10:
            scale = 1.4826 * np.median(np.abs(r - np.median(r))) + np.median(r)
            limit = max(settings.outlier_factor * scale, settings.outlier_floor)
            bad = np.isfinite(m.residual) & (m.residual > limit)
            if settings.readmit_strong and np.any(bad) and pts.prior is not None:
                # near a clamped end the neighbours predict the motion poorly; a point seen in
                # >= 2 views that all face the camera well is a sound measurement: keep it,
                # rather than replace it by a guided point from the grazing views left over
                bad &= ~_strong_points(pts, self.cameras, settings)[np.maximum(a, 0)]
            a = np.where(bad, -1, a)
            step["outliers"] = int(bad.sum())
        return a, m.predicted, m.gate

    def search_regions(self, radius_px: float) -> list[tuple[np.ndarray, float, tuple[float, float] | None]] | None:
        """Where each camera should look for the markers of the next step: per camera the
        projections (m, 2) px of the markers' latest positions that face it, a search radius
        (px): ``radius_px`` plus 1.5x the 95th percentile of the markers' image motion in the last step, and
        the camera's latest (threshold, noise) detection levels (grey levels) or None.
        None before the reference step."""
        if not self._carried:
            return None
        latest = self._carried[-1]
        out = []
        for cam in self.cameras:
            px = cam.project(latest)
            if self._prior is not None:
                px = px[self._prior.facing(latest, cam)]
            motion = 0.0
            if len(self._carried) >= 2:
                moved = np.linalg.norm(cam.project(latest) - cam.project(self._carried[-2]), axis=1)
                moved = moved[np.isfinite(moved)]
                motion = float(np.percentile(moved, 95)) if moved.size else 0.0
            out.append((px[np.all(np.isfinite(px), axis=1)], radius_px + 1.5 * motion, self._levels[len(out)]))
        return out

    def detected_counts(self) -> np.ndarray | None:
        """Detections per camera in the last step added, (n_cameras,), or None."""
        return self._steps[-1]["detected"] if self._steps else None

    def result(self, *, frame: str = "calibration", axis_sign: int = 1, progress: Progress | None = None) -> SeriesResult:
        """The :class:`SeriesResult` of the steps added so far (see :func:`track_series`)."""
        if frame not in ("calibration", "specimen"):
            raise ValueError(f"frame must be 'calibration' or 'specimen'; got {frame!r}")
        if not self._steps:
            raise ValueError("no steps were added: add the reference step first")
        steps = self._steps
        centres = np.stack([s["centres"] for s in steps])
        visible = np.all(np.isfinite(centres), axis=2)
        positions = _surface_points(centres, visible, self.settings, progress)
        T = np.eye(4)
        if frame == "specimen" and visible[0].sum() >= 6:
            R, origin = specimen_frame(centres[0], self.cameras[0].center, axis_sign=axis_sign)
            T[:3, :3], T[:3, 3] = R, -R @ origin
            centres = centres @ R.T + T[:3, 3]
            positions = positions @ R.T + T[:3, 3]
        diag = {key: np.array([s[key] for s in steps]) for key in _DIAG_KEYS}
        diag["reject_reasons"] = np.array(REJECT_REASONS)
        return SeriesResult(positions, centres, visible, np.stack([s["uncertainty"] for s in steps]),
                            np.stack([s["n_views"] for s in steps]), np.stack([s["rms"] for s in steps]),
                            np.arange(centres.shape[1]), T, diag)


_DIAG_KEYS = ("detected", "rejects", "reconstructed", "tracked", "lost", "recovered", "unassigned", "swaps",
              "outliers", "ambiguous", "sigma_px", "reprojection_rms_median")


def _empty_step(n: int, pts: StepPoints, tracked: int = 0) -> dict:
    """Per-step arrays for n tracked markers (NaN = not seen) and the step's diagnostics."""
    return {
        "centres": np.full((n, 3), np.nan), "uncertainty": np.full(n, np.nan), "n_views": np.zeros(n, np.int64),
        "rms": np.full(n, np.nan), "reconstructed": pts.centres.shape[0], "tracked": tracked, "lost": 0,
        "recovered": 0, "unassigned": 0, "swaps": 0, "outliers": 0, "ambiguous": 0, "sigma_px": pts.sigma_px,
        "reprojection_rms_median": float(np.median(pts.reprojection_rms)) if pts.centres.shape[0] else np.nan,
    }


def _reject_counts(found: Sequence[Detections | None] | None, n_cams: int) -> np.ndarray:
    """(n_cameras, n_reasons) rejected candidates per camera and reason."""
    out = np.zeros((n_cams, len(REJECT_REASONS)), np.int64)
    for c, d in enumerate(found or []):
        if d is not None:
            counts = d.reject_counts()
            out[c] = [counts[r] for r in REJECT_REASONS]
    return out


def _surface_points(centres: np.ndarray, visible: np.ndarray, settings: ReconstructionSettings,
                    progress: Progress | None) -> np.ndarray:
    """Wall points under the markers, (n_steps, n, 3) m: centres moved one marker radius inwards."""
    positions = np.full_like(centres, np.nan)
    n_steps = centres.shape[0]
    for k in range(n_steps):
        if progress:
            progress(k, n_steps, "surface")
        v = visible[k]
        if v.sum() >= 8:
            normals = surface_normals(centres[k, v], method=settings.normals)
            positions[k, v] = marker_surface_points(centres[k, v], settings.marker_diameter / 2, normals)
    return positions


def track_series(
    detections: Sequence[Sequence[np.ndarray]],
    cameras: list[Camera],
    settings: ReconstructionSettings | None = None,
    *,
    axial_ratios: Sequence[float] | None = None,
    progress: Progress | None = None,
    detection_stats: Sequence[Sequence[Detections | None]] | None = None,
    frame: str = "calibration",
    axis_sign: int = 1,
) -> SeriesResult:
    """Correspondence, triangulation and tracking for a series of steps given detections.

    Parameters
    ----------
    detections : sequence (n_steps) of sequences (n_cameras) of ndarray (n_i, 2)
        Pixel centres per step and camera; step 0 is the reference that defines the identities.
    cameras : list of Camera
    settings : ReconstructionSettings
    axial_ratios : sequence of float, optional
        Expected axial length ratio of each step to the previous one (e.g. stretch[k] /
        stretch[k-1]); default estimated from the points.
    progress : callable (step, n_steps, stage), optional
    detection_stats : optional per-step list of Detections (for the diagnostics)
    frame : {"calibration", "specimen"}
        Return points in the calibration's world frame, or in the rig frame of decision 0002
        (z along the fitted specimen axis, origin at the markers' mid-length in the reference
        step, x towards camera 0); see :func:`reconstruction.surface.specimen_frame`.
    axis_sign : {1, -1}
        Orientation of +z with ``frame="specimen"`` (images cannot tell the load-cell end).

    Returns
    -------
    SeriesResult
    """
    if frame not in ("calibration", "specimen"):
        raise ValueError(f"frame must be 'calibration' or 'specimen'; got {frame!r}")
    n_steps = len(detections)
    if n_steps == 0:
        raise ValueError("detections must contain at least the reference step; got 0 steps")
    tracker = SeriesTracker(cameras, settings)
    for k in range(n_steps):
        if progress:
            progress(k, n_steps, "correspondence")
        found = None if detection_stats is None else detection_stats[k]
        quality = None if found is None else [d.quality if d is not None else None for d in found]
        ratio = None if axial_ratios is None or k == 0 else float(axial_ratios[k])
        tracker.add(detections[k], quality=quality, axial_ratio=ratio, found=found)
    return tracker.result(frame=frame, axis_sign=axis_sign, progress=progress)
