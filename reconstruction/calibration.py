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
from dataclasses import dataclass, field

import cv2
import numpy as np
import scipy.sparse as sp
from scipy.optimize import least_squares

from .cameras import Camera, rotation_matrix
from .refraction import Window, refracted_directions
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

_N_CAM = 15  # fx fy cx cy k1 k2 p1 p2 k3 | rvec | tvec
_N_VIEW = 6


class CalibrationError(RuntimeError):
    """Calibration cannot proceed (too few views, disconnected cameras, ...)."""


@dataclass
class CalibrationResult:
    """Outcome of :func:`calibrate_cameras`.

    Attributes
    ----------
    cameras : list of Camera
        Calibrated cameras (world -> camera poses in the chosen world frame).
    board_rvecs, board_tvecs : ndarray, shape (n_views, 3)
        Board -> world poses (m); NaN for views no camera used.
    rms : ndarray, shape (n_cams,)
        RMS reprojection error per camera over inlier observations, px
        (``sqrt(mean |residual|^2)``, as OpenCV reports it).
    rms_per_view : ndarray, shape (n_cams, n_views)
        Same per camera and view, NaN where not observed.
    rms_total : float
        Over all inlier observations, px.
    n_observations : int
        Inlier point observations used in the final solve.
    n_outliers : int
        Observations rejected.
    outliers : ndarray, shape (n_outliers, 3), int
        (camera, view, point) of each rejected observation.
    converged : bool
    message : str
    initial_rms : ndarray, shape (n_cams,)
        Per-camera RMS of the independent ``cv2.calibrateCamera`` initialisations, px.
    parameter_std : ndarray, shape (n_cams, 15)
        Standard deviations of (fx, fy, cx, cy [px], k1, k2, p1, p2, k3, rvec [rad], tvec [m]) of
        each camera from the final solve's covariance ``s^2 (J^T J)^-1`` (NaN for fixed parameters;
        it assumes independent pixel noise, so it is a lower bound when residuals are correlated).
        Pose uncertainties refer to the adjustment gauge (the reference camera fixed).
    window_fit : WindowFit or None
        The refined windows with their uncertainties (``refine_window=True``); the cameras carry their
        windows (``Camera.window``) whenever ``windows`` was given.
    """

    cameras: list[Camera]
    board_rvecs: np.ndarray
    board_tvecs: np.ndarray
    rms: np.ndarray
    rms_per_view: np.ndarray
    rms_total: float
    n_observations: int
    n_outliers: int
    outliers: np.ndarray
    converged: bool
    message: str
    initial_rms: np.ndarray = field(default_factory=lambda: np.zeros(0))
    parameter_std: np.ndarray = field(default_factory=lambda: np.zeros((0, _N_CAM)))
    window_fit: "WindowFit | None" = None

    def summary(self) -> list[dict]:
        """One row per camera: name, views used, RMS (px), fx, fy, cx, cy and their standard deviations (px)."""
        rows = []
        for i, c in enumerate(self.cameras):
            rows.append(
                dict(
                    camera=c.name,
                    views=int(np.isfinite(self.rms_per_view[i]).sum()),
                    rms_px=float(self.rms[i]),
                    fx=float(c.K[0, 0]),
                    fy=float(c.K[1, 1]),
                    cx=float(c.K[0, 2]),
                    cy=float(c.K[1, 2]),
                    **{f"{k}_std": float(self.parameter_std[i, j]) if self.parameter_std.shape[0] > i else float("nan")
                       for j, k in enumerate(("fx", "fy", "cx", "cy"))},
                )
            )
        return rows


