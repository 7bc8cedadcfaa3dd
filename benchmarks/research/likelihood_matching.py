"""Multi-camera particle matching by a likelihood ratio instead of hard gates.

At a high particle density the true matches of a frame are among its candidates at wide gates, but so are
many chance coincidences (``docs/validation/reconstruction.md``, "Real data"). Hard gates either cut true matches whose
calibration error is larger than the gate or let chance in. Each candidate instead gets the log of the ratio
of its likelihood as a true match to its likelihood as a chance coincidence, product over its cameras
(Blackman's track score; Blackman & Popoli 1999, "Design and analysis of modern tracking systems", 6.2):

    LLR = sum over the observing cameras c of  [ log N2(r_c; 0, s_c^2) - log rho_c ]
        = sum_c [ -|r_c|^2 / (2 s_c^2) - log(2 pi s_c^2 rho_c) ]

- ``r_c``: the candidate's reprojection residual in camera c (projected minus detected, px) after its
  triangulation with all its views, on detections moved by the calibration's measured bias map
  (:func:`benchmarks.research.temporal_matching.apply_pixel_correction`);
- ``s_c``: the scatter of a true match's residual in camera c (per axis, px), measured (:func:`fit_true_model`);
- ``rho_c``: the local density of detections around the candidate's detection in camera c (px^-2,
  :func:`local_density`): a chance detection within a small radius of the projection of an unrelated point
  lies anywhere in that disc with density ``rho_c`` (P(chance within r) ~ 1 - exp(-rho pi r^2)).

Each view adds ``-log(2 pi s^2 rho)`` (about +5 to +6 for s = 0.4 px, one detection per 350 px^2) minus its
residual penalty: a 4-view candidate with moderate residuals can be far more credible than a 3-view one with
small residuals in a crowded region. The terms common to all candidates (the prior of the 3-D point over the
volume, the triangulation's Laplace factor, nearly the same for 3 and 4 views) go into the threshold.

:func:`select_by_score`: candidates ranked by LLR, each detection used once (global greedy, as
``correspondence.match_views`` ranks by cost), those at or above a threshold kept. :func:`likelihood_match`
runs candidates, score and selection on one frame; :func:`fit_true_model` measures the bias map and ``s_c``
on one frame by alternating selection and fit (then used frozen on other frames).

Over time (:func:`likelihood_match_over_time`): a candidate in a smooth triplet of consecutive frames
(``temporal_matching.smooth_triplets``: small second difference, some motion, a residual per camera that stays
constant) gets ``persistence_bonus`` added to its score before the selection: the persistence test's evidence.

Pure functions over arrays; metres and pixels as OpenCV (``docs/decisions/0002-frames-and-shapes.md``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from reconstruction.cameras import Camera
from reconstruction.correspondence import observed_pixels
from benchmarks.research.temporal_matching import (FrameCandidates, apply_pixel_correction, fit_pixel_correction,
                                              frame_candidates, persistence_support, select_greedy)
from reconstruction.triangulation import triangulate

__all__ = ["TrueModel", "LikelihoodMatch", "local_density", "with_subsets", "log_likelihood_ratio",
           "select_by_score", "score_candidates", "likelihood_match", "fit_true_model", "likelihood_match_over_time"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrueModel:
    """What a true match's residuals look like, per camera.

    Attributes
    ----------
    sigma_px : ndarray, shape (n_cameras,)
        Scatter per axis of a true match's residual after the bias map, px.
    coefficients : ndarray, shape (n_cameras, n_terms, 2)
        Bias map (:func:`benchmarks.research.temporal_matching.fit_pixel_correction`; zeros = no bias).
    """

    sigma_px: np.ndarray
    coefficients: np.ndarray

    @classmethod
    def isotropic(cls, sigma_px: float, n_cameras: int, degree: int = 3) -> "TrueModel":
        """The same ``sigma_px`` in every camera, no bias map."""
        if not sigma_px > 0:
            raise ValueError(f"sigma_px must be > 0 px; got {sigma_px}")
        n_terms = (degree + 1) * (degree + 2) // 2
        return cls(np.full(n_cameras, float(sigma_px)), np.zeros((n_cameras, n_terms, 2)))

    def corrected(self, detections: list[np.ndarray], cameras: list[Camera]) -> list[np.ndarray]:
        """Detections ``(n_i, 2)`` per camera moved by the bias map."""
        if not np.any(self.coefficients):
            return [np.asarray(d, float).reshape(-1, 2) for d in detections]
        return apply_pixel_correction(detections, self.coefficients, [c.image_size for c in cameras])


@dataclass(frozen=True)
class LikelihoodMatch:
    """Result of :func:`likelihood_match`.

    Attributes
    ----------
    observations : ndarray of int, shape (m, n_cameras)
        Accepted matches: detection index per camera (into the detections as given), -1 = not seen.
    points : ndarray, shape (m, 3)
        Their triangulated points (on the corrected detections), m.
    rms : ndarray, shape (m,)
        Their reprojection RMS (on the corrected detections), px.
    score : ndarray, shape (m,)
        Their log-likelihood ratio.
    candidates : FrameCandidates
        Every candidate scored (on the corrected detections).
    candidate_score : ndarray, shape (n,)
        The candidates' log-likelihood ratio.
    """

    observations: np.ndarray
    points: np.ndarray
    rms: np.ndarray
    score: np.ndarray
    candidates: FrameCandidates
    candidate_score: np.ndarray


def local_density(detections: np.ndarray, radius_px: float | None = 25.0) -> np.ndarray:
    """Detections per px^2 around each detection: the others within ``radius_px``, over the disc's area.

    ``detections`` ``(n, 2)`` px -> ``(n,)`` px^-2; at least one detection per disc is assumed (a lone
    detection is not infinitely credible). ``radius_px=None``: one density for all, the count over the area of
    the detections' bounding box (no local information)."""
    d = np.asarray(detections, float).reshape(-1, 2)
    if radius_px is not None and not radius_px > 0:
        raise ValueError(f"radius_px must be > 0 px or None; got {radius_px}")
    if len(d) == 0:
        return np.zeros(0)
    if radius_px is None:
        area = max(float(np.prod(np.ptp(d, axis=0))), 1.0)
        return np.full(len(d), len(d) / area)
    n = cKDTree(d).query_ball_point(d, radius_px, return_length=True) - 1
    return np.maximum(n, 1) / (np.pi * radius_px**2)


