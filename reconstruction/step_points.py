"""One step's markers: detection in every camera (in parallel), correspondence, triangulation and the
marker-centre offset, giving :class:`StepPoints`. Pure: images and cameras in, arrays out.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from reconstruction.cameras import Camera
from reconstruction.correspondence import CylinderPrior, match_views, observed_pixels
from reconstruction.detection import Detections, detect_markers, detect_markers_near
from reconstruction.settings import ReconstructionSettings
from reconstruction.surface import fit_cylinder
from reconstruction.tracking import marker_spacing
from reconstruction.triangulation import triangulate

__all__ = ["StepPoints", "expected_diameter_px", "convergence_point", "detect_all", "points_from_detections", "reconstruct_step"]

log = logging.getLogger(__name__)


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


def _weak_view_uncertainty(unc: np.ndarray, weak: np.ndarray, sigma_px: float, settings: ReconstructionSettings) -> np.ndarray:
    """Uncertainty (m) of points built with grazing views: the pixel noise is replaced by the
    centroid bias of a blob near the silhouette (``settings.grazing_bias_px``)."""
    scale = max(1.0, settings.grazing_bias_px / max(float(sigma_px), 1e-6))
    return np.where(weak, unc * scale, unc)
