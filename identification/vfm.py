"""Virtual Fields Method: internal and external virtual work (Avril et al. 2010, eqs. 5-11).

For each step m and virtual field k

    IVW[k, m] = sum over quadrature points of  S(C) : dE*  dV0
    EVW[k, m] = p_m * sum (n da) . u*  +  load_end[k] * N_m

with S the membrane second Piola-Kirchhoff stress, dE* = sym(F^T Grad u*) the virtual Green
strain (so that S : dE* dV0 = sigma : eps* dv), n da the current oriented area element, and N_m
the axial force the wall carries across the top measured boundary (see ``end_force``).

Two wall forms:

``wall="membrane"``
    the paper's plain form: the marker surface is the surface the pressure acts on, and the wall
    (reference thickness e0) is lumped on it.
``wall="thick"``
    the markers are on the outer surface and the pressure acts on the lumen. The wall is
    integrated through its thickness in Gauss-Legendre layers whose current radius follows from
    incompressibility (r^2 - r_s^2 = (R^2 - R_s^2) / J, J = d(theta, z) / d(Theta, Z)), and each
    virtual field is extended through the wall as a divergence-free field
    (r u_r(r) = r_o u_r(r_o) - (r^2 - r_o^2)/2 du_z/dz - (r - r_o) du_theta/dtheta), so that the
    unknown radial stress does no virtual work and the plane-stress membrane law is exact in
    every layer.

Everything that does not depend on the material parameters is computed once in ``prepare``; the
cost evaluation is then a few vectorised array operations.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from dataclasses import fields as fields_of

import numpy as np

from .errors import DegenerateDataError
from .dense import DenseQuadrature, cached_state, grid_fields, marker_survey, quadrature_grid, wants_dense
from ._wall import _external_work, _internal_work_terms, _wall_geometry, end_force
from .kinematics import SurfaceState, align_steps, surface_state
from .mesh import SurfaceMesh, build_mesh
from .models import get_model
from .models._base import Model, pk2_components, seed_virtual_strains, virtual_work_sensitivities
from .virtual_fields import VirtualFields, check_fields, paper_fields
from .thick_fields import flat_end_fields

__all__ = ["DenseParts", "PrepareSettings", "VFMData", "dense_parts", "prepare", "internal_virtual_work", "virtual_work_basis", "end_force"]

log = logging.getLogger(__name__)

WALLS = ("membrane", "thick")
ENDS = ("clamped", "free")


@dataclass(frozen=True)
class VFMData:
    """Parameter-independent part of the virtual-work balance.

    Attributes
    ----------
    c : ndarray, shape (n_steps, n_points, 3)
        (C11, C22, C12) at every integration point (identity where excluded).
    work_density : ndarray, shape (n_fields, n_steps, n_points, 3)
        dV0 * (dE*11, dE*22, 2 dE*12): IVW = sum(work_density * S).
    evw : ndarray, shape (n_fields, n_steps)
        External virtual work (J).
    pressure_work, end_work : ndarray, shape (n_fields, n_steps)
        The two parts of ``evw``.
    end_force : ndarray, shape (n_steps,)
        Axial force across the top measured boundary used in the balance (N).
    scale : ndarray, shape (n_fields,)
        Normalisation of each field's residuals (RMS of its EVW over the steps, J).
    field_names : tuple of str
    wall, ends : str
    mesh : SurfaceMesh
    n_valid_triangles : ndarray, shape (n_steps,)
    n_outliers : ndarray, shape (n_steps,)
        Markers set unobserved as mis-tracked, per step.
    marker_noise : float
        Estimated marker noise (m, median over steps; ``outliers.marker_outliers``).
    smoothing : tuple or None
        Smoothing degrees used: three (axial degree, harmonics) pairs for the r, theta, z
        displacement components, or None.
    pressure, axial_force : ndarray, shape (n_steps,)
    strip_force : ndarray, shape (n_steps,)
        ``p (A_loop - A_clamp)`` (N): what ``ends="clamped"`` adds to the load-cell force for the
        pressure on the unmeasured strip next to the clamp (used whatever ``ends``, by the checks).
    """

    c: np.ndarray
    work_density: np.ndarray
    evw: np.ndarray
    pressure_work: np.ndarray
    end_work: np.ndarray
    end_force: np.ndarray
    scale: np.ndarray
    field_names: tuple[str, ...]
    wall: str
    ends: str
    mesh: SurfaceMesh
    n_valid_triangles: np.ndarray
    n_outliers: np.ndarray
    marker_noise: float
    smoothing: tuple | None
    pressure: np.ndarray
    axial_force: np.ndarray
    thickness: float
    strip_force: np.ndarray | None = None
    #: a dense cloud's quadrature (``dense.DenseQuadrature``): the integration points are on its grid's triangles
    quadrature: DenseQuadrature | None = None
    #: parameter-independent intermediates of the cost (seeded virtual strains), filled on first use
    cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @property
    def n_steps(self) -> int:
        return self.c.shape[0]

    @property
    def points_mesh(self) -> SurfaceMesh:
        """The mesh whose triangles carry the integration points: a dense cloud's quadrature grid, else ``mesh``."""
        return self.mesh if self.quadrature is None else self.quadrature.grid


