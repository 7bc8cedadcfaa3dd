"""Step- and series-level marker reconstruction: detection -> correspondence -> triangulation
-> tracking -> marker-centre offset.

All functions are pure (images and cameras in, arrays out); progress is reported through an
optional callback ``progress(step, n_steps, stage)`` and nothing is printed.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from reconstruction.cameras import Camera
from reconstruction.correspondence import CylinderPrior, match_views, observed_pixels
from reconstruction.detection import REJECT_REASONS, Detections, detect_markers, detect_markers_near
from reconstruction.surface import (
    fit_cylinder,
    marker_surface_points,
    specimen_frame,
    surface_normals,
    surface_residuals,
)
from reconstruction.tracking import marker_spacing, match_step
from reconstruction.triangulation import triangulate

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

Progress = Callable[[int, int, str], None]


@dataclass(frozen=True)
class ReconstructionSettings:
    """Tunable settings of the reconstruction (all lengths in m, pixel gates in px).

    Attributes
    ----------
    marker_diameter : float
        Diameter of the spherical markers, m.
    specimen_radius : float or None
        Approximate outer radius of the specimen at the reference step, m (None: bootstrapped
        from markers seen in >= 3 views).
    epipolar_px, max_reprojection_px : float
        Correspondence gates.
    prior_tolerance : float
        Relative radial tolerance of the loose specimen prior (fraction of the radius).
    normals : {"local", "cylinder"}
        Surface normal estimate for the marker-centre offset.
    guided_gate_px : float
        Image-space gate when searching lost markers near their predicted projection.
    min_facing : float
        A camera can see a marker only if the cosine between the outward normal and the direction
        to the camera exceeds this. Slightly negative keeps the views just beyond the limb that
        a ring of few cameras needs for coverage; with >= 6 cameras 0.0 is ~0.1-1 um more
        accurate and ~1 % less complete.
    outlier_factor, outlier_floor : float
        A tracked point farther from its prediction (previous position + neighbours' motion) than
        ``max(outlier_factor * s, outlier_floor)`` (``s`` = median + 1.4826 MAD of all the step's
        prediction residuals; floor in m) is rejected as a bad measurement and reported NaN.
    reference_outlier_factor, reference_outlier_floor : float
        In the reference step, a point farther than ``max(factor * s, floor)`` from the surface
        through its neighbours (:func:`reconstruction.surface.surface_residuals`) is NaN there and
        tracked from its projection on that surface.
    min_view_cos : float
        Views at grazing incidence (cosine between the surface normal and the direction to the
        camera below this) are dropped when at least two better views remain: near the limb the
        marker is seen against the silhouette and its centroid is biased by up to ~0.5 px.
    grazing_bias_px : float
        Centroid bias (px) assumed for such a view when a point cannot do without it (fewer than
        two better views): its uncertainty is computed with this instead of the pixel noise.
    readmit_strong : bool
        Keep a point beyond the outlier limit (below) when it has >= 2 views that all face their
        camera (cosine >= ``min_view_cos``) and a usual reprojection error: near a clamped end the
        neighbours predict the motion poorly, and rejecting it leaves only grazing views to recover it.
    detection : dict
        Extra keyword arguments for :func:`reconstruction.detection.detect_markers`.
    workers : int or None
        Threads detecting the cameras of a step in parallel (None: one per CPU core; 1: serial).
    guided_detection : bool
        From the second loaded step on, search each image only near the tracked markers'
        predicted projections (:func:`detect_step`).
    guided_radius : float
        Search radius around each predicted projection, in expected marker diameters (plus 1.5x
        the 95th percentile of the markers' image motion in the previous step).
    guided_min_fraction : float
        A camera whose guided search finds fewer than this fraction of its previous step's
        detections is searched again over the whole image.
    """

    marker_diameter: float = 0.4e-3
    specimen_radius: float | None = None
    epipolar_px: float = 2.0
    max_reprojection_px: float = 1.5
    prior_tolerance: float = 0.35
    normals: str = "local"
    guided_gate_px: float = 4.0
    min_view_cos: float = 0.35
    grazing_bias_px: float = 0.2
    readmit_strong: bool = True
    min_facing: float = -0.15
    outlier_factor: float = 6.0
    outlier_floor: float = 15e-6
    reference_outlier_factor: float = 5.0
    reference_outlier_floor: float = 30e-6
    sigma_px: float | None = None
    detection: dict = field(default_factory=dict)
    workers: int | None = None
    guided_detection: bool = True
    guided_radius: float = 2.0
    guided_min_fraction: float = 0.98

    def __post_init__(self) -> None:
        if not self.marker_diameter > 0:
            raise ValueError(f"marker_diameter must be > 0 m; got {self.marker_diameter}")
        if self.specimen_radius is not None and not self.specimen_radius > 0:
            raise ValueError(f"specimen_radius must be > 0 m or None; got {self.specimen_radius}")
        if self.normals not in ("local", "cylinder"):
            raise ValueError(f"normals must be 'local' or 'cylinder'; got {self.normals!r}")


@dataclass(frozen=True)
class StepPoints:
    """Unlabelled 3-D markers of one step.

    Attributes
    ----------
    centres : ndarray, shape (n, 3)
        Sphere centres, m.
    observations : ndarray of int, shape (n, n_cameras)
        Detection index per camera, -1 = unobserved.
    uncertainty : ndarray, shape (n,)
        RMS 3-D position uncertainty, m.
    reprojection_rms : ndarray, shape (n,)
        px.
    n_views : ndarray of int, shape (n,)
    prior : CylinderPrior or None
        The specimen prior used for the final matching.
    detections : list of ndarray, shape (n_i, 2)
        The per-camera detections the observations refer to.
    sigma_px : float
        Pixel noise estimate of the step.
    """

    centres: np.ndarray
    observations: np.ndarray
    uncertainty: np.ndarray
    reprojection_rms: np.ndarray
    n_views: np.ndarray
    prior: CylinderPrior | None
    detections: list[np.ndarray]
    sigma_px: float


def expected_diameter_px(camera: Camera, marker_diameter: float, target: np.ndarray | None = None) -> float:
    """Approximate image diameter (px) of a marker at ``target`` (default world origin)."""
    target = np.zeros(3) if target is None else np.asarray(target, dtype=float)
    dist = float(np.linalg.norm(camera.to_camera(target)))
    return float(camera.K[0, 0] * marker_diameter / max(dist, 1e-12))


def convergence_point(cameras: list[Camera]) -> np.ndarray:
    """Least-squares point closest to all optical axes, (3,) m: where the ring looks (any world frame)."""
    if len(cameras) < 2:
        return cameras[0].center + 0.1 * cameras[0].R[2] if cameras else np.zeros(3)
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for c in cameras:
        d = c.R[2]
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ c.center
    try:
        return np.linalg.solve(A, b)
    except np.linalg.LinAlgError:  # all axes parallel
        return np.mean([c.center + 0.1 * c.R[2] for c in cameras], axis=0)


def detect_all(
    images: Mapping[str, np.ndarray],
    cameras: list[Camera],
    settings: ReconstructionSettings,
    *,
    regions: Sequence[tuple[np.ndarray, float, tuple[float, float] | None] | None] | None = None,
    only: Sequence[int] | None = None,
) -> list[Detections | None]:
    """Run :func:`detect_markers` on every camera's image (None where a camera has no image).

    The accepted diameter range per camera follows from the marker diameter and the camera's
    distance to the point its optical axis shares with the others. The cameras are processed in
    ``settings.workers`` threads (OpenCV and NumPy release the GIL). ``regions`` (per camera:
    expected centres (m, 2) px, a search radius px and the image's (threshold, noise) levels or
    None; or None for the whole image) restricts the search to those neighbourhoods
    (:func:`reconstruction.detection.detect_markers_near`). ``only``: indices of
    the cameras to process (the others are None).
    """
    target = convergence_point(cameras)

    def one(c: int) -> Detections | None:
        cam = cameras[c]
        img = images.get(cam.name)
        if img is None or (only is not None and c not in only):
            return None
        kw = dict(settings.detection)
        if "diameter_range" not in kw:
            d = expected_diameter_px(cam, settings.marker_diameter, target)
            kw["diameter_range"] = (max(0.45 * d, 2.0), max(1.7 * d, 4.0))
        if regions is not None and regions[c] is not None and len(regions[c][0]):
            points, radius, levels = regions[c]
            return detect_markers_near(img, points, radius, levels=levels, **kw)
        return detect_markers(img, **kw)

    workers = min(settings.workers or os.cpu_count() or 1, len(cameras))
    if workers <= 1:
        return [one(c) for c in range(len(cameras))]
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="detect") as pool:
        return list(pool.map(one, range(len(cameras))))


def _bootstrap_prior(dets, cameras, settings: ReconstructionSettings, loose: CylinderPrior | None) -> CylinderPrior | None:
    """A tight cylinder prior from points seen in >= 3 views (matched under a loose prior)."""
    res = match_views(
        dets, cameras, epipolar_px=settings.epipolar_px, max_reprojection_px=settings.max_reprojection_px,
        prior=loose, min_views=3, sigma_px=settings.sigma_px,
    )
    rms = res.triangulation.reprojection_rms
    if rms.size < 8:  # too few markers seen by >= 3 cameras to fit the specimen (e.g. a sparse ring)
        return loose
    clean = rms <= 4.0 * np.median(rms) + 0.05
    if clean.sum() < 8:
        return loose
    guess = None if loose is None else loose.axis_direction
    try:
        cyl = fit_cylinder(res.points[clean], axis_guess=guess)
    except ValueError:
        return loose
    r, _, z = cyl.cylindrical(res.points[clean])
    spread = float(np.percentile(np.abs(r - cyl.radius), 95))
    tol = max(4.0 * spread, 0.04 * cyl.radius, 2.0 * settings.marker_diameter)
    half = float(np.max(np.abs(z))) * 1.3 + 2 * marker_spacing(res.points[clean])
    return CylinderPrior(radius=cyl.radius, tolerance=tol, half_length=half, axis_point=cyl.axis_point,
                         axis_direction=cyl.axis_direction, min_facing=settings.min_facing)


def points_from_detections(
    detections: Sequence[np.ndarray],
    cameras: list[Camera],
    settings: ReconstructionSettings,
    *,
    loose_prior: CylinderPrior | None = None,
    quality: Sequence[np.ndarray] | None = None,
) -> StepPoints:
    """Correspondence + triangulation of one step's detections (pixel centres per camera).

    ``quality`` (per camera, ``(n_i,)``, as :attr:`Detections.quality`): views with quality below
    0.75 (centres recovered from merged blobs) and grazing views are left out of the final
    triangulation of a point when it keeps at least two other views.
    """
    dets = [np.asarray(d, dtype=float).reshape(-1, 2) for d in detections]
    # without a prior the specimen is found from markers seen in >= 3 views, in any world frame
    prior = _bootstrap_prior(dets, cameras, settings, loose_prior)
    rho = settings.marker_diameter / 2
    if settings.specimen_radius is not None:
        R = settings.specimen_radius + rho
        if prior is None:
            log.warning("no specimen found from >= 3-view markers; assuming the axis is the world z axis")
            prior = CylinderPrior(radius=R, tolerance=settings.prior_tolerance * R, min_facing=settings.min_facing)
        elif loose_prior is None and abs(prior.radius - R) > 0.5 * R:
            log.warning("fitted marker-centre radius %.3f mm differs from the expected %.3f mm", prior.radius * 1e3, R * 1e3)
    res = match_views(
        dets, cameras, epipolar_px=settings.epipolar_px, max_reprojection_px=settings.max_reprojection_px,
        prior=prior, min_views=2, sigma_px=settings.sigma_px,
    )
    obs = res.observations
    t = res.triangulation
    weak = np.zeros(obs.shape[0], bool)
    if prior is not None and obs.shape[0] and settings.min_view_cos > -1:
        cosv = _view_cosines(t.points, prior, cameras)  # (n, n_cams)
        weak = np.any((obs >= 0) & (cosv < settings.min_view_cos), axis=1)
        good = (obs >= 0) & (cosv >= settings.min_view_cos)
        if quality is not None:
            for c, q in enumerate(quality):
                if q is not None and len(q):
                    qc = np.where(obs[:, c] >= 0, np.asarray(q)[np.maximum(obs[:, c], 0)], 1.0)
                    good[:, c] &= qc >= 0.75
        drop = (obs >= 0) & ~good & (good.sum(axis=1) >= 2)[:, None]
        if np.any(drop):
            obs = np.where(drop, -1, obs)
            t = triangulate(observed_pixels(dets, obs), cameras, sigma_px=settings.sigma_px)
            weak &= np.any((obs >= 0) & (cosv < settings.min_view_cos), axis=1)
    # a point whose views disagree more than usual (e.g. two views, one biased) is less certain
    # than the pooled pixel noise says: scale its uncertainty by its excess reprojection error;
    # one that cannot do without a grazing view inherits that view's centroid bias (the larger
    # of the two: a grazing view's bias is what makes the views disagree)
    excess = np.ones(obs.shape[0])
    if obs.shape[0] >= 10:
        typical = float(np.median(t.reprojection_rms))
        excess = np.maximum(1.0, t.reprojection_rms / max(typical, 1e-6))
    unc = np.maximum(t.uncertainty * excess, _weak_view_uncertainty(t.uncertainty, weak, t.sigma_px, settings))
    return StepPoints(t.points, obs, unc, t.reprojection_rms, t.n_views, prior, dets, t.sigma_px)


def _view_cosines(points: np.ndarray, prior: CylinderPrior, cameras: list[Camera]) -> np.ndarray:
    """Cosine between the outward radial direction and the direction to each camera, (n, n_cams)."""
    _, _, nrm = prior.radial(points)
    out = np.empty((points.shape[0], len(cameras)))
    for c, cam in enumerate(cameras):
        v = cam.center - points
        out[:, c] = np.sum(nrm * v, axis=1) / np.linalg.norm(v, axis=1)
    return out


def _strong_points(step: StepPoints, cameras: list[Camera], settings: ReconstructionSettings) -> np.ndarray:
    """(n,) bool: points with >= 2 views, all facing their camera (cosine >= ``min_view_cos``)
    and a reprojection error within the step's usual range."""
    obs = step.observations >= 0
    if step.prior is None or not obs.shape[0]:
        return np.zeros(obs.shape[0], bool)
    cosv = _view_cosines(step.centres, step.prior, cameras)
    facing = np.all(~obs | (cosv >= settings.min_view_cos), axis=1)
    typical = float(np.median(step.reprojection_rms))
    return facing & (obs.sum(axis=1) >= 2) & (step.reprojection_rms <= 3.0 * typical + 0.05)


def reconstruct_step(
    images: Mapping[str, np.ndarray],
    cameras: list[Camera],
    settings: ReconstructionSettings | None = None,
    *,
    loose_prior: CylinderPrior | None = None,
) -> tuple[StepPoints, list[Detections | None]]:
    """Detect, match and triangulate the markers of one step (no identities).

    Parameters
    ----------
    images : mapping camera name -> ndarray (H, W)
        Missing cameras are allowed.
    cameras : list of Camera
    settings : ReconstructionSettings, optional

    Returns
    -------
    (StepPoints, list of Detections or None per camera)
    """
    settings = settings or ReconstructionSettings()
    found = detect_all(images, cameras, settings)
    dets = [d.centres if d is not None else np.zeros((0, 2)) for d in found]
    return points_from_detections(dets, cameras, settings, loose_prior=loose_prior), found


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


def _weak_view_uncertainty(unc: np.ndarray, weak: np.ndarray, sigma_px: float, settings: ReconstructionSettings) -> np.ndarray:
    """Uncertainty (m) of points built with grazing views: the pixel noise is replaced by the
    centroid bias of a blob near the silhouette (``settings.grazing_bias_px``)."""
    scale = max(1.0, settings.grazing_bias_px / max(float(sigma_px), 1e-6))
    return np.where(weak, unc * scale, unc)


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
