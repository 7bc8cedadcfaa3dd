"""Specimen axes by damped Gauss-Newton: one cloud's (``fit_axis``), and every step's axis at once.

The residual is the radius of each marker minus its least-squares Legendre profile along the axis
(variable projection); the variables are the tilt of the axis and the offset of its origin in the
frame of a starting axis. ``fit_clouds`` solves it for a batch of marker clouds together (numpy
only: no solver set-up per cloud); ``fit_axis`` uses it for one cloud and ``refit_axes`` for
all the (aligned) steps of a test from the reference axis, which every step is close to.
"""

from __future__ import annotations

import numpy as np

from .axis import MIN_MARKERS, Axis, _frame
from .errors import MeshError

__all__ = ["fit_axis", "fit_clouds", "refit_axes"]

#: Relative finite-difference step of the residual's Jacobian (the iteration's fixed point does not
#: depend on it: only the speed of convergence does).
_H = 1e-7
#: Trial offsets of the four variables evaluated together: the point itself and one step along each.
_TRIALS = np.concatenate([np.zeros((1, 4)), _H * np.eye(4)])


def _hankel(degree: int) -> np.ndarray:
    """Indices (degree + 1, degree + 1) into the power moments (0 .. 2 degree) forming the Hankel normal matrix."""
    k = np.arange(degree + 1)
    return k[:, None] + k[None]


def _clouds(pts, w, c0):
    """What ``_profile_residual`` needs of the clouds, computed once per fit: the markers relative to the
    starting origins transposed (s, 3, n), their squared norms (s, 1, n), the weights (s, 1, n) and their
    sums (s, 1, 1), and an additive mask (s, 1, n) (0 where fitted, inf elsewhere; None if all are fitted)."""
    q = pts - c0[:, None]
    qt = np.swapaxes(q, 1, 2)
    ww = w[:, None]
    excluded = None if np.all(ww > 0) else np.where(ww > 0, 0.0, np.inf)
    return qt, np.sum(q * q, axis=-1)[:, None], ww, w.sum(-1)[:, None, None], excluded


def _profile_residual(clouds, frame0, c0, x, degree):
    """Radius minus its least-squares Legendre profile along the axis, per cloud.

    clouds: ``_clouds(pts, w, c0)`` of the markers pts (s, n, 3) with 0/1 weights w (s, n); frame0 (s, 3, 3)
    and c0 (s, 3) the starting axes, x (s, e, 4) axis variables for e trial sets.
    Returns the residual (s, e, n), the unit directions (s, e, 3), origins (s, e, 3), radii (s, e, n).
    """
    qt, qq, ww, w_sum, excluded = clouds
    f0, f1, f2 = frame0[:, None, 0], frame0[:, None, 1], frame0[:, None, 2]  # (s, 1, 3)
    d = f2 + x[..., :1] * f0 + x[..., 1:2] * f1
    d = d / np.sqrt(np.sum(d * d, axis=-1, keepdims=True))
    shift = x[..., 2:3] * f0 + x[..., 3:4] * f1  # (s, e, 3) origin offset from c0 (small: no cancellation below)
    # |p - o|^2 and (p - o) . d from products of the (s, n, 3) markers with the (s, e, 3) trial vectors
    # in place where a temporary of the (s, e, n) size would be made (the same operations in the same order)
    along = d @ qt
    along -= np.sum(shift * d, axis=-1)[..., None]  # (s, e, n)
    r = shift @ qt
    r *= 2.0
    np.subtract(qq, r, out=r)
    r += np.sum(shift * shift, axis=-1)[..., None]  # |p - o|^2
    r -= along * along
    np.sqrt(np.maximum(r, 0.0, out=r), out=r)
    mean = np.sum(along * ww, axis=-1, keepdims=True) / w_sum
    if excluded is None:  # every marker fitted
        lo, hi = np.min(along, -1), np.max(along, -1)
    else:
        lo, hi = np.min(along + excluded, -1), np.max(along - excluded, -1)
    t = along
    t -= mean
    t /= np.maximum(0.5 * (hi - lo), 1e-12)[..., None]
    return _projection_residual(t, r, ww, w_sum, degree), d, c0[:, None] + shift, r


def _projection_residual(t, r, ww, w_sum, degree):
    """Weighted residual ``w (r - p(t))`` of the least-squares polynomial p of degree ``degree`` in t (s, e, n),
    from the power moments of t (Hankel normal equations: t is scaled into [-1, 1], where their condition
    number at degree 4 is ~4e2; the same projection as a Legendre basis to rounding). The moments are summed
    power by power, so no array larger than t (s, e, n) is formed (linear cost and memory in n).
    r (s, e, n), weights ww (s, 1, n) with sums w_sum (s, 1, 1)."""
    rw = r * ww
    wt = np.broadcast_to(ww, t.shape) * t  # w t^k, k = 1 .. 2 degree in turn
    moments = [np.broadcast_to(w_sum[..., 0], t.shape[:-1])]
    rhs = [np.sum(rw, axis=-1)]
    for k in range(1, 2 * degree + 1):
        moments.append(np.sum(wt, axis=-1))
        if k <= degree:
            rhs.append(np.einsum("...n,...n->...", wt, r))
        if k < 2 * degree:
            wt *= t
    moments = np.stack(moments, axis=-1)  # (s, e, 2 degree + 1)
    coef = np.linalg.solve(moments[..., _hankel(degree)], np.stack(rhs, axis=-1)[..., None])[..., 0]
    fitted = np.broadcast_to(coef[..., degree:], t.shape).copy()  # Horner
    for k in range(degree - 1, -1, -1):
        fitted *= t
        fitted += coef[..., k:k + 1]
    return rw - fitted * ww


