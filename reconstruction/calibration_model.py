"""Calibration's results and its parameter model: the result objects, the packed camera/board-pose vectors
(``_N_CAM`` camera slots, ``_N_VIEW`` view slots), projection and rays through optional windows, and the window
model (one plane per tank wall, its offset and tilts as unknowns). Used by :mod:`reconstruction.calibration`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .calibration_errors import CalibrationError
from .cameras import Camera, rotation_matrix
from .refraction import Window, refracted_directions

__all__ = ["CalibrationResult", "WindowFit"]

_N_CAM = 15  # fx fy cx cy k1 k2 p1 p2 k3 | rvec | tvec
_N_VIEW = 6


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


_WIN_SLOTS = ("offset", "tilt_a", "tilt_b")