def _check_inputs(positions, pressure, axial_force, thickness):
    x = np.asarray(positions, dtype=float)
    if x.ndim != 3 or x.shape[2] != 3:
        raise ValueError(f"positions must have shape (n_steps, n_markers, 3); got {x.shape}")
    n_steps = x.shape[0]
    p = np.asarray(pressure, dtype=float).reshape(-1)
    f = np.asarray(axial_force, dtype=float).reshape(-1)
    if p.shape != (n_steps,) or f.shape != (n_steps,):
        raise ValueError(f"pressure and axial_force must have shape ({n_steps},); got {p.shape} and {f.shape}")
    if n_steps < 2:
        raise DegenerateDataError(f"need a reference step and at least one loaded step; got {n_steps} step(s)")
    # every coordinate finite (a dense cloud: 3.75 M of them at 50,000 points x 25 steps): no step is empty, and
    # the flat reduction is ~10x faster than the per-marker one
    empty = (np.zeros(0, np.intp) if np.isfinite(x).all()
             else np.flatnonzero(~np.any(np.all(np.isfinite(x), axis=-1), axis=-1)))
    if len(empty):
        raise DegenerateDataError(f"steps {empty.tolist()} have no observed marker (all NaN)")
    if not np.all(np.isfinite(p)):
        raise DegenerateDataError(f"pressure is missing (NaN) at steps {np.flatnonzero(~np.isfinite(p)).tolist()}")
    if not np.all(np.isfinite(f)):
        raise DegenerateDataError(
            f"axial force is missing (NaN) at steps {np.flatnonzero(~np.isfinite(f)).tolist()}; the axial "
            "virtual field needs the load-cell force at every step")
    if not np.any(np.abs(p) > 0):
        raise DegenerateDataError("all steps are at zero pressure: the inflation test carries no information")
    if not (np.isfinite(thickness) and thickness > 0):
        raise ValueError(f"thickness must be a positive reference wall thickness in m; got {thickness!r}")
    return x, p, f


@dataclass(frozen=True)
class PrepareSettings:
    """How ``prepare`` builds the balance: every option of ``prepare`` but the data and the thickness.

    The fields and their defaults are ``prepare``'s keywords (documented there); ``prepare(..., settings=s)``
    or ``prepare(..., wall="thick", ...)`` (the keywords override ``settings``).
    """

    wall: str = "membrane"
    ends: str = "clamped"
    fields: VirtualFields | None = None
    mesh: SurfaceMesh | None = None
    reference_step: int = 0
    clamp_radius: float | None = None
    n_layers: int = 4
    quadrature: int = 1
    toward: np.ndarray | None = None
    smoothing: tuple[int, int] | str | None = None
    reject_outliers: bool = True
    marker_weights: np.ndarray | None = None
    smooth_reference: bool = True
    reference_noise_correction: bool = False
    estimate_noise: bool = True
    dense_reuse: DenseQuadrature | None = None
    axes_start: tuple | None = None

    @classmethod
    def from_options(cls, settings: PrepareSettings | None = None, **options) -> PrepareSettings:
        """``settings`` (default: the defaults) with the given keyword ``options`` replacing its fields."""
        unknown = sorted(set(options) - {f.name for f in fields_of(cls)})
        if unknown:
            raise TypeError(f"prepare() got unexpected keyword argument(s) {unknown}; expected the fields of "
                            f"PrepareSettings {[f.name for f in fields_of(cls)]}")
        base = cls() if settings is None else settings
        return replace(base, **options) if options else base