@dataclass
class WindowFit:
    """The windows refined by :func:`calibrate_cameras` (``refine_window=True``), one row per plane.

    Attributes
    ----------
    cameras : list of list of str
        The cameras looking through each plane (one tank wall shared, or one window per camera).
    nominal, refined : list of Window
        The window of each plane before and after the adjustment (world frame of the result).
    offset_std : ndarray, shape (n_planes,)
        1-sigma of the plane's position along its normal where the cameras look through it (the pivot
        of its tilts), m.
    normal_std : ndarray, shape (n_planes,)
        1-sigma of the normal's direction (root-sum-square of its two tilt angles), rad.
    max_correlation : ndarray, shape (n_planes, 3)
        Strongest correlation of each window unknown (offset, tilt a, tilt b) with any other unknown.
    correlated_with : list of list of str
        That other unknown, by name (``camera 1 tz``, ``view 4 tx``, ...).
    condition : float
        Condition number of the adjustment's scaled normal matrix (1 = orthogonal unknowns).
    well_posed : bool
        False when a plane's offset or normal is not determined to the tolerances (``max_window_std_m``,
        ``max_window_std_deg`` of :func:`calibrate_cameras`); then ``message`` says ILL-POSED.
    message : str
    """

    cameras: list
    nominal: list
    refined: list
    offset_std: np.ndarray
    normal_std: np.ndarray
    max_correlation: np.ndarray
    correlated_with: list
    condition: float
    well_posed: bool
    message: str

    def summary(self) -> list[dict]:
        """One row per plane, in the units people read: mm, deg."""
        rows = []
        for g, (a, b) in enumerate(zip(self.nominal, self.refined)):
            rows.append(dict(cameras=list(self.cameras[g]), plane_distance_mm=1e3 * b.offset,
                             plane_distance_std_mm=1e3 * float(self.offset_std[g]),
                             plane_shift_mm=1e3 * (b.offset - a.offset), normal=[float(v) for v in b.normal],
                             normal_std_deg=float(np.rad2deg(self.normal_std[g])),
                             normal_change_deg=float(np.rad2deg(np.arccos(np.clip(a.normal @ b.normal, -1, 1)))),
                             max_correlation=float(np.max(self.max_correlation[g])),
                             correlated_with=self.correlated_with[g][int(np.argmax(self.max_correlation[g]))]))
        return rows


