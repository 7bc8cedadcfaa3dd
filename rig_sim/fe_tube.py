"""Finite-element ground truth of a thick-walled artery, clamped on cannulae or free (felupe, axisymmetric).

Independent of the closed-form tubes of ``rig_sim.tube`` and of the identification's own
equations: a 2-D axisymmetric finite-element model (felupe, 4-node quadrilaterals, u/p/J mixed
formulation for near-incompressibility) of half the tube, mirror-symmetric at mid-length.

- Geometry (reference): outer radius ``radius`` (the marker surface), wall ``thickness``, length
  ``length`` between the clamps. Mesh axis x = axial (m), y = radial (m).
- Loading: the ends are moved axially to the stretch L/L0 (at zero pressure), then the lumen is
  pressurised step by step (follower pressure on the inner surface).
- ``clamped=True``: the end face is tied on the cannula (radial displacement 0 there), so the tube
  tapers to the cannula radius near the clamps. ``clamped=False``: the end face slides freely in
  the radial direction (a uniform tube).
- Wall force: the axial reaction on the end face, i.e. the force the wall carries into the clamp,
  what a load cell with ``measures = "wall"`` reads (docs/decisions/0003-load-cell.md).
- Markers on the outer surface: the deformed outer profile r(Z), z(Z) of the nodes, interpolated
  with cubic splines and revolved at random angles.

Materials (``W`` per reference volume, isochoric invariants for the isotropic part, nearly
incompressible with bulk modulus ``bulk``):

- ``"hgo"``: ``c/2 (I1b - 3) + k1/(2 k2) sum_i [exp(k2 (I4i - 1)^2) - 1]``, two fibre families
  at +/- phi from the circumferential direction, in tension only.
- ``"delfino"`` (Demiray): ``beta/2 [exp(alpha (I1b - 3)) - 1]``.

felupe is a test/benchmark dependency (``pip install vfmlab[test]``); it is imported lazily.
Only tests and benchmarks use this module.
"""

from __future__ import annotations

import functools
import hashlib
import json
import logging
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

log = logging.getLogger(__name__)

__all__ = ["FETube", "solve_fe_tube", "fe_markers", "FE_MATERIALS"]

FE_MATERIALS = ("hgo", "delfino")
#: Bumped when the model changes, so that cached solutions are recomputed.
FE_VERSION = 3
#: Width of the smoothed tension-only switch of the HGO fibres (in I4 - 1).
FIBRE_SWITCH = 1e-3
#: Default bulk modulus / the law's largest stiffness-like parameter. The exponential laws stiffen by
#: orders of magnitude by 150 mmHg; on the free Delfino tube (4 elements through the wall) 1e5 left the outer
#: radius 9e-4 off the closed form and beta +3 %, 1e7 2.8e-4 and +0.4 %, 1e8 to 1e10 2.7e-4 and +0.37 %
#: (the rest is the radial discretisation: 6.9e-5 with 8 elements, 1.8e-5 with 16).
BULK_RATIO = 1e8
#: Newton increment (m) taken as converged whatever the residual (see ``_converged``).
DX_CONVERGED = 1e-12
#: felupe's Newton progress printout (0 = quiet).
VERBOSE = 0


@dataclass(frozen=True)
class FETube:
    """Deformed outer profiles and loads of an FE inflation/extension test.

    Attributes
    ----------
    Z : ndarray, shape (n_nodes,)
        Reference axial coordinate of the outer-surface nodes, from 0 (mid-length) to L/2 (m).
    r, z : ndarray, shape (n_steps, n_nodes)
        Deformed radius and axial position of those nodes (m); step 0 is the reference.
    pressure : ndarray, shape (n_steps,)
        Lumen pressure (Pa).
    wall_force : ndarray, shape (n_steps,)
        Axial force the wall carries into the clamp (N).
    stretch : ndarray, shape (n_steps,)
    radius, thickness, length : float
        Reference outer radius, wall thickness, length between the clamps (m).
    model : str
    params : dict
    clamped : bool
    r_inner, z_inner : ndarray, shape (n_steps, n_nodes)
        Deformed radius and axial position of the lumen nodes at the same reference Z (m): the
        material line through the wall at Z runs from (r_inner, z_inner) to (r, z).
    """

    Z: np.ndarray
    r: np.ndarray
    z: np.ndarray
    pressure: np.ndarray
    wall_force: np.ndarray
    stretch: np.ndarray
    radius: float
    thickness: float
    length: float
    model: str
    params: dict
    clamped: bool
    r_inner: np.ndarray
    z_inner: np.ndarray