def prepare(
    positions: np.ndarray,
    pressure: np.ndarray,
    axial_force: np.ndarray,
    *,
    thickness: float,
    settings: PrepareSettings | None = None,
    **options,
) -> VFMData:
    """Build the virtual-work balance from measured data.

    Parameters
    ----------
    positions : ndarray, shape (n_steps, n_markers, 3)
        Marker positions (m, world frame), NaN = not observed; ``reference_step`` is stress-free.
    pressure : ndarray, shape (n_steps,)
        Transmural pressure (Pa).
    axial_force : ndarray, shape (n_steps,)
        Axial force carried by the wall at the load-cell end (N).
    thickness : float
        Reference wall thickness e0 (m).
    settings : PrepareSettings, optional
        The options below in one frozen object (default: their defaults).
    **options
        Any field of ``PrepareSettings`` by keyword, replacing the one of ``settings``:
    wall : {"membrane", "thick"}
    ends : {"clamped", "free"}
        "clamped": the tube is tied on cannulae (radius fixed there) beyond the measured region,
        so the pressure on the unmeasured strip is accounted for (``end_force``). "free": the
        measured tube is uniform up to the load cell.
    fields : VirtualFields, optional
        Default: the paper's two fields (``paper_fields``) for ``wall="membrane"``; for ``wall="thick"`` the
        same boundary values with zero axial gradient at the measured ends (``thick_fields.flat_end_fields``).
    mesh : SurfaceMesh, optional
        Default: ``build_mesh`` on the reference step.
    clamp_radius : float, optional
        Radius of the pressurised surface at the load-cell clamp (m); default: the reference
        radius of the top boundary markers (minus e0 for ``wall="thick"``).
    n_layers : int
        Through-thickness Gauss points for ``wall="thick"``.
    quadrature : {1, 3}
        In-plane quadrature points per triangle.
    toward : ndarray, shape (3,), optional
        World direction of the load-cell end (default +z).
    smoothing : (int, int), optional
        Smooth each step's displacement field on Legendre(Z) x Fourier(Theta) of these degrees
        before differentiating (for noisy markers; see ``smoothing.smooth_cylindrical``);
        ``"auto"``: the basis of each component chosen from the data (``smoothing.select_smoothing``)
        unless the markers look exact.
    marker_weights : ndarray, shape (n_steps, n_markers), optional
        Relative weights of the markers in the smoothing fit (1 / variance, e.g. from the
        reconstruction's reported uncertainty); default equal.
    smooth_reference : bool
        With smoothing (default), also replace the reference radius of the markers by its smooth fit
        (``smoothing.smooth_reference_radius``); False: the measured reference radius (before issue 10).
    reference_noise_correction : bool
        With smoothing, remove the errors-in-variables bias of the reference markers' noise
        (``smoothing.regressor_noise_correction``).
    reject_outliers : bool
        Treat markers that disagree with their neighbours in a step (mis-tracked) as unobserved
        there (``outliers.marker_outliers``); counts in ``VFMData.n_outliers``.
    estimate_noise : bool
        False: leave ``VFMData.marker_noise`` NaN when nothing else needs the neighbour-mismatch noise
        estimate (``reject_outliers=False``, smoothing given as degrees): a bootstrap replicate's ~1.5 ms.
    dense_reuse : DenseQuadrature, optional
        On a dense cloud (``dense``: more than ``dense.DENSE_POINTS`` markers, smoothed), the step axes of the
        data a bootstrap replicate re-measures (``VFMData.quadrature``): the replicate, simulated in the data's
        aligned frame, is neither re-aligned nor are its axes refitted.
    axes_start : tuple of Axis, optional
        On a dense cloud, one per step: where every step's axis fit starts (the same minimum in fewer iterations;
        ``gap_jacobian.Reprepare`` starts its re-preparations from the data's, ``VFMData.quadrature.axes``).

    A smoothed cloud of more than ``dense.DENSE_POINTS`` markers is smoothed on all of them and its balance
    evaluated on a quadrature grid of bounded size (``dense``; ``VFMData.quadrature`` says so).
    """
    s = PrepareSettings.from_options(settings, **options)
    wall, ends, fields, mesh, reference_step = s.wall, s.ends, s.fields, s.mesh, s.reference_step
    quadrature, toward, smoothing, reject_outliers = s.quadrature, s.toward, s.smoothing, s.reject_outliers
    marker_weights, smooth_reference = s.marker_weights, s.smooth_reference
    reference_noise_correction, estimate_noise = s.reference_noise_correction, s.estimate_noise
    if wall not in WALLS:
        raise ValueError(f"wall must be one of {WALLS}; got {wall!r}")
    if ends not in ENDS:
        raise ValueError(f"ends must be one of {ENDS}; got {ends!r}")
    x, p, f = _check_inputs(positions, pressure, axial_force, thickness)
    e0 = float(thickness)
    reference = x[reference_step]
    if mesh is None:
        mesh = _cached_mesh(reference, toward)
    if wants_dense(mesh, smoothing, smooth_reference, reference_noise_correction):
        dense = _prepare_dense(x, p, f, e0, mesh, s)
        if dense is not None:
            return dense
    if fields is None:
        fields = default_fields(mesh, wall)
    check_fields(fields, mesh)
    aligned, _, _ = align_steps(x, reference)
    # a bootstrap replicate (estimate_noise=False) is never seen again: not cached (the cache's states hold ~10
    # arrays of shape (n_steps, n_triangles) each: hundreds of MB on dense clouds)
    state = _cached_surface_state if estimate_noise else surface_state
    st = state(mesh, aligned, quadrature, smoothing, reject_outliers, marker_weights,
               smooth_reference=smooth_reference,
               reference_noise_correction=reference_noise_correction, estimate_noise=estimate_noise)
    return balance(st, mesh, fields, p, f, e0, s)