def _tilt_basis(normal: np.ndarray) -> np.ndarray:
    """Two unit vectors ``(2, 3)`` perpendicular to ``normal``: the axes of a window's two tilt unknowns."""
    a = np.cross(normal, [0.0, 0.0, 1.0])
    if np.linalg.norm(a) < 1e-6:
        a = np.cross(normal, [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    return np.stack([a, np.cross(normal, a)])


@dataclass
class _WindowModel:
    """The windows of the adjustment: planes (each shared by a group of cameras) moved by ``x``.

    Plane ``g`` has unknowns ``x[g] = (delta [m], a, b [rad])``: normal ``n0 + a e1 + b e2`` (normalised),
    through the pivot ``p0 + delta n`` (``p0`` on the nominal plane where the cameras look through it,
    so that tilting the plane does not move it there: offset and tilt are nearly uncorrelated).
    """

    nominal: list  # Window per plane
    cam_group: np.ndarray  # (n_cams,) plane of each camera, -1 = none
    pivots: np.ndarray  # (n_planes, 3), m
    refine: bool = False
    x: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    def plane(self, g: int, xg: np.ndarray) -> Window:
        w0 = self.nominal[g]
        e = _tilt_basis(w0.normal)
        n = w0.normal + xg[1] * e[0] + xg[2] * e[1]
        n = n / np.linalg.norm(n)
        offset = float(n @ (self.pivots[g] + xg[0] * w0.normal))
        return Window(n, offset, w0.thicknesses, w0.indices, w0.n_bath, w0.n_air)

    def windows(self, x: np.ndarray) -> list:
        """Per camera its Window (or None) for unknowns ``x (n_planes, 3)``."""
        planes = [self.plane(g, x[g]) for g in range(len(self.nominal))]
        return [planes[g] if g >= 0 else None for g in self.cam_group]


def _window_model(windows, n_cams: int, groups, x_cam: np.ndarray, x_view: np.ndarray, names: list) -> _WindowModel:
    """Planes and their cameras from ``windows`` (one Window for all cameras, or one per camera, None = none):
    cameras with equal windows share a plane unless ``groups`` (one label per camera) says otherwise."""
    if isinstance(windows, Window):
        windows = [windows] * n_cams
    windows = list(windows)
    if len(windows) != n_cams or not all(w is None or isinstance(w, Window) for w in windows):
        raise CalibrationError(f"windows must be a Window or one Window (or None) per camera ({n_cams}); got {windows!r}")
    if groups is None:
        keys = [None if w is None else repr(sorted(w.to_dict().items())) for w in windows]
    else:
        if len(groups) != n_cams:
            raise CalibrationError(f"window_groups needs one label per camera ({n_cams}); got {len(groups)}")
        keys = [None if w is None else groups[c] for c, w in enumerate(windows)]
    labels = list(dict.fromkeys(k for k in keys if k is not None))
    cam_group = np.array([-1 if k is None else labels.index(k) for k in keys])
    nominal = [windows[int(np.flatnonzero(cam_group == g)[0])] for g in range(len(labels))]
    for g, w0 in enumerate(nominal):
        other = [names[c] for c in np.flatnonzero(cam_group == g) if windows[c].to_dict() != w0.to_dict()]
        if other:
            raise CalibrationError(f"window_groups: cameras {other} share a plane with {names[int(np.flatnonzero(cam_group == g)[0])]!r} "
                                   "but were given a different window")
    pivots = np.array([_pivot(w, x_cam[cam_group == g], x_view) for g, w in enumerate(nominal)])
    return _WindowModel(nominal, cam_group, pivots, x=np.zeros((len(nominal), len(_WIN_SLOTS))))


def _pivot(win: Window, x_cam: np.ndarray, x_view: np.ndarray) -> np.ndarray:
    """Where the lines from the cameras' centres to the boards' mean position cross the window's first plane."""
    target = np.nanmean(x_view[:, 3:6], axis=0)
    Rc = rotation_matrix(x_cam[:, 9:12])
    centres = -np.einsum("nji,nj->ni", Rc, x_cam[:, 12:15])
    d = target - centres
    t = (win.offset - centres @ win.normal) / np.where(np.abs(d @ win.normal) > 1e-12, d @ win.normal, 1e-12)
    p = (centres + t[:, None] * d).mean(axis=0)
    return p + (win.offset - p @ win.normal) * win.normal


# ---------------------------------------------------------------------------------------------
# projection with per-observation parameters (vectorised)


def _project(cam_params: np.ndarray, view_params: np.ndarray, ci: np.ndarray, vi: np.ndarray, X: np.ndarray,
             windows: list | None = None) -> np.ndarray:
    """Pixels ``(n_obs, 2)`` of board points ``X (n_obs, 3)`` for parameter arrays.

    ``windows``: per camera a :class:`~reconstruction.refraction.Window` (world frame) or None; the
    rays of a camera with a window are refracted exactly (points not beyond it give NaN).
    """
    return _pixels(cam_params, ci, _camera_rays(cam_params, view_params, ci, vi, X, windows))


def _camera_rays(cam_params, view_params, ci, vi, X, windows=None) -> np.ndarray:
    """Directions ``(n_obs, 3)`` (camera frame, any length) of the rays leaving the cameras towards ``X``."""
    Rv = rotation_matrix(view_params[:, :3])
    Rc = rotation_matrix(cam_params[:, 9:12])
    Xw = np.einsum("nij,nj->ni", Rv[vi], X) + view_params[vi, 3:6]
    Xc = np.einsum("nij,nj->ni", Rc[ci], Xw) + cam_params[ci, 12:15]
    if windows is not None:
        for c, win in enumerate(windows):
            m = ci == c
            if win is None or not m.any():
                continue
            centre = -Rc[c].T @ cam_params[c, 12:15]
            d, beyond = refracted_directions(win, Rc[c], centre, Xw[m])
            Xc[m] = np.where(beyond[:, None], d, np.nan)
    return Xc


def _pixels(cam_params: np.ndarray, ci: np.ndarray, Xc: np.ndarray) -> np.ndarray:
    """Pixels ``(n_obs, 2)`` of camera-frame ray directions ``Xc`` through each camera's distortion and K."""
    p = cam_params[ci]
    x = Xc[:, 0] / Xc[:, 2]
    y = Xc[:, 1] / Xc[:, 2]
    r2 = x * x + y * y
    k1, k2, p1, p2, k3 = p[:, 4], p[:, 5], p[:, 6], p[:, 7], p[:, 8]
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([p[:, 0] * xd + p[:, 2], p[:, 1] * yd + p[:, 3]], -1)


def _camera_params(cam: Camera) -> np.ndarray:
    K = cam.K
    return np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], cam.dist, cam.rvec, cam.tvec])