def fit_clouds(pts: np.ndarray, w: np.ndarray, frame0: np.ndarray, c0: np.ndarray, radius: float, *,
               profile_degree: int = 4, max_iterations: int = 50):
    """Axes of several marker clouds from starting axes, by damped Gauss-Newton on the profile residual.

    Parameters
    ----------
    pts : ndarray, shape (s, n, 3)
        Marker positions (m); entries with zero weight are ignored (must be finite).
    w : ndarray, shape (s, n)
        0/1 weights (markers to fit).
    frame0 : ndarray, shape (s, 3, 3)
        Starting frames (rows x', y', z'; z' the starting direction).
    c0 : ndarray, shape (s, 3)
        Starting origins (m).
    radius : float
        Typical radius (m): the cost floor at the rounding level of the radii.

    Returns
    -------
    residual (s, n), direction (s, 3), origin (s, 3), radii (s, n) at the solution.
    """
    x = np.zeros((len(pts), 4))
    previous = np.full(len(pts), np.inf)
    floor = w.sum(axis=1) * (1e-12 * radius) ** 2  # cost at the rounding level of the radii
    delta = np.zeros_like(x)
    clouds = _clouds(pts, w, c0)
    probe = False  # evaluate the point alone, without the Jacobian's trials: the last step looked like the last one
    for _ in range(max_iterations):
        evaluated = _profile_residual(clouds, frame0, c0, x[:, None] + (_TRIALS[:1] if probe else _TRIALS)[None],
                                      profile_degree)
        res = evaluated[0]
        cost = np.sum(res[:, 0] ** 2, axis=-1)
        worse = cost > previous * (1.0 + 1e-9) + floor  # a Gauss-Newton step that overshot: step back halfway
        if worse.any():
            delta = np.where(worse[:, None], 0.5 * delta, 0.0)
            x = x - delta
            continue
        if np.all(previous - cost <= 1e-10 * cost + floor):
            break
        if probe:  # not converged after all: the trials at this point too
            res = _profile_residual(clouds, frame0, c0, x[:, None] + _TRIALS[None], profile_degree)[0]
        previous = cost
        jac = np.swapaxes((res[:, 1:] - res[:, :1]) / _H, 1, 2)  # (s, n, 4)
        jtj = np.swapaxes(jac, 1, 2) @ jac
        jtj = jtj + 1e-12 * np.trace(jtj, axis1=1, axis2=2)[:, None, None] * np.eye(4)
        delta = -np.linalg.solve(jtj, np.swapaxes(jac, 1, 2) @ res[:, 0, :, None])[..., 0]
        x = x + delta
        # the decrease Gauss-Newton predicts, |J delta|^2, within the stopping test: most likely the last step
        predicted = np.sum((jac @ delta[..., None]) ** 2, axis=(1, 2))
        probe = bool(np.all(predicted <= 1e-10 * (cost - predicted) + floor))
    else:  # out of iterations: evaluate where the last step went
        evaluated = _profile_residual(clouds, frame0, c0, x[:, None], profile_degree)
    return tuple(a[:, 0] for a in evaluated)  # the untouched trial set (offset 0) is the solution