def with_subsets(observations: np.ndarray, min_views: int = 3) -> np.ndarray:
    """The candidates ``(n, n_cameras)`` and, for those with more than ``min_views`` views, every subset with
    one view fewer down to ``min_views`` (a 4-view candidate that loses a detection to a better one may still
    stand on its other three). Unique rows ``(n', n_cameras)``."""
    obs = np.asarray(observations, np.int64)
    out, cur = [obs], obs
    n_cams = obs.shape[1]
    while True:
        cur = cur[(cur >= 0).sum(axis=1) > min_views]
        if len(cur) == 0:
            break
        subs = []
        for c in range(n_cams):
            s = cur[cur[:, c] >= 0].copy()
            s[:, c] = -1
            subs.append(s)
        cur = np.unique(np.concatenate(subs), axis=0)
        out.append(cur)
    return np.unique(np.concatenate(out), axis=0)


def log_likelihood_ratio(residuals: np.ndarray, density: np.ndarray, sigma_px: np.ndarray) -> np.ndarray:
    """Per candidate, sum over its cameras of ``-|r|^2 / (2 s^2) - log(2 pi s^2 rho)`` (module docstring).

    Parameters
    ----------
    residuals : ndarray, shape (n_cameras, n, 2)
        Reprojection residuals, px; NaN where a camera does not see the candidate.
    density : ndarray, shape (n_cameras, n)
        Local detection density around the candidate's detection, px^-2 (ignored where not seen).
    sigma_px : ndarray, shape (n_cameras,)
        Per-axis scatter of a true match's residual, px.

    Returns
    -------
    ndarray, shape (n,)
    """
    r2 = np.sum(np.asarray(residuals, float) ** 2, axis=-1)  # (n_cams, n)
    s2 = np.asarray(sigma_px, float)[:, None] ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        term = -r2 / (2.0 * s2) - np.log(2.0 * np.pi * s2 * np.asarray(density, float))
    return np.sum(np.where(np.isfinite(r2), term, 0.0), axis=0)