def _compose_inverse_pose(R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return R.T, -R.T @ t


def _mean_rotation(Rs: np.ndarray) -> np.ndarray:
    """Chordal L2 mean of rotation matrices ``(n, 3, 3)``."""
    U, _, Vt = np.linalg.svd(np.sum(Rs, axis=0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


# ---------------------------------------------------------------------------------------------


def _normalise_inputs(image_points, object_points):
    uv = np.asarray(image_points, float)
    if uv.ndim != 4 or uv.shape[-1] != 2:
        raise CalibrationError(f"image_points must have shape (n_cams, n_views, n_points, 2); got {uv.shape}")
    n_cams, n_views, n_points, _ = uv.shape
    obj = np.asarray(object_points, float)
    if obj.shape == (n_points, 3):
        obj = np.broadcast_to(obj, (n_views, n_points, 3))
    if obj.shape != (n_views, n_points, 3):
        raise CalibrationError(
            f"object_points must have shape (n_points, 3) or (n_views, n_points, 3) = ({n_views}, {n_points}, 3); got {obj.shape}"
        )
    return uv, obj


def _init_camera(uv_c, obj, size, min_points, name):
    """cv2.calibrateCamera on the views of one camera. Returns (K, dist, {view: (R, t)}, rms)."""
    views = [v for v in range(uv_c.shape[0]) if np.isfinite(uv_c[v]).all(-1).sum() >= min_points]
    if len(views) < 2:
        raise CalibrationError(f"camera {name!r}: board seen in {len(views)} views; need at least 2 (better >= 5)")
    op, ip = [], []
    planar = True
    for v in views:
        ok = np.isfinite(uv_c[v]).all(-1)
        op.append(obj[v, ok].astype(np.float32))
        ip.append(uv_c[v, ok].astype(np.float32).reshape(-1, 1, 2))
        planar = planar and np.ptp(obj[v, ok, 2]) == 0
    w, h = size
    K0 = np.array([[max(w, h), 0, (w - 1) / 2], [0, max(w, h), (h - 1) / 2], [0, 0, 1.0]])
    flags = 0 if planar else cv2.CALIB_USE_INTRINSIC_GUESS
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(op, ip, (w, h), K0, np.zeros(5), flags=flags, criteria=crit)
    poses = {v: (cv2.Rodrigues(r)[0], np.asarray(t, float).ravel()) for v, r, t in zip(views, rvecs, tvecs)}
    return K, np.asarray(dist, float).ravel()[:5], poses, float(rms)


def _angle(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """Angle (rad) of the rotation between two rotation matrices."""
    return float(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1.0, 1.0)))


def _reversal_symmetry(obj: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(R, t) with ``R @ obj[k] + t = obj[n-1-k]`` if the target is symmetric under reversal, else None."""
    a, b = obj, obj[::-1]
    ca, cb = a.mean(0), b.mean(0)
    U, _, Vt = np.linalg.svd((a - ca).T @ (b - cb))
    R = Vt.T @ np.diag([1, 1, np.sign(np.linalg.det(Vt.T @ U.T))]) @ U.T
    t = cb - R @ ca
    scale = max(np.ptp(a, axis=0).max(), 1e-300)
    return (R, t) if np.abs(a @ R.T + t - b).max() < 1e-6 * scale else None


def _relative_pose(pi: dict, pj: dict, views: np.ndarray, flip) -> tuple[np.ndarray, np.ndarray]:
    """Camera i -> camera j pose from shared views, robust to bad views (and to reversed targets if ``flip``).

    The candidate (per view, per order hypothesis) agreeing with most views within 2 deg wins;
    the agreeing candidates are averaged.
    """
    cands = []
    for v in views:
        Ri, ti = pi[v]
        hyps = [pj[v]] if flip is None else [pj[v], (pj[v][0] @ flip[0], pj[v][0] @ flip[1] + pj[v][1])]
        for Rj, tj in hyps:
            R = Rj @ Ri.T
            cands.append((v, R, tj - R @ ti))
    tol = np.deg2rad(2.0)
    best = max(range(len(cands)), key=lambda k: len({c[0] for c in cands if _angle(c[1], cands[k][1]) < tol}))
    chosen = {}
    for v, R, t in cands:
        d = _angle(R, cands[best][1])
        if d < tol and (v not in chosen or d < chosen[v][0]):
            chosen[v] = (d, R, t)
    Rs = np.array([c[1] for c in chosen.values()])
    ts = np.array([c[2] for c in chosen.values()])
    return _mean_rotation(Rs), np.median(ts, axis=0)


def _spanning_tree(n_cams: int, weights: np.ndarray, root: int) -> list[tuple[int, int]]:
    """Maximum spanning tree edges (parent, child) by Prim's algorithm from ``root``."""
    inside = {root}
    edges = []
    while len(inside) < n_cams:
        best = None
        for i in inside:
            for j in range(n_cams):
                if j not in inside and weights[i, j] > 0 and (best is None or weights[i, j] > best[0]):
                    best = (weights[i, j], i, j)
        if best is None:
            break
        edges.append((best[1], best[2]))
        inside.add(best[2])
    return edges


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


def _initialise_cameras(uv, obj, image_sizes, min_points, names, fix_k3):
    """Step 1: each camera on its own (OpenCV): K, distortion, board poses per view, RMS."""
    Ks, dists, poses, init_rms = [], [], [], []
    for c in range(uv.shape[0]):
        K, d, p, r = _init_camera(uv[c], obj, image_sizes[c], min_points, names[c])
        if fix_k3:
            d[4] = 0.0
        Ks.append(K)
        dists.append(d)
        poses.append(p)
        init_rms.append(r)
        log.info("camera %s: initial RMS %.3f px over %d views", names[c], r, len(p))
    return Ks, dists, poses, init_rms


def _pose_graph(obj, names, counts, usable, poses, reference, resolve_flips):
    """Step 2: every camera's pose in the reference camera's frame, chained along the spanning tree of shared
    views; and the target's reversal symmetry when ``resolve_flips``."""
    n_cams = len(names)
    shared = np.zeros((n_cams, n_cams))
    for i in range(n_cams):
        for j in range(n_cams):
            if i != j:
                both = usable[i] & usable[j]
                shared[i, j] = np.minimum(counts[i], counts[j])[both].sum()
    edges = _spanning_tree(n_cams, shared, reference)
    flip = _reversal_symmetry(obj[np.flatnonzero(usable.any(0))[0]]) if resolve_flips and usable.any() else None
    if resolve_flips and flip is None:
        log.warning("resolve_flips: the target is not symmetric under reversal of its point order; nothing to resolve")
    Rw = {reference: np.eye(3)}
    tw = {reference: np.zeros(3)}
    for i, j in edges:
        vs = np.flatnonzero(usable[i] & usable[j])
        R, t = _relative_pose(poses[i], poses[j], vs, flip)
        Rw[j] = R @ Rw[i]
        tw[j] = R @ tw[i] + t
    missing = [names[c] for c in range(n_cams) if c not in Rw]
    if missing:
        raise CalibrationError(f"cameras {missing} share no board view with the others (directly or through other cameras)")
    return Rw, tw, flip


def _resolve_flips(uv, counts, usable, poses, Rw, flip):
    """Reverse the point order of the camera views that disagree with the camera seeing most of the view
    (updates ``poses`` in place; returns the re-ordered copy of ``uv``)."""
    uv = uv.copy()
    n_flipped = 0
    for v in np.flatnonzero(usable.sum(0) > 1):
        a = int(np.argmax(np.where(usable[:, v], counts[:, v], -1)))
        Ra = Rw[a].T @ poses[a][v][0]
        for c in np.flatnonzero(usable[:, v]):
            if c == a:
                continue
            Rc0 = Rw[c].T @ poses[c][v][0]
            Rc1 = Rc0 @ flip[0]
            if _angle(Rc1, Ra) < _angle(Rc0, Ra):
                Rcv, tcv = poses[c][v]
                poses[c][v] = (Rcv @ flip[0], Rcv @ flip[1] + tcv)
                uv[c, v] = uv[c, v, ::-1]
                n_flipped += 1
    if n_flipped:
        log.info("resolve_flips: reversed the point order of %d camera views to match the other cameras", n_flipped)
    return uv


def _board_poses(n_views, counts, usable, poses, Rw, tw) -> np.ndarray:
    """Board poses ``(n_views, 6)`` (Rodrigues, t) in the world, from the camera seeing most points; NaN = unseen."""
    Vp = np.full((n_views, 6), np.nan)
    for v in np.flatnonzero(usable.any(0)):
        c = int(np.argmax(np.where(usable[:, v], counts[:, v], -1)))
        Rcv, tcv = poses[c][v]
        R = Rw[c].T @ Rcv
        t = Rw[c].T @ (tcv - tw[c])
        Vp[v] = np.concatenate([cv2.Rodrigues(R)[0].ravel(), t])
    return Vp


def _camera_vectors(Ks, dists, Rw, tw) -> np.ndarray:
    """The adjustment's camera parameters ``(n_cams, _N_CAM)``: fx fy cx cy, k1 k2 p1 p2 k3, rvec, tvec."""
    Cp = np.zeros((len(Ks), _N_CAM))
    for c, K in enumerate(Ks):
        Cp[c] = np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], dists[c], cv2.Rodrigues(Rw[c])[0].ravel(), tw[c]])
    return Cp


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