class _Umat:
    """Isochoric hyperelastic material for felupe: ``gradient`` (P) analytic, ``hessian`` by central
    differences of P. F has shape (3, 3, n_q, n_cells) in (axial, radial, hoop) components."""

    def __init__(self, model: str, params: Mapping[str, float]):
        if model not in FE_MATERIALS:
            raise ValueError(f"model must be one of {FE_MATERIALS}; got {model!r}")
        self.model, self.p = model, dict(params)
        self.x = [np.eye(3), np.zeros(0)]
        if model == "hgo":
            phi = float(self.p["phi"])  # from the circumferential (hoop, index 2) towards the axis (index 0)
            self.fibres = [np.array([np.sin(phi), 0.0, np.cos(phi)]), np.array([-np.sin(phi), 0.0, np.cos(phi)])]

    def _stress(self, F: np.ndarray) -> np.ndarray:
        J = np.linalg.det(np.moveaxis(F, (0, 1), (-2, -1)))
        iFT = np.moveaxis(np.linalg.inv(np.moveaxis(F, (0, 1), (-2, -1))), (-2, -1), (1, 0))
        I1 = np.einsum("ij...,ij...->...", F, F)
        Jm23 = J ** (-2.0 / 3.0)
        dI1b = Jm23 * (2.0 * F - 2.0 / 3.0 * I1 * iFT)  # d(I1b)/dF
        I1b = Jm23 * I1
        if self.model == "hgo":
            P = 0.5 * self.p["c"] * dI1b
            k1, k2 = self.p["k1"], self.p["k2"]
            for a in self.fibres:
                Fa = np.einsum("ij...,j->i...", F, a)
                e = np.einsum("i...,i...->...", Fa, Fa) - 1.0
                # dW/dI4, tension only; the switch is smoothed over |I4 - 1| < FIBRE_SWITCH (stresses of
                # ~k1 x 1e-3 there) so that Newton does not cycle on fibres at the edge of slackness
                on = 0.5 * (1.0 + np.tanh(e / FIBRE_SWITCH))
                w = on * k1 * e * np.exp(np.minimum(k2 * e * e, 50.0))
                P = P + 2.0 * w * np.einsum("i...,j->ij...", Fa, a)
            return P
        beta, alpha = self.p["beta"], self.p["alpha"]
        return 0.5 * beta * alpha * np.exp(alpha * (I1b - 3.0)) * dI1b

    def gradient(self, x):
        return [self._stress(x[0]), x[-1]]

    def hessian(self, x):
        F = x[0]
        h = 1e-7
        A = np.empty((3, 3) + F.shape)
        for k in range(3):
            for m in range(3):
                d = np.zeros_like(F)
                d[k, m] = h
                A[:, :, k, m] = (self._stress(F + d) - self._stress(F - d)) / (2.0 * h)
        return [A]