def default_fields(mesh: SurfaceMesh, wall: str) -> VirtualFields:
    """``prepare``'s virtual fields when none are given: for ``wall="thick"`` fields flat at the measured boundaries
    (``thick_fields``: the clamped FE tube's Delfino beta -3.3 % -> -0.9 %); for the membrane the paper's."""
    return flat_end_fields(mesh) if wall == "thick" else paper_fields(mesh)


def balance(st, mesh: SurfaceMesh, fields: VirtualFields, p: np.ndarray, f: np.ndarray, e0: float,
            s: PrepareSettings, *, work_mesh: SurfaceMesh | None = None,
            quadrature: DenseQuadrature | None = None) -> VFMData:
    """The virtual-work balance of the surface state ``st`` (``kinematics.surface_state``), ``prepare``'s second
    half: pressure ``p`` (Pa) and force ``f`` (N) of shape (n_steps,), thickness ``e0`` (m), and of the settings
    ``s`` the wall, ends, n_layers and clamp_radius. ``work_mesh``: the mesh whose triangles ``st`` and the nodes
    ``fields`` are on (default ``mesh``; a dense cloud's quadrature grid, ``quadrature``)."""
    wall, ends = s.wall, s.ends
    work_mesh = mesh if work_mesh is None else work_mesh
    if not st.valid.any(axis=1).all():
        bad = np.flatnonzero(~st.valid.any(axis=1)).tolist()
        raise DegenerateDataError(f"steps {bad} have no triangle with all three markers observed")
    wg = _wall_geometry(fields, work_mesh, st, e0)
    c, work_density, surface = _internal_work_terms(wg, wall, s.n_layers)
    pressure_work, end_work, n_end, strip_force = _external_work(wg, surface, work_mesh, st, fields, p, f, wall, ends,
                                                                 e0, s.clamp_radius)
    evw = pressure_work + end_work
    scale = np.sqrt(np.mean(evw**2, axis=1))
    if np.any(scale <= 0):
        raise DegenerateDataError(f"virtual fields {[n for n, s in zip(fields.names, scale) if s <= 0]} do no "
                                  "external work at any step")
    n_valid = st.valid.sum(axis=1)
    if np.any(n_valid < st.valid.shape[1]):
        log.warning("triangles excluded for unobserved markers per step: %s", (st.valid.shape[1] - n_valid).tolist())
    return VFMData(c=c, work_density=work_density, evw=evw, pressure_work=pressure_work, end_work=end_work,
                   end_force=n_end, scale=scale, field_names=tuple(fields.names), wall=wall, ends=ends, mesh=mesh,
                   n_valid_triangles=n_valid, n_outliers=st.outliers.sum(axis=1),
                   marker_noise=float(np.nanmedian(st.noise)) if np.isfinite(st.noise).any() else float("nan"),
                   smoothing=st.smoothing, pressure=p, axial_force=f,
                   thickness=e0, strip_force=strip_force, quadrature=quadrature)