_NAN_RESIDUAL_PX = 1e3  # residual of a point the model cannot image (not beyond its window)
_CAM_SLOTS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "rx", "ry", "rz", "tx", "ty", "tz")
_VIEW_SLOTS = ("rx", "ry", "rz", "tx", "ty", "tz")
_WIN_SLOTS = ("offset", "tilt_a", "tilt_b")


def _bundle_adjust(x_cam, x_view, cam_free, ci, vi, X, uv, loss, f_scale, wm=None, tol=1e-12, max_nfev=200):
    """One least-squares solve; Jacobian by grouped central differences (one group per parameter slot).

    ``wm`` (:class:`_WindowModel`, optional): the cameras' windows; their parameters are unknowns when
    ``wm.refine``. ``tol``: xtol and ftol of the solver (a start needs less than the final solve).
    """
    n_cams, n_views = x_cam.shape[0], x_view.shape[0]
    cam_idx = np.flatnonzero(cam_free.ravel())
    n_cf, n_vf = cam_idx.size, n_views * _N_VIEW
    n_wf = wm.x.size if wm is not None and wm.refine else 0
    n_obs = ci.size

    def unpack(x):
        cam = x_cam.copy().ravel()
        cam[cam_idx] = x[:n_cf]
        xw = None if wm is None else (x[n_cf + n_vf:].reshape(wm.x.shape) if n_wf else wm.x)
        return cam.reshape(n_cams, _N_CAM), x[n_cf:n_cf + n_vf].reshape(n_views, _N_VIEW), xw

    def rays_of(cam, view, xw):
        return _camera_rays(cam, view, ci, vi, X, None if wm is None else wm.windows(xw))

    def proj(cam, view, xw, rays=None):
        return _pixels(cam, ci, rays_of(cam, view, xw) if rays is None else rays)

    def fun(x):
        return np.nan_to_num(proj(*unpack(x)) - uv, nan=_NAN_RESIDUAL_PX).ravel()

    col_cam = -np.ones((n_cams, _N_CAM), int)
    col_cam.ravel()[cam_idx] = np.arange(n_cf)
    col_view = n_cf + np.arange(n_vf).reshape(n_views, _N_VIEW)
    col_win = n_cf + n_vf + np.arange(n_wf).reshape(-1, len(_WIN_SLOTS)) if n_wf else None
    group = wm.cam_group[ci] if wm is not None else None

    def jac(x):
        cam, view, xw = unpack(x)
        blocks = [_jac_camera_block(proj, rays_of, cam, view, xw, col_cam, ci),
                  _jac_view_block(proj, cam, view, xw, col_view, vi)]
        if n_wf:
            blocks.append(_jac_window_block(proj, cam, view, xw, col_win, group))
        data, rr, cc = (np.concatenate(z) for z in zip(*blocks))
        J = sp.csr_matrix((data, (rr, cc)), shape=(2 * n_obs, x.size))
        return J.toarray() if dense else J

    x0 = np.concatenate([x_cam.ravel()[cam_idx], x_view.ravel(), wm.x.ravel() if n_wf else []])
    dense = x0.size * 2 * n_obs <= 3e7
    sol = least_squares(fun, x0, jac=jac, method="trf", loss=loss, f_scale=f_scale, x_scale="jac",
                        tr_solver="exact" if dense else "lsmr", xtol=tol, ftol=tol, gtol=1e-10, max_nfev=max_nfev)
    cam, view, xw = unpack(sol.x)
    names = _column_names(cam_idx, n_views, n_wf)
    unc = _uncertainties(jac(sol.x), fun(sol.x), cam_idx, (n_cams, _N_CAM), 2 * n_obs - x0.size, names, n_cf + n_vf, n_wf)
    return dict(cam=cam, view=view, win=None if xw is None else np.array(xw), success=sol.status > 0,
                message=sol.message, cost=sol.cost, cam_std=unc["cam_std"], window_unc=unc.get("window"))