def _build(radius, thickness, length, n_axial, n_radial, clamped):
    import felupe as fem

    half = 0.5 * length
    # grade the axial spacing towards the clamp, where a clamped tube bends
    s = np.linspace(0.0, 1.0, int(n_axial) + 1)
    xs = half * (1.0 - (1.0 - s) ** 1.5 if clamped else s)
    ys = np.linspace(radius - thickness, radius, int(n_radial) + 1)
    mesh = fem.mesh.Grid(xs, ys)
    region = fem.RegionQuad(mesh)
    field = fem.FieldContainer([fem.FieldAxisymmetric(region, dim=2)])
    x = mesh.points
    tol = 1e-9 * length
    boundaries = {
        "mid": fem.Boundary(field[0], fx=0.0, skip=(False, True)),  # mirror plane: no axial displacement
        "move": fem.Boundary(field[0], fx=half, skip=(False, True)),
    }
    if clamped:
        boundaries["clamp"] = fem.Boundary(field[0], fx=half, skip=(True, False))
    inner = fem.RegionQuadBoundary(mesh, only_surface=True, mask=np.abs(x[:, 1] - (radius - thickness)) < tol,
                                   ensure_3d=True)
    lumen = fem.FieldContainer([fem.FieldAxisymmetric(inner, dim=2)])
    outer = np.flatnonzero(np.abs(x[:, 1] - radius) < tol)
    outer = outer[np.argsort(x[outer, 0])]
    lumen_nodes = np.flatnonzero(np.abs(x[:, 1] - (radius - thickness)) < tol)
    lumen_nodes = lumen_nodes[np.argsort(x[lumen_nodes, 0])]
    end = np.flatnonzero(np.abs(x[:, 0] - half) < tol)
    return fem, mesh, field, boundaries, lumen, (outer, lumen_nodes), end


def _converged(dx, x, f, xtol, ftol, dof1=None, dof0=None, items=None):
    """felupe's Newton test (residual / reactions < ftol and increment < xtol), or an increment below
    ``DX_CONVERGED`` m: with a stiff bulk modulus the residual has a round-off floor of ~bulk x 1e-16 m
    which, at the small reactions of the first pressure steps, stays above ``ftol`` after Newton has converged."""
    import felupe as fem

    xnorm, fnorm, success = fem.tools._newton.check(dx, x, f, xtol, ftol, dof1, dof0, items)
    return xnorm, fnorm, bool(success or xnorm < DX_CONVERGED)


def _newton(fem, field, items, boundaries, move, p):
    """One Newton solve at (axial displacement, pressure) from the field's current state: the result
    or None if it failed (the field is then left as it was)."""
    boundaries["move"].update(move)
    items[1].update(p)
    dof0, dof1 = fem.dof.partition(field, boundaries)
    ext0 = fem.dof.apply(field, boundaries, dof0)
    checkpoint = items[0].checkpoint()  # field values and the condensed p, J of the solid
    try:
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore")  # singular trial systems of a too-large increment: cut back
            res = fem.newtonraphson(items=items, x0=field, dof1=dof1, dof0=dof0, ext0=ext0, tol=1e-7, maxiter=40,
                                    verbose=VERBOSE, check=_converged)
    except (fem.tools.NewtonConvergenceError, np.linalg.LinAlgError, ValueError):
        res = None
    if res is None or not res.success:
        # restore the solid's internal p, J too: its mean-dilatation J is linearised about its last state,
        # so a failed iterate left there spoils the next attempt (bulk x its O(du^2) error)
        items[0].restore(checkpoint)
        return None
    if res.x is not field:  # keep the container the boundaries refer to
        for mine, solved in zip(field.fields, res.x.fields):
            mine.values[:] = solved.values
    return res


def _run(fem, field, solid, pressure_item, boundaries, loads, max_cuts: int = 8):
    """Solve each (axial displacement, pressure) load in order, halving an increment that fails.

    Returns a list of (nodal displacements (n_points, 2), axial reaction on the moved end (N)).
    """
    items = [solid, pressure_item]
    out, last = [], (0.0, 0.0)
    for target in loads:
        cuts = 0
        while True:
            res = _newton(fem, field, items, boundaries, *target)
            if res is not None:
                last = target
                if target == loads[len(out)]:
                    break
                target = loads[len(out)]  # the cut increment converged: try the rest
                continue
            cuts += 1
            if cuts > max_cuts:
                raise RuntimeError(f"the FE solve did not converge towards axial displacement {target[0]:.4g} m, "
                                   f"pressure {target[1]:.4g} Pa")
            target = tuple(0.5 * (a + b) for a, b in zip(last, target))
        reaction = fem.tools.force(field, res.fun, boundaries["move"])
        out.append((field[0].values.copy(), float(reaction[0])))
    return out


