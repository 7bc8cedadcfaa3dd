"""The specimen axis of every step at once: a batched version of ``mesh.fit_axis(..., initial=...)``.

``mesh.fit_axis`` fits one marker cloud with ``scipy.optimize.least_squares``; refitting each of the
steps that way costs a solver set-up per step. Here all steps are refitted together by a damped
Gauss-Newton iteration on the same residual (radius minus its Legendre profile along the axis,
variable projection) from the reference axis, which every aligned step is close to. It converges
to the same axes (to ~1e-12 relative).
"""

from __future__ import annotations

import numpy as np

from .mesh import MIN_MARKERS, Axis, _frame

__all__ = ["refit_axes"]

#: Relative finite-difference step of the residual's Jacobian (the iteration's fixed point does not
#: depend on it: only the speed of convergence does).
_H = 1e-7


def _legendre(t: np.ndarray, degree: int) -> np.ndarray:
    """Legendre polynomials P_0..P_degree at t, shape ``t.shape + (degree + 1,)`` (Bonnet's recursion)."""
    out = [np.ones_like(t), t]
    for k in range(1, degree):
        out.append(((2 * k + 1) * t * out[k] - k * out[k - 1]) / (k + 1))
    return np.stack(out[: degree + 1], axis=-1)


def _profile_residual(pts, w, frame0, c0, x, degree):
    """Radius minus its least-squares Legendre profile along the axis, per step.

    pts (s, n, 3), w (s, n) 0/1 weights, x (s, e, 4) axis variables for e trial sets.
    Returns the residual (s, e, n), the unit directions (s, e, 3), origins (s, e, 3), radii (s, e, n).
    """
    d = frame0[2] + x[..., :1] * frame0[0] + x[..., 1:2] * frame0[1]
    d = d / np.sqrt(np.sum(d * d, axis=-1, keepdims=True))
    o = c0 + x[..., 2:3] * frame0[0] + x[..., 3:4] * frame0[1]
    v = pts[:, None] - o[:, :, None]  # (s, e, n, 3)
    along = np.einsum("senk,sek->sen", v, d)
    r = np.sqrt(np.maximum(np.einsum("senk,senk->sen", v, v) - along * along, 0.0))
    ww = w[:, None]
    mean = np.einsum("sen,sn->se", along, w)[..., None] / w.sum(-1)[:, None, None]
    lo, hi = np.min(np.where(ww > 0, along, np.inf), -1), np.max(np.where(ww > 0, along, -np.inf), -1)
    t = (along - mean) / np.maximum(0.5 * (hi - lo), 1e-12)[..., None]
    basis = _legendre(t, degree) * ww[..., None]  # (s, e, n, b)
    rw = r * ww
    bt = np.swapaxes(basis, -1, -2)
    coef = np.linalg.solve(bt @ basis, bt @ rw[..., None])
    return rw - (basis @ coef)[..., 0], d, o, r


def refit_axes(points: np.ndarray, observed: np.ndarray, initial: Axis, *, profile_degree: int = 4,
               max_iterations: int = 50) -> list[Axis]:
    """Refit the axis of each step from ``initial`` (``mesh.fit_axis(step, initial=initial)`` for all steps).

    Parameters
    ----------
    points : ndarray, shape (n_steps, n_markers, 3)
        Marker positions (m), rigidly aligned on the reference.
    observed : ndarray, shape (n_steps, n_markers) bool
        Markers to fit; steps with fewer than ``MIN_MARKERS`` keep ``initial``.
    initial : Axis

    Returns
    -------
    list of Axis, one per step (angular origin kept from ``initial``).
    """
    ok = observed & np.all(np.isfinite(points), axis=-1)
    fit = ok.sum(axis=1) >= MIN_MARKERS
    axes = [initial] * len(points)
    if not fit.any():
        return axes
    pts = np.where(ok[fit, :, None], points[fit], 0.0)
    w = ok[fit].astype(float)
    frame0 = _frame(initial.direction)
    c0 = initial.origin
    x = np.zeros((len(pts), 4))
    steps = np.concatenate([np.zeros((1, 4)), _H * np.eye(4)])  # (5, 4) trial offsets
    previous = np.full(len(pts), np.inf)
    floor = w.sum(axis=1) * (1e-12 * initial.radius) ** 2  # cost at the rounding level of the radii
    for _ in range(max_iterations):
        evaluated = _profile_residual(pts, w, frame0, c0, x[:, None] + steps[None], profile_degree)
        res = evaluated[0]
        cost = np.sum(res[:, 0] ** 2, axis=-1)
        worse = cost > previous * (1.0 + 1e-9) + floor  # a Gauss-Newton step that overshot: step back halfway
        if worse.any():
            delta = np.where(worse[:, None], 0.5 * delta, 0.0)
            x = x - delta
            continue
        if np.all(previous - cost <= 1e-10 * cost + floor):
            break
        previous = cost
        jac = np.swapaxes((res[:, 1:] - res[:, :1]) / _H, 1, 2)  # (s, n, 4)
        jtj = np.swapaxes(jac, 1, 2) @ jac
        jtj = jtj + 1e-12 * np.trace(jtj, axis1=1, axis2=2)[:, None, None] * np.eye(4)
        delta = -np.linalg.solve(jtj, np.swapaxes(jac, 1, 2) @ res[:, 0, :, None])[..., 0]
        x = x + delta
    else:  # out of iterations: evaluate where the last step went
        evaluated = _profile_residual(pts, w, frame0, c0, x[:, None], profile_degree)
    res, d, o, r = (a[:, :1] for a in evaluated)  # the untouched trial set (offset 0) is the solution
    for k, step in enumerate(np.flatnonzero(fit)):
        axes[step] = _axis_from(pts[k], w[k] > 0, d[k, 0], o[k, 0], r[k, 0], res[k, 0], initial)
    return axes


def _axis_from(pts, used, d, o, r, res, initial: Axis) -> Axis:
    """The ``Axis`` of a fitted direction and origin, oriented and framed as ``mesh.fit_axis`` does."""
    if d @ initial.direction < 0:
        d = -d
    p = pts[used]
    o = o + ((p - o) @ d).mean() * d
    x = initial.basis[0] - (initial.basis[0] @ d) * d
    x /= np.linalg.norm(x)
    frame = np.stack([x, np.cross(d, x), d])
    return Axis(origin=o, basis=frame, radius=float(r[used].mean()), rms=float(np.sqrt(np.mean(res[used] ** 2))))