def _fd_step(values: np.ndarray, floor: float) -> np.ndarray:
    return 1e-6 * np.maximum(np.abs(values), floor)


def _jac_camera_block(proj, rays_of, cam, view, xw, col_cam, ci):
    """(data, rows, cols) of the camera columns by central differences, one slot of all cameras at a time."""
    rows = np.arange(2 * ci.size)
    data, rr, cc = [], [], []
    rays = None
    for slot in range(_N_CAM):
        cols = col_cam[:, slot]
        if (cols < 0).all():
            continue
        h = _fd_step(cam[:, slot], 1e-2 if slot >= 12 else 1.0)
        cp, cm = cam.copy(), cam.copy()
        cp[:, slot] += h
        cm[:, slot] -= h
        if slot < 9:  # intrinsics do not move the rays: trace them once
            rays = rays_of(cam, view, xw) if rays is None else rays
            d = np.nan_to_num((proj(cp, view, xw, rays) - proj(cm, view, xw, rays)) / (2 * h[ci])[:, None])
        else:
            d = np.nan_to_num((proj(cp, view, xw) - proj(cm, view, xw)) / (2 * h[ci])[:, None])
        c_of_obs = cols[ci]
        ok = np.repeat(c_of_obs >= 0, 2)
        data.append(d.ravel()[ok])
        rr.append(rows[ok])
        cc.append(np.repeat(c_of_obs, 2)[ok])
    return np.concatenate(data), np.concatenate(rr), np.concatenate(cc)