def _load_path(pressures, move, n_ramp, max_step=2e3):
    """(axial displacement, pressure) loads to solve in order, and the indices of the requested states.

    The material is hyperelastic, so the path does not change the states; it is chosen for Newton:
    pressurise to the first level at L/L0 = 1 (the slack-fibre start of an HGO tube under axial
    stretch is a near-mechanism), then stretch, then the pressure levels in increments <= max_step Pa.
    """
    first = float(pressures[0]) if len(pressures) else 0.0
    ts = np.linspace(0.0, 1.0, int(n_ramp) + 1)[1:]
    loads = [(0.0, first * t) for t in ts] if first > 0 else []
    loads += [(move * t, first) for t in ts]
    keep = [len(loads) - 1]
    previous = first
    for p in pressures[1:]:
        n_sub = max(1, int(np.ceil(abs(float(p) - previous) / max_step)))
        loads += [(move, previous + (float(p) - previous) * k / n_sub) for k in range(1, n_sub + 1)]
        keep.append(len(loads) - 1)
        previous = float(p)
    return loads, keep


@functools.lru_cache(maxsize=16)
def _solve_cached(model, params, radius, thickness, length, stretch, pressures, clamped, n_axial, n_radial, bulk,
                  n_ramp):
    built = _build(radius, thickness, length, n_axial, n_radial, clamped)
    fem, mesh, field, boundaries, lumen, (outer, inner), end = built
    solid = fem.SolidBodyNearlyIncompressible(_Umat(model, dict(params)), field, bulk=bulk)
    pressure_item = fem.SolidBodyPressure(lumen, pressure=0.0)
    half = 0.5 * length
    loads, keep = _load_path(pressures, (stretch - 1.0) * half, n_ramp)
    solved = _run(fem, field, solid, pressure_item, boundaries, loads)
    states = [solved[i] for i in keep]
    x = mesh.points
    u = np.concatenate([np.zeros((1,) + x.shape), np.array([state[0] for state in states])])  # (s, points, 2)
    force = np.array([0.0] + [state[1] for state in states])
    deformed = x[None] + u
    return (x[outer, 0].copy(), deformed[:, outer, 1], deformed[:, outer, 0], force, deformed[:, inner, 1],
            deformed[:, inner, 0])


def solve_fe_tube(model: str, params: Mapping[str, float], *, radius: float = 10e-3, thickness: float = 1.3e-3,
                  length: float = 35e-3, stretch: float = 1.1, pressures: Sequence[float] = (),
                  clamped: bool = True, n_axial: int = 60, n_radial: int = 4, bulk: float | None = None,
                  n_ramp: int = 4, cache_dir: str | os.PathLike | None = None) -> FETube:
    """Solve the FE tube (cached per argument set in this process).

    Parameters
    ----------
    model : {"hgo", "delfino"}
    params : mapping
        SI parameters (``rig_sim.materials.PAPER_PARAMETERS`` names).
    radius, thickness, length : float
        Reference outer radius, wall thickness, length between the clamps (m).
    stretch : float
        Axial stretch L/L0 applied first, at zero pressure.
    pressures : sequence of float
        Lumen pressures (Pa) applied in order at that stretch (a leading 0 gives a stretched,
        unpressurised step).
    clamped : bool
        End faces tied on cannulae (radial displacement 0) or free to slide radially.
    n_axial, n_radial : int
        Elements along the half length and through the wall.
    bulk : float, optional
        Bulk modulus (Pa) of the near-incompressibility penalty (default ``BULK_RATIO`` = 1e8 x the
        largest stiffness-like parameter: the exponential laws stiffen by orders of magnitude by 150 mmHg).
    n_ramp : int
        Substeps of the axial stretch.
    cache_dir : path, optional
        Keep the solution in ``cache_dir/fe-tube-<hash>.npz`` and reuse it (the hash covers every
        argument and ``FE_VERSION``).

    Returns
    -------
    FETube
        Step 0 is the reference; then one step per pressure.
    """
    params = {k: float(v) for k, v in params.items()}
    if cache_dir is not None:
        return _disk_cached(cache_dir, model, params, radius=radius, thickness=thickness, length=length,
                            stretch=stretch, pressures=pressures, clamped=clamped, n_axial=n_axial, n_radial=n_radial,
                            bulk=bulk, n_ramp=n_ramp)
    if bulk is None:
        bulk = BULK_RATIO * max(v for k, v in params.items() if k in ("c", "k1", "beta", "mu"))
    key = tuple(sorted(params.items()))
    Z, r, z, force, r_in, z_in = _solve_cached(model, key, float(radius), float(thickness), float(length),
                                               float(stretch), tuple(float(p) for p in pressures), bool(clamped),
                                               int(n_axial), int(n_radial), float(bulk), int(n_ramp))
    n = len(pressures)
    return FETube(Z=Z, r=r, z=z, pressure=np.concatenate([[0.0], np.asarray(pressures, float)]), wall_force=force,
                  stretch=np.concatenate([[1.0], np.full(n, float(stretch))]), radius=float(radius),
                  thickness=float(thickness), length=float(length), model=model, params=params, clamped=bool(clamped),
                  r_inner=r_in, z_inner=z_in)


