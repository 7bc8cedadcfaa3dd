"""Calibration's joint sparse bundle adjustment (``scipy.optimize.least_squares``) of intrinsics, camera poses,
board poses and optional window planes, with its Jacobian blocks and parameter uncertainties. Step 3 of
:mod:`reconstruction.calibration`.
"""

from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sp
from scipy.optimize import least_squares

from .calibration_model import _N_CAM, _N_VIEW, _WIN_SLOTS, _camera_rays, _pixels

log = logging.getLogger(__name__)

_NAN_RESIDUAL_PX = 1e3  # residual of a point the model cannot image (not beyond its window)
_CAM_SLOTS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "rx", "ry", "rz", "tx", "ty", "tz")
_VIEW_SLOTS = ("rx", "ry", "rz", "tx", "ty", "tz")


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