def _prepare_dense(x, p, f, e0: float, mesh: SurfaceMesh, s: PrepareSettings) -> VFMData | None:
    """``prepare`` of a dense cloud on its quadrature grid (``dense``); None where the full path is needed
    (given fields that depend on more than Z, exact-looking markers)."""
    parts = dense_parts(x, mesh, s)
    return None if parts is None else parts.balanced(p, f, e0, s)


@dataclass(frozen=True)
class DenseParts:
    """A dense cloud as ``prepare`` smoothed it, before the balance (``dense_parts``): the surface state on the
    quadrature grid (``dense.dense_state``: arrays of the grid's 576 triangles, the outliers (n_steps, n_markers)
    bool), how it was evaluated, the mesh, and the virtual fields on the grid of the wall form it was made for.
    ``balanced`` gives the balance of any wall form and ends from it (the efficient weighting's moved sets
    judged under the other wall form, ``efficient.GapCovariance.for_wall``, without their kinematics again)."""

    state: SurfaceState
    quadrature: DenseQuadrature
    mesh: SurfaceMesh
    wall: str
    fields: VirtualFields

    def balanced(self, p: np.ndarray, f: np.ndarray, e0: float, s: PrepareSettings) -> VFMData:
        """``balance`` of the state: readings ``p`` (Pa), ``f`` (N) (n_steps,), thickness ``e0`` (m), settings ``s``
        (its wall, ends, fields, n_layers, clamp_radius); the fields of another wall form built on the grid as
        ``prepare`` builds them."""
        fields = self.fields if s.wall == self.wall else grid_fields(s.fields, self.mesh, quadrature_grid(self.mesh),
                                                                     s.wall)
        if fields is None:
            raise ValueError("the given virtual fields depend on more than Z: no balance on the quadrature grid")
        return balance(self.state, self.mesh, fields, p, f, e0, s, work_mesh=self.quadrature.grid,
                       quadrature=self.quadrature)