def select_by_score(observations: np.ndarray, score: np.ndarray, threshold: float = -np.inf) -> np.ndarray:
    """Indices of the candidates kept: ranked by ``score`` (descending), one kept when its score is
    >= ``threshold`` and none of its detections is taken yet (each detection used once).

    ``observations`` ``(n, n_cameras)`` (-1 = not seen), ``score`` ``(n,)`` -> ndarray of int ``(m,)``, in rank
    order."""
    score = np.asarray(score, float)
    if len(observations) != score.shape[0]:
        raise ValueError(f"score must have one value per candidate ({len(observations)}); got {score.shape[0]}")
    idx = np.flatnonzero(score >= threshold)
    return select_greedy(observations, idx[np.argsort(-score[idx], kind="stable")])


def score_candidates(detections: list[np.ndarray], cameras: list[Camera], bounds, model: TrueModel, *,
                     gates=(3.0, 2.5, 2.5), min_views: int = 3,
                     density_radius_px: float | None = 25.0) -> tuple[FrameCandidates, np.ndarray, list[np.ndarray]]:
    """Candidates of one frame on the detections moved by ``model``'s bias map, with their 4-view candidates'
    3-view subsets, and their log-likelihood ratio.

    Parameters
    ----------
    detections : list of ndarray, shape (n_i, 2)
        Distorted pixel centres per camera, px.
    cameras : list of Camera
    bounds : (ndarray (3,), ndarray (3,))
        World box of the measurement volume, m.
    model : TrueModel
    gates : tuple of 3 float
        (epipolar_px, radius_px, max_residual_px) of :func:`benchmarks.research.temporal_matching.frame_candidates`.
    min_views : int
    density_radius_px : float or None
        Radius of :func:`local_density`, px (None: one density for the whole image).

    Returns
    -------
    candidates : FrameCandidates
        On the corrected detections.
    score : ndarray, shape (n,)
    corrected : list of ndarray, shape (n_i, 2)
        The corrected detections.
    """
    dets = model.corrected(detections, cameras)
    fc = frame_candidates(dets, cameras, bounds, epipolar_px=gates[0], radius_px=gates[1],
                          max_residual_px=gates[2], min_views=min_views)
    obs = with_subsets(fc.observations, min_views)
    tri = triangulate(observed_pixels(dets, obs), cameras, covariance=False)
    worst = np.nanmax(np.linalg.norm(tri.residuals, axis=-1), axis=0, initial=0.0) if len(obs) else np.zeros(0)
    ok = (worst <= gates[2]) & np.all(np.isfinite(tri.points), axis=1)
    cands = FrameCandidates(obs[ok], tri.points[ok], tri.reprojection_rms[ok], tri.residuals[:, ok])
    rho = np.full(cands.observations.T.shape, np.nan)
    for c, d in enumerate(dets):
        seen = cands.observations[:, c] >= 0
        rho[c, seen] = local_density(d, density_radius_px)[cands.observations[seen, c]]
    return cands, log_likelihood_ratio(cands.residuals, rho, model.sigma_px), dets


