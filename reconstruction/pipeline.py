"""Step- and series-level marker reconstruction: detection -> correspondence -> triangulation
-> tracking -> marker-centre offset.

All functions are pure (images and cameras in, arrays out); progress is reported through an
optional callback ``progress(step, n_steps, stage)`` and nothing is printed.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from reconstruction.cameras import Camera
from reconstruction.correspondence import CylinderPrior, match_views, observed_pixels
from reconstruction.detection import REJECT_REASONS, Detections, detect_markers
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
    "StepPoints",
    "SeriesResult",
    "detect_all",
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
    images: Mapping[str, np.ndarray], cameras: list[Camera], settings: ReconstructionSettings
) -> list[Detections | None]:
    """Run :func:`detect_markers` on every camera's image (None where a camera has no image).

    The accepted diameter range per camera follows from the marker diameter and the camera's
    distance to the point its optical axis shares with the others.
    """
    target = convergence_point(cameras)
    out: list[Detections | None] = []
    for cam in cameras:
        img = images.get(cam.name)
        if img is None:
            out.append(None)
            continue
        kw = dict(settings.detection)
        if "diameter_range" not in kw:
            d = expected_diameter_px(cam, settings.marker_diameter, target)
            kw["diameter_range"] = (max(0.45 * d, 2.0), max(1.7 * d, 4.0))
        out.append(detect_markers(img, **kw))
    return out


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
    settings = settings or ReconstructionSettings()
    if frame not in ("calibration", "specimen"):
        raise ValueError(f"frame must be 'calibration' or 'specimen'; got {frame!r}")
    n_steps = len(detections)
    if n_steps == 0:
        raise ValueError("detections must contain at least the reference step; got 0 steps")
    n_cams = len(cameras)
    rho = settings.marker_diameter / 2
    diag = {
        "detected": np.array([[len(d) for d in step] for step in detections], dtype=np.int64),
        "reconstructed": np.zeros(n_steps, np.int64),
        "tracked": np.zeros(n_steps, np.int64),
        "lost": np.zeros(n_steps, np.int64),
        "recovered": np.zeros(n_steps, np.int64),
        "unassigned": np.zeros(n_steps, np.int64),
        "swaps": np.zeros(n_steps, np.int64),
        "outliers": np.zeros(n_steps, np.int64),
        "ambiguous": np.zeros(n_steps, np.int64),
        "sigma_px": np.full(n_steps, np.nan),
        "reprojection_rms_median": np.full(n_steps, np.nan),
        "reject_reasons": np.array(REJECT_REASONS),
        "rejects": np.zeros((n_steps, n_cams, len(REJECT_REASONS)), np.int64),
    }
    if detection_stats is not None:
        for k, step in enumerate(detection_stats):
            for c, d in enumerate(step):
                if d is not None:
                    counts = d.reject_counts()
                    diag["rejects"][k, c] = [counts[r] for r in REJECT_REASONS]

    if progress:
        progress(0, n_steps, "correspondence")
    def quality(k):
        if detection_stats is None:
            return None
        return [d.quality if d is not None else None for d in detection_stats[k]]

    ref = points_from_detections(detections[0], cameras, settings, quality=quality(0))
    n = ref.centres.shape[0]
    if n == 0:
        raise ValueError("no markers were reconstructed in the reference step (step 0)")
    centres = np.full((n_steps, n, 3), np.nan)
    unc = np.full((n_steps, n), np.nan)
    nv = np.zeros((n_steps, n), np.int64)
    rms = np.full((n_steps, n), np.nan)
    centres[0], unc[0], nv[0], rms[0] = ref.centres, ref.uncertainty, ref.n_views, ref.reprojection_rms
    diag["reconstructed"][0] = diag["tracked"][0] = n
    diag["sigma_px"][0] = ref.sigma_px
    diag["reprojection_rms_median"][0] = float(np.median(ref.reprojection_rms))
    carried = ref.centres.copy()
    # the reference has no prediction to check against: a point standing out of the smooth wall
    # of its neighbours (a depth error of a 2-view point) is NaN in step 0; its position projected
    # on the neighbours' surface is carried so that it is still tracked in later steps
    r0, n0 = surface_residuals(ref.centres)
    fin = np.isfinite(r0)
    if fin.sum() >= 10:
        scale = 1.4826 * np.median(np.abs(r0[fin] - np.median(r0[fin]))) + np.median(np.abs(r0[fin]))
        bad = fin & (np.abs(r0) > max(settings.reference_outlier_factor * scale, settings.reference_outlier_floor))
        if np.any(bad):
            carried[bad] = ref.centres[bad] - r0[bad, None] * n0[bad]
            centres[0, bad] = np.nan
            unc[0, bad] = rms[0, bad] = np.nan
            nv[0, bad] = 0
            diag["outliers"][0] = int(bad.sum())
            diag["tracked"][0] = n - int(bad.sum())
    prior = ref.prior
    for k in range(1, n_steps):
        if progress:
            progress(k, n_steps, "correspondence")
        loose = None
        if prior is not None:
            loose = CylinderPrior(radius=prior.radius, tolerance=settings.prior_tolerance * prior.radius,
                                  axis_point=prior.axis_point, axis_direction=prior.axis_direction,
                                  min_facing=settings.min_facing)
        step = points_from_detections(detections[k], cameras, settings, loose_prior=loose, quality=quality(k))
        diag["reconstructed"][k] = step.centres.shape[0]
        diag["sigma_px"][k] = step.sigma_px
        if step.centres.shape[0]:
            diag["reprojection_rms_median"][k] = float(np.median(step.reprojection_rms))
        if progress:
            progress(k, n_steps, "tracking")
        ratio = None if axial_ratios is None else float(axial_ratios[k])
        if step.centres.shape[0] >= 6:
            m = match_step(carried, step.centres, axial_ratio=ratio)
            a, pred = m.assignment, m.predicted
            diag["swaps"][k] = m.swaps.shape[0]
            diag["ambiguous"][k] = int(m.ambiguous.sum())
            gate = m.gate
            # a point far from where its neighbours say it should be is a bad measurement (a
            # partly occluded or merged view in a 2-view point): NaN rather than a wrong position
            r = m.residual[np.isfinite(m.residual)]
            if r.size >= 10:
                scale = 1.4826 * np.median(np.abs(r - np.median(r))) + np.median(r)
                limit = max(settings.outlier_factor * scale, settings.outlier_floor)
                bad = np.isfinite(m.residual) & (m.residual > limit)
                if settings.readmit_strong and np.any(bad) and step.prior is not None:
                    # near a clamped end the neighbours predict the motion poorly; a point seen in
                    # >= 2 views that all face the camera well is a sound measurement: keep it,
                    # rather than replace it by a guided point from the grazing views left over
                    bad &= ~_strong_points(step, cameras, settings)[np.maximum(a, 0)]
                a = np.where(bad, -1, a)
                diag["outliers"][k] = int(bad.sum())
        else:
            a, pred, gate = np.full(n, -1, np.int64), carried.copy(), 0.35 * marker_spacing(carried)
        ok = a >= 0
        centres[k, ok] = step.centres[a[ok]]
        unc[k, ok] = step.uncertainty[a[ok]]
        nv[k, ok] = step.n_views[a[ok]]
        rms[k, ok] = step.reprojection_rms[a[ok]]
        diag["unassigned"][k] = step.centres.shape[0] - int(ok.sum())
        rec = _guided_recovery(pred, ~ok, step, cameras, settings, gate)
        if rec is not None:
            idx, X, u, r, v, _ = rec
            centres[k, idx], unc[k, idx], rms[k, idx], nv[k, idx] = X, u, r, v
            diag["recovered"][k] = idx.size
        vis = np.all(np.isfinite(centres[k]), axis=1)
        diag["tracked"][k] = int(vis.sum())
        diag["lost"][k] = n - int(vis.sum())
        carried = np.where(vis[:, None], centres[k], pred)
        if step.prior is not None:
            prior = step.prior
    visible = np.all(np.isfinite(centres), axis=2)
    positions = np.full_like(centres, np.nan)
    for k in range(n_steps):
        if progress:
            progress(k, n_steps, "surface")
        v = visible[k]
        if v.sum() >= 8:
            normals = surface_normals(centres[k, v], method=settings.normals)
            positions[k, v] = marker_surface_points(centres[k, v], rho, normals)
    T = np.eye(4)
    if frame == "specimen" and visible[0].sum() >= 6:
        R, origin = specimen_frame(centres[0], cameras[0].center, axis_sign=axis_sign)
        T[:3, :3], T[:3, 3] = R, -R @ origin
        centres = centres @ R.T + T[:3, 3]
        positions = positions @ R.T + T[:3, 3]
    return SeriesResult(positions, centres, visible, unc, nv, rms, np.arange(n), T, diag)


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
    if callable(images):
        if n_steps is None:
            raise ValueError("n_steps is required when images is a callable")
        get = images
    else:
        n_steps = len(images) if n_steps is None else n_steps
        seq = images
        get = lambda k: seq[k]  # noqa: E731
    dets, stats = [], []
    for k in range(n_steps):
        if progress:
            progress(k, n_steps, "detection")
        found = detect_all(get(k), cameras, settings)
        stats.append(found)
        dets.append([d.centres if d is not None else np.zeros((0, 2)) for d in found])
    return track_series(dets, cameras, settings, axial_ratios=axial_ratios, progress=progress, detection_stats=stats,
                        frame=frame, axis_sign=axis_sign)