def dense_parts(x: np.ndarray, mesh: SurfaceMesh, s: PrepareSettings) -> DenseParts | None:
    """``prepare``'s dense path up to the balance: the smoothed state of the markers ``x`` (n_steps, n_markers, 3)
    m on ``mesh`` with the settings ``s`` (``dense.wants_dense`` holds); None where the full path is needed."""
    if s.fields is not None:
        check_fields(s.fields, mesh)
    fields = grid_fields(s.fields, mesh, quadrature_grid(mesh), s.wall)
    if fields is None:
        log.info("dense cloud: the given virtual fields depend on more than Z; full mesh used")
        return None
    # a bootstrap replicate of a dense cloud is simulated in the data's aligned frame: no rigid motion to remove
    aligned = x if s.dense_reuse is not None else align_steps(x, x[s.reference_step])[0]
    # the same markers again (another wall form, model or the chosen smoothing given): their axes and outliers
    # (a replicate is seen once: not cached)
    key = None if s.dense_reuse is not None else (
        "dense markers", id(mesh), _option_key(aligned),
        s.estimate_noise or s.reject_outliers or isinstance(s.smoothing, str))
    hit = _STATE_CACHE.get(key) if key is not None else None
    if hit is not None and hit[0] is mesh:
        survey = hit[1]
    else:
        survey = marker_survey(mesh, aligned, s.smoothing, s.reject_outliers, s.estimate_noise, s.dense_reuse,
                               s.axes_start)
        if key is not None:
            if len(_STATE_CACHE) >= _STATE_CACHE_SIZE:
                _STATE_CACHE.pop(next(iter(_STATE_CACHE)))
            _STATE_CACHE[key] = (mesh, survey)
    reuse = s.dense_reuse  # a moved set of the efficient weighting keeps the data's reference radius basis
    dense = cached_state(mesh, aligned, s.quadrature, s.smoothing, s.reject_outliers, s.marker_weights, survey,
                         once=reuse is not None and not s.estimate_noise,
                         reference_degree=reuse.reference_degree if reuse is not None and reuse.keep_reference else None)
    if dense is None:
        return None
    st, quadrature = dense
    if not st.valid.any(axis=1).all():
        bad = np.flatnonzero(~st.valid.any(axis=1)).tolist()
        raise DegenerateDataError(f"steps {bad} have no valid quadrature cell")
    return DenseParts(st, quadrature, mesh, s.wall, fields)


#: Meshes of recently seen reference configurations (a reprocessing run meshes the same markers again).
_MESH_CACHE: dict = {}
_MESH_CACHE_SIZE = 8


def _cached_mesh(reference: np.ndarray, toward) -> SurfaceMesh:
    """``build_mesh(reference, toward=toward)``, reused when the same reference markers come again."""
    key = (reference.shape, reference.tobytes(), None if toward is None else np.asarray(toward, float).tobytes())
    mesh = _MESH_CACHE.get(key)
    if mesh is None:
        mesh = build_mesh(reference, toward=toward)
        if len(_MESH_CACHE) >= _MESH_CACHE_SIZE:
            _MESH_CACHE.pop(next(iter(_MESH_CACHE)))
        _MESH_CACHE[key] = mesh
    return mesh


#: Surface states (axes, outliers, kinematics of every step) of recently seen data: reprocessing the
#: same markers with another model or wall form repeats them exactly.
_STATE_CACHE: dict = {}
_STATE_CACHE_SIZE = 4


def _option_key(value):
    """A hashable stand-in for an option value; arrays by their bytes (their repr elides long ones)."""
    if isinstance(value, np.ndarray):
        return (value.shape, value.dtype.str, value.tobytes())
    return repr(value)


def _cached_surface_state(mesh: SurfaceMesh, aligned: np.ndarray, *options, **keywords):
    """``kinematics.surface_state(mesh, aligned, *options, **keywords)``, reused for the same mesh object,
    markers and options.

    The cache holds the mesh it was computed on, so its ``id`` cannot be reused while the entry lives.
    """
    key = (id(mesh), _option_key(np.asarray(aligned)), tuple(_option_key(o) for o in options),
           tuple((k, _option_key(v)) for k, v in sorted(keywords.items())))
    hit = _STATE_CACHE.get(key)
    if hit is not None and hit[0] is mesh:
        st = hit[1]
        if st.outliers.any():  # say it again: this run's reader has not seen the first run's log
            log.warning("markers disagreeing with their neighbours (set unobserved) per step: %s",
                        st.outliers.sum(axis=1).tolist())
        return st
    st = surface_state(mesh, aligned, *options, **keywords)
    if len(_STATE_CACHE) >= _STATE_CACHE_SIZE:
        _STATE_CACHE.pop(next(iter(_STATE_CACHE)))
    _STATE_CACHE[key] = (mesh, st)
    return st


def internal_virtual_work(data: VFMData, model: str | Model, parameters) -> np.ndarray:
    """IVW (J), shape ``(n_fields, n_steps)``, or ``(n_sets, n_fields, n_steps)`` if every parameter
    value is an array of shape ``(n_sets,)``."""
    model = get_model(model)
    vals = {k: np.asarray(parameters[k], dtype=float) for k in model.parameter_names}
    batched = any(v.ndim > 0 for v in vals.values())
    if batched:
        vals = {k: np.reshape(v, (-1, 1, 1)) for k, v in vals.items()}
    c = data.c[None] if batched else data.c
    s11, s22, s12 = pk2_components(model, c[..., 0], c[..., 1], c[..., 2], vals)
    S = np.stack(np.broadcast_arrays(s11, s22, s12), -1)
    if batched:
        return np.einsum("fspc,espc->efs", data.work_density, S)
    return np.einsum("fspc,spc->fs", data.work_density, S)