def _jac_view_block(proj, cam, view, xw, col_view, vi):
    """(data, rows, cols) of the board-pose columns."""
    rows = np.arange(2 * vi.size)
    data, rr, cc = [], [], []
    for slot in range(_N_VIEW):
        h = _fd_step(view[:, slot], 1e-2 if slot >= 3 else 1.0)
        vp, vm = view.copy(), view.copy()
        vp[:, slot] += h
        vm[:, slot] -= h
        d = np.nan_to_num((proj(cam, vp, xw) - proj(cam, vm, xw)) / (2 * h[vi])[:, None])
        data.append(d.ravel())
        rr.append(rows)
        cc.append(np.repeat(col_view[vi, slot], 2))
    return np.concatenate(data), np.concatenate(rr), np.concatenate(cc)


def _jac_window_block(proj, cam, view, xw, col_win, group):
    """(data, rows, cols) of the window columns (offset [m], two tilts [rad] per plane)."""
    rows = np.arange(2 * group.size)
    ok = np.repeat(group >= 0, 2)
    data, rr, cc = [], [], []
    for slot in range(len(_WIN_SLOTS)):
        h = 1e-7
        wp, wm_ = xw.copy(), xw.copy()
        wp[:, slot] += h
        wm_[:, slot] -= h
        d = np.nan_to_num((proj(cam, view, wp) - proj(cam, view, wm_)) / (2 * h))
        data.append(d.ravel()[ok])
        rr.append(rows[ok])
        cc.append(np.repeat(col_win[np.maximum(group, 0), slot], 2)[ok])
    return np.concatenate(data), np.concatenate(rr), np.concatenate(cc)