def _disk_cached(cache_dir, model, params, **kwargs) -> FETube:
    """``solve_fe_tube`` through an .npz file per argument set."""
    key = json.dumps({"version": FE_VERSION, "model": model, "params": params,
                      **{k: (list(map(float, v)) if k == "pressures" else v) for k, v in kwargs.items()}},
                     sort_keys=True)
    path = Path(cache_dir) / f"fe-tube-{hashlib.sha256(key.encode()).hexdigest()[:16]}.npz"
    if path.exists():
        d = np.load(path, allow_pickle=False)
        return FETube(Z=d["Z"], r=d["r"], z=d["z"], pressure=d["pressure"], wall_force=d["wall_force"],
                      stretch=d["stretch"], radius=float(d["radius"]), thickness=float(d["thickness"]),
                      length=float(d["length"]), model=model, params=params, clamped=bool(d["clamped"]),
                      r_inner=d["r_inner"], z_inner=d["z_inner"])
    tube = solve_fe_tube(model, params, **kwargs)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, Z=tube.Z, r=tube.r, z=tube.z, pressure=tube.pressure, wall_force=tube.wall_force,
             stretch=tube.stretch, radius=tube.radius, thickness=tube.thickness, length=tube.length,
             clamped=tube.clamped, r_inner=tube.r_inner, z_inner=tube.z_inner, key=key)
    log.info("FE tube cached in %s", path)
    return tube


def fe_markers(tube: FETube, n_markers: int = 300, *, margin: float = 4e-3, seed: int = 0) -> np.ndarray:
    """Marker positions (n_steps, n_markers, 3) m on the outer surface of ``tube``.

    Markers at random reference angles and axial positions ``|Z| <= length/2 - margin``
    (``rig_sim.markers.place_markers``, minimum spacing), the profile mirrored about mid-length
    and interpolated with cubic splines between the FE nodes. World frame: z along the axis.
    """
    from scipy.interpolate import CubicSpline

    from .markers import place_markers

    half = 0.5 * tube.length - margin
    theta, Zm = place_markers(n_markers, tube.radius, -half, half, seed=seed)
    out = np.empty((tube.r.shape[0], n_markers, 3))
    for k in range(tube.r.shape[0]):
        r = CubicSpline(np.concatenate([-tube.Z[:0:-1], tube.Z]), np.concatenate([tube.r[k, :0:-1], tube.r[k]]))
        z = CubicSpline(np.concatenate([-tube.Z[:0:-1], tube.Z]), np.concatenate([-tube.z[k, :0:-1], tube.z[k]]))
        rm, zm = r(Zm), z(Zm)
        out[k] = np.column_stack([rm * np.cos(theta), rm * np.sin(theta), zm])
    return out