def virtual_work_basis(data: VFMData, model: str | Model, parameters, *,
                       closed_form: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """IVW of each linear (stress-like) parameter's part of W and its derivatives (variable projection).

    W = sum_l p_l W_l(C; q) with p the model's ``linear`` parameters and q the others, so
    ``IVW = sum_l p_l A_l(q)``. Values of the linear parameters in ``parameters`` are ignored.

    Returns
    -------
    A : ndarray, shape (n_linear, n_fields, n_steps)
        IVW (J) of W_l (that is of W with p_l = 1 and the other linear parameters 0).
    dA : ndarray, shape (n_linear, n_nonlinear, n_fields, n_steps)
        Exact derivatives of ``A`` with respect to the nonlinear parameters, in model order.

    The derivatives come from the shared second-order AD of the strain energy
    (``models.virtual_work_sensitivities``), or from the model's closed form (``Model.work``) when it
    has one and ``closed_form`` is true (both agree to rounding; the closed form is ~10x faster).
    """
    model = get_model(model)
    linear = [n for n, lin in zip(model.parameter_names, model.linear) if lin]
    nonlinear = tuple(n for n, lin in zip(model.parameter_names, model.linear) if not lin)
    n_f, n_s = data.evw.shape
    A = np.zeros((len(linear), n_f, n_s))
    dA = np.zeros((len(linear), len(nonlinear), n_f, n_s))
    closed = _closed_form_work(data, model, parameters, nonlinear) if closed_form else {}
    for i, name in enumerate(linear):
        key = ("constant basis", model.name, name)  # a part of W that no nonlinear parameter enters
        if name in closed:
            A[i], dA[i] = closed[name][0], np.swapaxes(closed[name][1], 0, 1)
            continue
        if key in data.cache:
            A[i] = data.cache[key]
            continue
        chunks = _seeded_chunks(data)
        values = {n: float(parameters[n]) for n in nonlinear}
        values.update({n: float(n == name) for n in linear})
        constant = True
        for seeds in chunks:
            work, d_work, const = virtual_work_sensitivities(model, seeds, values, nonlinear)
            A[i] += work.sum(-1)
            dA[i] += np.swapaxes(d_work.sum(-1), 0, 1)
            constant &= const
        if constant:
            data.cache[key] = A[i].copy()
    return A, dA


def _closed_form_work(data: VFMData, model: Model, parameters, nonlinear: tuple[str, ...]) -> dict:
    """``model.work`` on this data set (features cached on ``data``); {} if the model has none."""
    if model.work is None or model.work_features is None:
        return {}
    key = ("work features", model.name)
    features = data.cache.get(key)
    if features is None:
        w = data.work_density
        features = model.work_features(data.c[..., 0], data.c[..., 1], data.c[..., 2],
                                       2.0 * w[..., 0], 2.0 * w[..., 1], w[..., 2])
        data.cache[key] = features
    return model.work(features, **{n: float(parameters[n]) for n in nonlinear})


#: Quadrature points per block of the derivative evaluation (its arrays then stay in the CPU cache).
CHUNK_POINTS = 4096


def _seeded_chunks(data: VFMData) -> list:
    """The C components seeded with the virtual strains, in blocks of points (cached on ``data``)."""
    chunks = data.cache.get("seeds")
    if chunks is None:
        n_s, n_p = data.c.shape[:2]
        step = max(1, CHUNK_POINTS // n_s)
        chunks = [seed_virtual_strains(data.c[:, j:j + step, 0], data.c[:, j:j + step, 1], data.c[:, j:j + step, 2],
                                       data.work_density[:, :, j:j + step]) for j in range(0, n_p, step)]
        data.cache["seeds"] = chunks
    return chunks