def likelihood_match(detections: list[np.ndarray], cameras: list[Camera], bounds, model: TrueModel,
                     threshold: float, **options) -> LikelihoodMatch:
    """Matches of one frame by log-likelihood ratio (module docstring): :func:`score_candidates`, then
    :func:`select_by_score` with ``threshold``. ``options``: keywords of :func:`score_candidates`."""
    if len(detections) != len(cameras):
        raise ValueError(f"detections must have one array per camera ({len(cameras)}); got {len(detections)}")
    cands, score, _ = score_candidates(detections, cameras, bounds, model, **options)
    keep = select_by_score(cands.observations, score, threshold)
    return LikelihoodMatch(cands.observations[keep], cands.points[keep], cands.rms[keep], score[keep], cands, score)


def fit_true_model(detections: list[np.ndarray], cameras: list[Camera], bounds, *, threshold: float,
                   sigma_px: float = 0.5, degree: int = 3, iterations: int = 3, **options) -> TrueModel:
    """Measure a true match's residuals on one frame: select with the current model (:func:`likelihood_match`
    at ``threshold``), fit the bias map on the selected matches' residuals (on the detections as given: the
    coefficients add up), take each camera's per-axis scatter from their median residual norm (a 2-D normal's
    median norm is 1.1774 sigma) and repeat ``iterations`` times, starting from ``sigma_px`` in every camera
    and no bias.

    ``degree``: of the bias map (0: no map, scatter only). ``options``: keywords of :func:`score_candidates`.
    Returns the TrueModel (to be used frozen on other frames)."""
    model = TrueModel.isotropic(sigma_px, len(cameras), max(degree, 1))
    sizes = [c.image_size for c in cameras]
    for it in range(iterations):
        cands, score, _ = score_candidates(detections, cameras, bounds, model, **options)
        keep = select_by_score(cands.observations, score, threshold)
        obs, res = cands.observations[keep], cands.residuals[:, keep]
        coef = model.coefficients
        if degree > 0:
            coef = coef + fit_pixel_correction(observed_pixels(detections, obs), res, sizes, degree=degree)
            moved = TrueModel(model.sigma_px, coef).corrected(detections, cameras)
            res = triangulate(observed_pixels(moved, obs), cameras, covariance=False).residuals
        norm = np.linalg.norm(res, axis=-1)
        sigma = np.array([np.nanmedian(n) / 1.1774 if np.isfinite(n).sum() >= 10 else s
                          for n, s in zip(norm, model.sigma_px)])
        model = TrueModel(sigma, coef)
        log.info("fit_true_model: pass %d, %d matches, sigma %s px", it + 1, len(obs), np.round(sigma, 3))
    return model


def likelihood_match_over_time(frames: list[list[np.ndarray]], cameras: list[Camera], bounds, model: TrueModel,
                               threshold: float, *, persistence_bonus: float, max_step_m: float, max_accel_m: float,
                               max_residual_change_px: float = 0.5, min_motion_m: float = 0.2e-3,
                               **options) -> list[LikelihoodMatch]:
    """Per frame of ``frames`` (consecutive; each the detections of every camera, px), the matches by
    log-likelihood ratio plus ``persistence_bonus`` (nats) for the candidates in a smooth triplet
    (``temporal_matching.persistence_support``; ``max_step_m``, ``max_accel_m``, ``min_motion_m`` in m,
    ``max_residual_change_px`` in px), selected at ``threshold``. ``options``: keywords of
    :func:`score_candidates`. The LikelihoodMatch scores include the bonus."""
    if len(frames) < 3:
        raise ValueError(f"frames must hold at least 3 consecutive frames (a smooth triplet); got {len(frames)}")
    scored = [score_candidates(d, cameras, bounds, model, **options)[:2] for d in frames]
    sup = persistence_support([c for c, _ in scored], max_step_m=max_step_m, max_accel_m=max_accel_m,
                              max_residual_change_px=max_residual_change_px, min_motion_m=min_motion_m)
    out = []
    for (cands, score), s in zip(scored, sup):
        total = score + persistence_bonus * (s > 0)
        keep = select_by_score(cands.observations, total, threshold)
        out.append(LikelihoodMatch(cands.observations[keep], cands.points[keep], cands.rms[keep], total[keep],
                                   cands, total))
    return out