def _column_names(cam_idx: np.ndarray, n_views: int, n_wf: int) -> list[str]:
    """Names of the unknowns, in the order of the adjustment's vector (for correlation reports)."""
    names = [f"camera {k // _N_CAM} {_CAM_SLOTS[k % _N_CAM]}" for k in cam_idx]
    names += [f"view {v} {s}" for v in range(n_views) for s in _VIEW_SLOTS]
    names += [f"window {g} {s}" for g in range(n_wf // len(_WIN_SLOTS)) for s in _WIN_SLOTS]
    return names


def _uncertainties(J, r, cam_idx, shape, dof, names, w0, n_wf) -> dict:
    """Standard deviations of the free camera parameters (NaN = fixed) and, for the window columns
    ``w0 .. w0 + n_wf``, their covariance, the strongest correlation of each with any other unknown and the
    condition number of the correlation matrix; from the Gauss-Newton covariance s^2 (J^T J)^-1."""
    cam_std = np.full(shape, np.nan)
    out: dict = {"cam_std": cam_std}
    if dof <= 0:
        return out
    JtJ = J.T @ J
    JtJ = JtJ.toarray() if sp.issparse(JtJ) else np.asarray(JtJ)
    s2 = float(np.sum(r**2)) / dof
    try:
        inv = np.linalg.inv(JtJ)
    except np.linalg.LinAlgError:
        log.warning("bundle adjustment: singular normal matrix; parameter uncertainties unavailable")
        if n_wf:
            out["window"] = {"inv": np.full((n_wf, n_wf), np.inf), "s2": s2, "max_corr": np.ones(n_wf),
                             "with": [""] * n_wf, "cond": np.inf}
        return out
    cam_std.ravel()[cam_idx] = np.sqrt(np.clip(np.diag(inv)[: cam_idx.size] * s2, 0, None))
    if n_wf:
        d = np.sqrt(np.clip(np.diag(inv), 1e-300, None))
        corr = inv / np.outer(d, d)
        wcols = np.arange(w0, w0 + n_wf)
        c = np.abs(corr[wcols])
        for k, col in enumerate(wcols):
            c[k, col] = 0.0
        best = np.argmax(c, axis=1)
        dj = np.sqrt(np.clip(np.diag(JtJ), 1e-300, None))
        ev = np.linalg.eigvalsh(JtJ / np.outer(dj, dj))
        out["window"] = {"inv": inv[np.ix_(wcols, wcols)], "s2": s2, "max_corr": c[np.arange(n_wf), best],
                         "with": [names[j] for j in best], "cond": float(ev[-1] / max(ev[0], 1e-300))}
    return out


def _camera_std(J, r: np.ndarray, cam_idx: np.ndarray, shape: tuple[int, int], dof: int) -> np.ndarray:
    """Standard deviations ``shape`` of the free camera parameters (columns ``0..len(cam_idx)`` of ``J``, at
    ``cam_idx`` of the flattened array) from the Gauss-Newton covariance s^2 (J^T J)^-1; NaN = fixed."""
    return _uncertainties(J, r, cam_idx, shape, dof, [], 0, 0)["cam_std"]


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
