"""Multi-camera calibration: per-camera initialisation, pose graph, one joint bundle adjustment.

Input are synchronised observations of a rigid target (a calibration board, or any set of
object points with known coordinates in its own frame) in several views:
``image_points (n_cams, n_views, n_points, 2)`` with NaN where a point is not observed.

Method
------
1. Each camera alone: ``cv2.calibrateCamera`` on the views it sees (intrinsics + board poses).
2. Relative camera poses from shared views, averaged over the shared views, chained along a
   maximum spanning tree of the camera graph (edge weight = shared observations) from the
   reference camera; board poses in the world from the best camera that sees them.
3. One joint sparse bundle adjustment (``scipy.optimize.least_squares``) of all intrinsics
   (fx, fy, cx, cy, k1, k2, p1, p2, k3), all camera poses (the reference camera fixes the gauge)
   and all board poses, with a robust loss; observations whose residual exceeds a robust
   threshold are rejected and the problem re-solved with a plain least-squares loss.

World frame: the reference camera's frame, or the board frame of view ``world_view``.

Windows (``windows=``): cameras looking into a bath through flat windows (air | glass | water) are
adjusted with the exact refraction of :mod:`reconstruction.refraction` (step 3 is repeated through
the windows, from the straight-ray solution); ``refine_window=True`` adds each plane's position
and normal to the unknowns (one plane per tank wall, shared by the cameras behind it), after
checking that the views determine them (else the refinement is refused: ILL-POSED).
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from .calibration_bundle import _NAN_RESIDUAL_PX, _bundle_adjust
from .calibration_init import (
    _board_poses,
    _camera_vectors,
    _initialise_cameras,
    _normalise_inputs,
    _pose_graph,
    _resolve_flips,
)
from .calibration_errors import CalibrationError
from .calibration_model import _N_CAM, CalibrationResult, WindowFit, _project, _window_model, _WindowModel
from .cameras import Camera, rotation_matrix
from .refraction import Window
from .targets import BoardDetection, BoardSpec

__all__ = [
    "CalibrationError",
    "CalibrationResult",
    "WindowFit",
    "calibrate_cameras",
    "calibrate_from_detections",
    "detections_to_arrays",
    "reprojection_errors",
]

log = logging.getLogger(__name__)


def calibrate_cameras(
    image_points: np.ndarray,
    object_points: np.ndarray,
    image_sizes: list[tuple[int, int]],
    camera_names: list[str] | None = None,
    *,
    reference: int = 0,
    world_view: int | None = None,
    min_points: int = 6,
    loss: str = "soft_l1",
    f_scale: float = 1.0,
    outlier_sigma: float = 5.0,
    min_outlier_px: float = 0.5,
    fix_k3: bool = False,
    max_rounds: int = 3,
    resolve_flips: bool = False,
    windows=None,
    window_groups: list | None = None,
    refine_window: bool = False,
    max_window_std_m: float = 0.5e-3,
    max_window_std_deg: float = 0.3,
    window_noise_px: float = 0.05,
) -> CalibrationResult:
    """Calibrate N cameras jointly from synchronised views of a rigid target.

    Parameters
    ----------
    image_points : ndarray, shape (n_cams, n_views, n_points, 2)
        Observed pixels; NaN where a camera does not see a point in a view.
    object_points : ndarray, shape (n_points, 3) or (n_views, n_points, 3)
        Target points in the target's own frame, m (any unit works; it sets the unit of the
        translations).
    image_sizes : list of (width, height)
        Pixels, per camera.
    camera_names : list of str, optional
        Default ``cam0, cam1, ...``.
    reference : int
        Camera whose frame is the world frame during the adjustment (gauge).
    world_view : int, optional
        Express the result in the board frame of this view instead.
    min_points : int
        A camera uses a view only if it sees at least this many points.
    loss, f_scale : str, float
        Robust loss of ``least_squares`` and its scale (px) for the first solve.
    outlier_sigma, min_outlier_px : float
        Observations with residual norm above ``max(min_outlier_px, outlier_sigma * s)`` are rejected,
        ``s = 1.4826 * median(residual norm)``.
    fix_k3 : bool
        Keep k3 at zero (recommended with few views or short lenses).
    max_rounds : int
        Rounds of outlier rejection and re-solve.
    resolve_flips : bool
        The target is symmetric under reversal of its point order (chessboards and symmetric circle
        grids: OpenCV may number a view from either end, and two cameras may disagree). Each camera's
        view is re-ordered when the reversed order agrees better with the other cameras.
    windows : Window or list of (Window or None), optional
        The flat window(s) the cameras look through into the bath (world frame = the reference camera's
        frame): one :class:`~reconstruction.refraction.Window` for all cameras (one tank wall, as the rig
        file's ``[window]`` table), or one per camera (None = straight rays). The adjustment then projects
        through them exactly (after a first solve with straight rays as the start). None: no window,
        nothing changes.
    window_groups : list, optional
        One label per camera: cameras with the same label look through the same plane. Default: cameras
        given equal windows share one plane; different windows are separate planes.
    refine_window : bool
        Also refine each plane's position along its normal and its normal's direction (two tilts).
        Needs the board at several depths and tilts through the window; the result's ``window_fit``
        gives the uncertainties, correlations and ``well_posed``.
    max_window_std_m, max_window_std_deg : float
        Before anything moves, the 1-sigma of every plane's offset (normal) at the start is computed at the
        noise floor; above these the window is not determined by the views: the refinement is refused
        (the windows are kept where given), ``window_fit.well_posed = False`` and its message says
        ILL-POSED (logged as a warning). The final 1-sigma are checked the same way. Measured on the
        synthetic rig of ``tests/test_calib_window_ba.py`` (3 cameras, 9 board views at 3 depths): one
        wall shared by the cameras 0.22 mm / 0.09 deg; one window per camera 3.7-11 mm.
    window_noise_px : float
        Floor of the pixel noise (per coordinate) behind the window's uncertainties: the residual RMS,
        but not less than this (noise-free synthetic data would otherwise call any window determined).

    Returns
    -------
    CalibrationResult
    """
    uv, obj, names, counts, usable = _checked_inputs(image_points, object_points, image_sizes, camera_names,
                                                     reference, min_points)
    n_cams, n_views = uv.shape[:2]
    Ks, dists, poses, init_rms = _initialise_cameras(uv, obj, image_sizes, min_points, names, fix_k3)
    Rw, tw, flip = _pose_graph(obj, names, counts, usable, poses, reference, resolve_flips)
    if flip is not None:
        uv = _resolve_flips(uv, counts, usable, poses, Rw, flip)
    view_ok = usable.any(0)
    Vp = _board_poses(n_views, counts, usable, poses, Rw, tw)
    cam_free = np.ones((n_cams, _N_CAM), bool)
    cam_free[reference, 9:] = False
    if fix_k3:
        cam_free[:, 8] = False
    views_used = np.flatnonzero(view_ok)
    vmap = -np.ones(n_views, int)
    vmap[views_used] = np.arange(views_used.size)
    opts = dict(loss=loss, f_scale=f_scale, outlier_sigma=outlier_sigma, min_outlier_px=min_outlier_px,
                max_rounds=max_rounds)
    if refine_window and windows is None:
        raise CalibrationError("refine_window needs the windows the cameras look through (windows=...)")
    # with windows, the straight-ray and fixed-window solves are only starts: one robust solve each
    start = dict(opts, max_rounds=0, tol=1e-6) if windows is not None else opts
    ba = _adjust_rejecting_outliers(_camera_vectors(Ks, dists, Rw, tw), Vp[views_used].copy(), cam_free, vmap, obj, uv,
                                    **start)
    wm = None
    if windows is not None:
        wm = _window_model(windows, n_cams, window_groups, ba["cam"], ba["view"], names)
        checks = (names, max_window_std_m, np.deg2rad(max_window_std_deg), window_noise_px)
        verdict = _window_determined(ba, wm, cam_free, vmap, obj, uv, checks) if refine_window else True
        refused = verdict is not True
        wm.refine = refine_window and not refused
        ba = _adjust_rejecting_outliers(ba["cam"], ba["view"], cam_free, vmap, obj, uv, wm=wm, **opts)
    result = _result(ba, names, image_sizes, n_views, views_used, view_ok, None, init_rms, wm)
    if refine_window:
        result.window_fit = verdict if refused else _window_fit(wm, ba["window_unc"], *checks)
    if world_view is not None:
        _to_world_view(result, world_view, view_ok)
    return result


def _checked_inputs(image_points, object_points, image_sizes, camera_names, reference, min_points):
    """Normalised arrays, camera names, points per (camera, view) and the usable (camera, view) pairs."""
    uv, obj = _normalise_inputs(image_points, object_points)
    n_cams = uv.shape[0]
    names = list(camera_names) if camera_names is not None else [f"cam{i}" for i in range(n_cams)]
    if len(names) != n_cams or len(image_sizes) != n_cams:
        raise CalibrationError(f"camera_names and image_sizes need {n_cams} entries; got {len(names)} and {len(image_sizes)}")
    if not 0 <= reference < n_cams:
        raise CalibrationError(f"reference must be a camera index in [0, {n_cams}); got {reference}")
    counts = np.isfinite(uv).all(-1).sum(-1)  # (n_cams, n_views)
    usable = counts >= min_points
    uv = np.where(usable[:, :, None, None], uv, np.nan)
    return uv, obj, names, counts, usable


def _adjust_rejecting_outliers(x_cam, x_view, cam_free, vmap, obj, uv, *, loss, f_scale, outlier_sigma,
                               min_outlier_px, max_rounds, wm=None, tol=1e-12) -> dict:
    """Step 3: bundle adjustment (robust loss first), then rounds of outlier rejection and re-solve.

    ``wm``: the windows (:class:`_WindowModel`), updated in place with the refined parameters."""
    ci_all, vi_all, pi_all = np.nonzero(np.isfinite(uv).all(-1))
    inlier = np.ones(ci_all.size, bool)
    converged, message = False, ""
    n_out_prev = -1
    for rnd in range(max_rounds + 1):
        ci, vi, pi = ci_all[inlier], vi_all[inlier], pi_all[inlier]
        sol = _bundle_adjust(x_cam, x_view, cam_free, ci, vmap[vi], obj[vi, pi], uv[ci, vi, pi], loss if rnd == 0 else "linear",
                             f_scale, wm, tol)
        x_cam, x_view = sol["cam"], sol["view"]
        if wm is not None:
            wm.x = sol["win"]
        converged, message = sol["success"], sol["message"]
        cam_std, window_unc = sol["cam_std"], sol["window_unc"]
        res = _project(x_cam, x_view, ci_all, vmap[vi_all], obj[vi_all, pi_all],
                       None if wm is None else wm.windows(wm.x)) - uv[ci_all, vi_all, pi_all]
        res = np.nan_to_num(res, nan=_NAN_RESIDUAL_PX)
        norm = np.linalg.norm(res, axis=-1)
        s = 1.4826 * np.median(norm[inlier])
        thr = max(min_outlier_px, outlier_sigma * s)
        new_inlier = norm <= thr
        n_out = int((~new_inlier).sum())
        log.info("BA round %d: RMS %.4f px, threshold %.3f px, %d outliers", rnd, np.sqrt(np.mean(norm[inlier] ** 2)), thr, n_out)
        if rnd > 0 and np.array_equal(new_inlier, inlier):
            break
        if rnd == max_rounds:
            break
        inlier = new_inlier
        if n_out == n_out_prev and rnd > 0:
            break
        n_out_prev = n_out
    return {"cam": x_cam, "view": x_view, "inlier": inlier, "res": res, "converged": converged, "message": message,
            "cam_std": cam_std, "ci": ci_all, "vi": vi_all, "pi": pi_all, "window_unc": window_unc}


def _result(ba, names, image_sizes, n_views, views_used, view_ok, world_view, init_rms, wm=None) -> CalibrationResult:
    """Cameras, board poses (optionally in the board frame of ``world_view``) and the RMS figures."""
    x_cam, x_view, inlier, res = ba["cam"], ba["view"], ba["inlier"], ba["res"]
    ci_all, vi_all, pi_all = ba["ci"], ba["vi"], ba["pi"]
    n_cams = len(names)
    cams = []
    wins = wm.windows(wm.x) if wm is not None else [None] * n_cams
    for c in range(n_cams):
        p = x_cam[c]
        K = np.array([[p[0], 0, p[2]], [0, p[1], p[3]], [0, 0, 1.0]])
        cams.append(Camera(names[c], K, p[4:9], p[9:12], p[12:15], tuple(image_sizes[c]), window=wins[c]))
    brv = np.full((n_views, 3), np.nan)
    btv = np.full((n_views, 3), np.nan)
    brv[views_used] = x_view[:, :3]
    btv[views_used] = x_view[:, 3:]
    if world_view is not None:
        if not (0 <= world_view < n_views and view_ok[world_view]):
            raise CalibrationError(f"world_view must index a view seen by some camera; got {world_view}")
        cams, brv, btv = _to_board_frame(cams, brv, btv, world_view)
    sq = np.sum(res**2, -1)
    rms = np.array([np.sqrt(np.mean(sq[inlier & (ci_all == c)])) if (inlier & (ci_all == c)).any() else np.nan for c in range(n_cams)])
    rpv = np.full((n_cams, n_views), np.nan)
    for c in range(n_cams):
        for v in range(n_views):
            m = inlier & (ci_all == c) & (vi_all == v)
            if m.any():
                rpv[c, v] = np.sqrt(np.mean(sq[m]))
    return CalibrationResult(
        cameras=cams,
        board_rvecs=brv,
        board_tvecs=btv,
        rms=rms,
        rms_per_view=rpv,
        rms_total=float(np.sqrt(np.mean(sq[inlier]))),
        n_observations=int(inlier.sum()),
        n_outliers=int((~inlier).sum()),
        outliers=np.stack([ci_all[~inlier], vi_all[~inlier], pi_all[~inlier]], -1),
        converged=bool(ba["converged"]),
        message=str(ba["message"]),
        initial_rms=np.array(init_rms),
        parameter_std=ba["cam_std"],
    )


def _window_to_frame(win: Window | None, Rk: np.ndarray, tk: np.ndarray) -> Window | None:
    """``win`` in the frame ``X' = Rk^T (X - tk)``: normal ``Rk^T n``, offset ``o - n . tk``."""
    if win is None:
        return None
    return Window(Rk.T @ win.normal, win.offset - win.normal @ tk, win.thicknesses, win.indices, win.n_bath, win.n_air)


def _to_world_view(result: CalibrationResult, k: int, view_ok: np.ndarray) -> None:
    """Re-express ``result`` (cameras, board poses, refined windows) in the board frame of view ``k``, in place."""
    if not (0 <= k < len(view_ok) and view_ok[k]):
        raise CalibrationError(f"world_view must index a view seen by some camera; got {k}")
    Rk, tk = rotation_matrix(result.board_rvecs[k]), result.board_tvecs[k].copy()
    result.cameras, result.board_rvecs, result.board_tvecs = _to_board_frame(result.cameras, result.board_rvecs,
                                                                             result.board_tvecs, k)
    if result.window_fit is not None:
        f = result.window_fit
        f.nominal = [_window_to_frame(w, Rk, tk) for w in f.nominal]
        f.refined = [_window_to_frame(w, Rk, tk) for w in f.refined]


def _window_determined(ba: dict, wm: _WindowModel, cam_free, vmap, obj, uv, checks) -> "bool | WindowFit":
    """True when the board views determine the windows (1-sigma at the noise floor from the Jacobian at the start,
    before anything moves); else the refusal (a :class:`WindowFit` saying ILL-POSED, planes as given)."""
    inlier = ba["inlier"]
    ci, vi, pi = ba["ci"][inlier], ba["vi"][inlier], ba["pi"][inlier]
    wm.refine = True
    probe = _bundle_adjust(ba["cam"], ba["view"], cam_free, ci, vmap[vi], obj[vi, pi], uv[ci, vi, pi], "linear", 1.0,
                           wm, max_nfev=1)
    wm.x = np.zeros_like(wm.x)
    unc = probe["window_unc"]
    unc = None if unc is None else dict(unc, s2=0.0)  # the noise floor only: the start's residuals are not noise
    fit = _window_fit(wm, unc, *checks, refused=True)
    return True if fit.well_posed else fit


def _window_fit(wm: _WindowModel, unc: dict | None, names: list, max_std_m: float, max_std_rad: float,
                noise_px: float, refused: bool = False) -> WindowFit:
    """The refined planes with their 1-sigma (at the residual RMS, at least ``noise_px``), correlations and the
    ILL-POSED verdict; ``refused``: the planes were kept at their nominal place (say so)."""
    n_planes = len(wm.nominal)
    if unc is None:
        unc = {"inv": np.full((3 * n_planes,) * 2, np.inf), "s2": 0.0, "max_corr": np.ones(3 * n_planes),
               "with": [""] * (3 * n_planes), "cond": np.inf}
    var = np.diag(unc["inv"]).reshape(n_planes, 3) * max(unc["s2"], noise_px**2)
    off_std, nrm_std = np.sqrt(var[:, 0]), np.sqrt(var[:, 1] + var[:, 2])
    corr = np.asarray(unc["max_corr"]).reshape(n_planes, 3)
    with_ = [unc["with"][3 * g: 3 * g + 3] for g in range(n_planes)]
    groups = [[names[c] for c in np.flatnonzero(wm.cam_group == g)] for g in range(n_planes)]
    refined = [wm.plane(g, wm.x[g]) for g in range(n_planes)]
    bad = [g for g in range(n_planes) if not (off_std[g] <= max_std_m and nrm_std[g] <= max_std_rad)]
    lines = [f"window {g} ({', '.join(groups[g])}): plane distance {1e3 * refined[g].offset:.3f} mm "
             f"+- {1e3 * off_std[g]:.3g} mm (moved {1e3 * (refined[g].offset - wm.nominal[g].offset):+.3f} mm), "
             f"normal +- {np.rad2deg(nrm_std[g]):.3g} deg (turned "
             f"{np.rad2deg(np.arccos(np.clip(refined[g].normal @ wm.nominal[g].normal, -1, 1))):.3f} deg); "
             f"strongest correlation {corr[g].max():.4f} ({with_[g][int(np.argmax(corr[g]))]})" for g in range(n_planes)]
    msg = "; ".join(lines) + f"; condition number {unc['cond']:.3g}"
    if bad:
        msg += (f": ILL-POSED (window {bad} not determined to {1e3 * max_std_m:g} mm / {np.rad2deg(max_std_rad):g} deg; "
                "show the board at several depths and tilts through the window, or keep the window fixed)")
        if refused:
            msg += "; refused: the windows were kept where given and not refined"
    (log.warning if bad else log.info)(msg)
    return WindowFit(groups, list(wm.nominal), refined, off_std, nrm_std, corr, with_, float(unc["cond"]), not bad, msg)


def _to_board_frame(cams, brv, btv, k):
    Rk = rotation_matrix(brv[k])
    tk = btv[k]
    out = []
    for c in cams:
        R = c.R @ Rk
        t = c.R @ tk + c.tvec
        out.append(Camera(c.name, c.K, c.dist, cv2.Rodrigues(R)[0].ravel(), t, c.image_size, dict(c.meta),
                          window=_window_to_frame(c.window, Rk, tk)))
    nrv = np.full_like(brv, np.nan)
    ntv = np.full_like(btv, np.nan)
    ok = np.isfinite(brv).all(-1)
    for v in np.flatnonzero(ok):
        R = Rk.T @ rotation_matrix(brv[v])
        nrv[v] = cv2.Rodrigues(R)[0].ravel()
        ntv[v] = Rk.T @ (btv[v] - tk)
    return out, nrv, ntv


def reprojection_errors(cameras: list[Camera], board_rvecs, board_tvecs, image_points, object_points) -> np.ndarray:
    """Residuals ``(n_cams, n_views, n_points, 2)`` (px) of observations against a calibration; NaN where unobserved."""
    uv, obj = _normalise_inputs(image_points, object_points)
    out = np.full(uv.shape, np.nan)
    for c, cam in enumerate(cameras):
        for v in range(uv.shape[1]):
            if not np.isfinite(board_rvecs[v]).all():
                continue
            Xw = obj[v] @ rotation_matrix(board_rvecs[v]).T + board_tvecs[v]
            out[c, v] = cam.project(Xw) - uv[c, v]
    return out


def detections_to_arrays(detections: dict[str, list[BoardDetection]], spec: BoardSpec) -> tuple[list[str], np.ndarray, np.ndarray]:
    """``{camera: [BoardDetection per view]}`` -> names, image_points ``(n_cams, n_views, n_points, 2)``, object points."""
    names = list(detections)
    n_views = {len(v) for v in detections.values()}
    if len(n_views) != 1:
        raise CalibrationError(f"every camera needs the same number of views; got {dict((k, len(v)) for k, v in detections.items())}")
    nv = n_views.pop()
    obj = spec.object_points()
    uv = np.full((len(names), nv, len(obj), 2), np.nan)
    for c, name in enumerate(names):
        for v, det in enumerate(detections[name]):
            if len(det):
                uv[c, v, det.ids] = det.points
    return names, uv, obj


def calibrate_from_detections(
    detections: dict[str, list[BoardDetection]], spec: BoardSpec, image_sizes: dict[str, tuple[int, int]], **kwargs
) -> CalibrationResult:
    """:func:`calibrate_cameras` on board detections ``{camera: [BoardDetection per view]}``.

    Point-order flips are resolved by default for chessboards and symmetric circle grids.
    """
    names, uv, obj = detections_to_arrays(detections, spec)
    kwargs.setdefault("resolve_flips", spec.kind in ("chessboard", "circles"))
    return calibrate_cameras(uv, obj, [image_sizes[n] for n in names], names, **kwargs)