def refit_axes(points: np.ndarray, observed: np.ndarray, initial: Axis, *, profile_degree: int = 4,
               max_iterations: int = 50, start: list[Axis] | None = None) -> list[Axis]:
    """Refit the axis of each step from ``initial`` (``mesh.fit_axis(step, initial=initial)`` for all steps).

    Parameters
    ----------
    points : ndarray, shape (n_steps, n_markers, 3)
        Marker positions (m), rigidly aligned on the reference.
    observed : ndarray, shape (n_steps, n_markers) bool
        Markers to fit; steps with fewer than ``MIN_MARKERS`` keep ``initial``.
    initial : Axis
    start : list of Axis, optional
        One per step: where each step's fit starts (default ``initial``); the orientation and angular origin
        are ``initial``'s whatever the start.

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
    n_fit = len(pts)
    if start is None:
        frame0 = np.broadcast_to(_frame(initial.direction), (n_fit, 3, 3))
        c0 = np.broadcast_to(initial.origin, (n_fit, 3))
    else:  # any orthonormal frame about the starting direction serves: the axis's own
        frame0 = np.stack([start[k].basis for k in np.flatnonzero(fit)])
        c0 = np.stack([start[k].origin for k in np.flatnonzero(fit)])
    res, d, o, r = fit_clouds(pts, w, frame0, c0, initial.radius, profile_degree=profile_degree,
                              max_iterations=max_iterations)
    for step, axis in zip(np.flatnonzero(fit), axes_from(pts, w, d, o, r, res, initial.direction, initial.basis[0])):
        axes[step] = axis
    return axes


def axes_from(pts, w, d, o, r, res, toward: np.ndarray, x_hint: np.ndarray) -> list[Axis]:
    """``Axis`` objects of fitted directions and origins, oriented and framed as ``fit_axis`` does.

    pts (s, n, 3), w (s, n) 0/1 weights, d and o (s, 3), r and res (s, n). Each direction is turned
    to have a positive component along ``toward`` (3,); its origin moves to the mean axial position
    of the fitted markers; the frame's x' is ``x_hint`` (3,) made perpendicular to the axis.
    """
    d = np.where((d @ toward < 0)[:, None], -d, d)
    n_w = w.sum(axis=1)
    o = o + (np.einsum("snk,sk->sn", pts - o[:, None], d) * w).sum(axis=1, keepdims=True) / n_w[:, None] * d
    x = x_hint[None] - (d @ x_hint)[:, None] * d
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    frames = np.stack([x, np.cross(d, x), d], axis=1)  # (s, 3, 3)
    radius = (r * w).sum(axis=1) / n_w
    rms = np.sqrt((res * res * w).sum(axis=1) / n_w)
    return [Axis(origin=o[k], basis=frames[k], radius=float(radius[k]), rms=float(rms[k])) for k in range(len(d))]


def fit_axis(points: np.ndarray, *, toward: np.ndarray | None = None, initial: Axis | None = None,
             profile_degree: int = 4) -> Axis:
    """Fit the axis of a tube (a surface of revolution) to a marker cloud.

    The radius is modelled as a Legendre polynomial of degree ``profile_degree`` in the axial
    coordinate (a bulged or tapered tube keeps its symmetry axis); the axis minimises the
    residual of that profile (variable projection).

    Parameters
    ----------
    points : ndarray, shape (n_markers, 3)
        Marker positions (m); rows with NaN are ignored.
    toward : ndarray, shape (3,), optional
        The axis is oriented to have a positive component along this direction (default world +z,
        or ``initial``'s direction).
    initial : Axis, optional
        Start from this axis (one local fit) instead of trying the three principal directions.
    profile_degree : int
        Degree of the radius profile r(z).

    Returns
    -------
    Axis
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (n_markers, 3); got {pts.shape}")
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) < MIN_MARKERS:
        raise MeshError(f"fitting the specimen axis needs at least {MIN_MARKERS} finite markers; got {len(pts)}")
    centre = pts.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((pts - centre) ** 2, axis=1))))
    best = None
    for d0, c0 in _axis_candidates(pts, centre, initial):
        res, d, o, r = fit_clouds(pts[None], np.ones((1, len(pts))), _frame(d0)[None], np.asarray(c0, float)[None],
                                  scale, profile_degree=int(profile_degree))
        rms = float(np.sqrt(np.mean(res[0] ** 2)))
        if best is None or rms / r[0].mean() < best[0]:
            best = (rms / r[0].mean(), d[0], o[0], r[0], rms)
        if best[0] < 0.05:  # a tube: the most promising principal direction was right
            break
    _, d, o, r, rms = best
    if toward is None:
        toward = np.array([0.0, 0.0, 1.0]) if initial is None else initial.direction
    return _oriented_axis(pts, d, o, r, rms, np.asarray(toward, dtype=float), initial)


def _axis_candidates(pts: np.ndarray, centre: np.ndarray, initial: Axis | None) -> list:
    """Starting (direction, origin) pairs of ``fit_axis``: ``initial``'s, or the three principal
    directions of the cloud, the one with the least relative scatter of the radii about it first."""
    if initial is not None:
        return [(initial.direction, initial.origin)]
    v = pts - centre
    _, _, vt = np.linalg.svd(v, full_matrices=False)

    def spread(d0):  # relative scatter of the radii about the principal direction, before fitting
        r = np.linalg.norm(v - np.outer(v @ d0, d0), axis=1)
        return np.std(r) / np.mean(r)

    return sorted([(d0, centre) for d0 in vt], key=lambda c: spread(c[0]))


def _oriented_axis(pts, d, o, r, rms, toward: np.ndarray, initial: Axis | None) -> Axis:
    """The ``Axis`` of a fitted direction d and origin o: d turned towards ``toward``, the origin moved to
    the markers' mean axial position, the angular origin kept from ``initial`` if given."""
    if d @ toward < 0:
        d = -d
    o = o + ((pts - o) @ d).mean() * d
    frame = _frame(d)
    if initial is not None:  # keep the angular origin of the initial frame
        x = initial.basis[0] - (initial.basis[0] @ d) * d
        x /= np.linalg.norm(x)
        frame = np.stack([x, np.cross(d, x), d])
    return Axis(origin=o, basis=frame, radius=float(r.mean()), rms=rms)
