"""Derivatives of the virtual-work gaps with respect to the measurements, for ``efficient.GapCovariance``.

The gaps ``(IVW - EVW) / scale`` of a prepared data set depend on the readings linearly (through the external
work) and on the markers through the smoothed displacement field. This module gives

- the readings' part in closed form (``reading_sensitivities``): ``EVW = p W_p + load_end N`` with ``W_p`` the
  virtual work of a unit pressure and ``N = F + p (A_loop - A_clamp)`` (clamped ends) or ``F`` (free ends), so
  ``dEVW/dp = W_p + load_end dN/dp`` and ``dEVW/dF = load_end``, read off the data set itself (one re-preparation
  at unit pressure only if a loaded step was read at exactly zero pressure);
- the markers' part by finite differences along the smoothing basis functions (module ``perturbed_sets``; the
  moved loaded steps of all functions prepared together, ``Reprepare.stacked``), **leaving out the rigid ones** (``rigid_columns``): a uniform circumferential or axial
  displacement of a step (a rotation about, a translation along the axis) is removed by the rigid alignment of
  ``prepare`` (Kabsch) and leaves every gap unchanged (measured: its finite difference is the step's truncation
  error, 1e-4 of the radial mode's at 0.17 mm), so its preparation is saved;
- the preparations themselves (``Reprepare``): ``prepare``'s steps on the moved markers, reusing what the move does
  not change: each moved step's axis fit starts from the unmoved step's axis (the same minimum in fewer
  iterations), the axis of a step whose markers did not move is the unmoved one carried along with the rigid
  alignment (a moved reference moves the other steps only rigidly), the smooth reference radius and the virtual
  fields of an unmoved reference are computed once.

Units SI; shapes in the docstrings.
"""

from __future__ import annotations


import numpy as np

from .axis import Axis
from .dense import perturbation_settings, wants_dense
from .kinematics import align_steps, cylindrical_about, interpolated_state, step_cylindrical
from .mesh import SurfaceMesh
from .smoothing import smooth_cylindrical, smooth_reference_radius
from .step_axes import refit_axes
from .vfm import DenseParts, PrepareSettings, VFMData, balance, default_fields, dense_parts, prepare

__all__ = ["Reprepare", "reading_sensitivities", "rigid_columns"]

#: A basis column is constant (a rigid motion along a circumferential or axial direction) when its spread over the
#: used markers is below this fraction of its largest value.
CONSTANT_COLUMN = 1e-12


def reading_sensitivities(data: VFMData, load_end: np.ndarray,
                          unit: VFMData | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Derivatives of the external work with respect to the pressure and the force readings of each step.

    ``EVW = p W_p + load_end N`` with ``N - F`` proportional to p, so ``dEVW/dp = (EVW - load_end F) / p`` and
    ``dEVW/dF = load_end`` (``load_end`` (n_fields,): the virtual fields' axial translation of the load end).
    At a step read at exactly zero pressure the unit pressure's work comes from ``unit``: the data set prepared
    from the same positions with 1 Pa at those steps (the readings elsewhere). Returns ``(dEVW/dp (J/Pa),
    dEVW/dF (J/N))``, each of shape (n_fields, n_steps): a step's work depends on its own readings only.
    """
    p = data.pressure
    zero = p == 0
    load_end = np.asarray(load_end, dtype=float)[:, None]

    def per_pascal(d: VFMData, q: np.ndarray) -> np.ndarray:
        return (d.pressure_work + load_end * (d.end_force - d.axial_force)[None]) / q

    d_pressure = per_pascal(data, np.where(zero, 1.0, p))
    if zero[1:].any():
        if unit is None:
            raise ValueError(f"steps {np.flatnonzero(zero[1:]) + 1} were read at zero pressure: unit must be the data "
                             "prepared with 1 Pa there")
        d_pressure[:, zero] = per_pascal(unit, np.where(zero, 1.0, p))[:, zero]
    return d_pressure, np.broadcast_to(load_end, data.evw.shape).copy()


def rigid_columns(basis: np.ndarray, use: np.ndarray) -> np.ndarray:
    """Columns of ``basis`` (n_markers, n_b) constant over the ``use``d markers (n_markers,) bool: shape (n_b,)."""
    b = basis[use]
    spread = np.ptp(b, axis=0)
    return spread <= CONSTANT_COLUMN * np.maximum(np.abs(b).max(axis=0), 1e-300)


class Reprepare:
    """``prepare(positions, pressure, force, thickness=data.thickness, mesh=mesh, settings=settings)`` for positions
    close to ``aligned`` (n_steps, n_markers, 3) m, the unmoved markers of ``data`` rigidly aligned on their
    reference step: the same data set (to the axis fits' convergence, ~1e-12 relative), in about half the time.

    Without smoothing, with outlier rejection, marker weights, the reference-noise correction, a reference step
    other than 0 or a dense cloud (``dense``) it is ``prepare`` itself.
    """

    def __init__(self, data: VFMData, aligned: np.ndarray, settings: PrepareSettings):
        self.data, self.s = data, settings
        s = settings
        # a dense cloud (``data.quadrature``): ``prepare`` itself, whose balance is on the same quadrature grid
        self.lean = (isinstance(s.smoothing, tuple) and s.marker_weights is None and not s.reject_outliers
                     and not s.reference_noise_correction and not s.estimate_noise and s.reference_step == 0
                     and data.quadrature is None)
        if not self.lean:
            return
        mesh = data.mesh
        x, rotation, translation = align_steps(aligned, aligned[0])
        self.aligned, self.alignment = aligned, (rotation, translation)
        self.axes = step_cylindrical(mesh, x)[3]  # where the moved steps' axis fits start
        self.reference_radius = smooth_reference_radius(mesh) if s.smooth_reference else mesh.r
        self.fields = s.fields if s.fields is not None else default_fields(mesh, s.wall)

    def __call__(self, positions: np.ndarray, pressure: np.ndarray | None = None, force: np.ndarray | None = None,
                 m: SurfaceMesh | None = None) -> VFMData:
        """The data set of ``positions`` (n_steps, n_markers, 3) m, readings (n_steps,) Pa and N (default the data's)
        on the mesh ``m`` (default the data's: a re-measured reference brings its own)."""
        d = self.data
        p = d.pressure if pressure is None else np.asarray(pressure, dtype=float)
        f = d.axial_force if force is None else np.asarray(force, dtype=float)
        mesh = d.mesh if m is None else m
        with np.errstate(all="ignore"):
            if not self.lean:
                return self.prepared(positions, p, f, mesh)[0]
            return self._lean(np.asarray(positions, dtype=float), p, f, mesh)

    def prepared(self, positions: np.ndarray, p: np.ndarray, f: np.ndarray,
                 mesh: SurfaceMesh) -> tuple[VFMData, DenseParts | None]:
        """``prepare`` itself (not ``lean``), and for a dense cloud the smoothed state it balanced
        (``vfm.DenseParts``: the balance of the other wall form from it, ``efficient.GapCovariance.for_wall``;
        None on the full path)."""
        d, s = self.data, self.settings
        with np.errstate(all="ignore"):
            if d.quadrature is not None and wants_dense(mesh, s.smoothing, s.smooth_reference,
                                                         s.reference_noise_correction):
                parts = dense_parts(np.asarray(positions, dtype=float), mesh, s)
                if parts is not None:
                    return parts.balanced(p, f, float(d.thickness), s), parts
            return prepare(positions, p, f, thickness=d.thickness, mesh=mesh, settings=s), None

    @property
    def settings(self) -> PrepareSettings:
        """The settings of ``prepare``: a dense cloud's on the data's alignment and axes (``dense``)."""
        q = self.data.quadrature
        return self.s if self.lean or q is None else perturbation_settings(self.s, q)

    def stacked(self, loaded: np.ndarray) -> VFMData:
        """One data set of the unmoved reference step and the loaded steps of several moved sets, set-major:
        loaded (n_sets, n_steps - 1, n_markers, 3) m, positions of steps 1.. (the reference unmoved); returns
        the data set of 1 + n_sets (n_steps - 1) steps whose step ``1 + i (n_steps - 1) + k`` is step ``k + 1``
        of set i as ``self(positions)`` gives it (every step is prepared on its own: the same numbers to the
        axis fits' convergence), in one vectorised pass. ``lean`` only."""
        if not self.lean:
            raise ValueError("stacked needs the lean settings (smoothing, no outliers, weights or noise estimate)")
        n_sets, n_loaded = loaded.shape[:2]
        origin = np.concatenate([[0], np.tile(np.arange(1, n_loaded + 1), n_sets)])
        positions = np.concatenate([self.aligned[:1], np.asarray(loaded, dtype=float).reshape(-1, *loaded.shape[2:])])
        d = self.data
        with np.errstate(all="ignore"):
            return self._lean(positions, d.pressure[origin], d.axial_force[origin], d.mesh, origin)

    def _lean(self, positions: np.ndarray, p: np.ndarray, f: np.ndarray, mesh: SurfaceMesh,
              origin: np.ndarray | None = None) -> VFMData:
        """``prepare``'s steps for the settings ``lean`` allows (``surface_state`` without outliers, weights or
        noise estimate, then ``vfm.balance``); ``origin`` (n_positions,): the step of the data each position
        step stands for (default: the same)."""
        s, same = self.s, mesh is self.data.mesh
        x, rotation, translation = align_steps(positions, positions[0])
        axes = self._axes(positions, x, rotation, translation, mesh,
                          np.arange(len(positions)) if origin is None else origin)
        r, th, z = cylindrical_about(x, axes)
        r, th, z = smooth_cylindrical(mesh, r, th, z, s.smoothing)
        reference_radius = mesh.r
        if s.smooth_reference:
            reference_radius = self.reference_radius if same else smooth_reference_radius(mesh)
            r = r + (reference_radius - mesh.r)[None]
        about = dict(outliers=np.zeros(r.shape, bool), noise=np.full(r.shape[0], np.nan), axes=tuple(axes),
                     smoothing=self.data.smoothing)
        st = interpolated_state(mesh, (r, th, z), reference_radius, s.quadrature, about)
        fields = self.fields if same or s.fields is not None else default_fields(mesh, s.wall)
        return balance(st, mesh, fields, p, f, self.data.thickness, s)

    def _axes(self, positions, x, rotation, translation, mesh: SurfaceMesh, origin: np.ndarray) -> list[Axis]:
        """Each step's axis (``step_cylindrical``'s): refitted for the steps whose markers moved, starting from the
        unmoved axis; carried along with the alignment for the others (their markers only moved rigidly with the
        reference, and the fit's minimum moves with them: ``_carried``). positions, x (n_steps, n_markers, 3) m,
        the moved markers before and after their alignment by ``rotation`` (n_steps, 3, 3), ``translation``;
        origin (n_steps,) the unmoved step each step stands for."""
        unmoved = self.aligned[origin]
        same = (positions == unmoved) | (np.isnan(positions) & np.isnan(unmoved))
        moved = ~same.all(axis=(1, 2))
        rotation0, translation0 = self.alignment[0][origin], self.alignment[1][origin]
        axes = [self.axes[k] for k in origin]
        for k in np.flatnonzero(~moved):
            turn = rotation[k] @ rotation0[k].T  # from the unmoved step's aligned frame to this one
            axes[k] = (mesh.axis if axes[k] is self.data.mesh.axis else
                       _carried(axes[k], turn, translation[k] - turn @ translation0[k], mesh.axis))
        if moved.any():
            observed = np.all(np.isfinite(x[moved]), axis=-1) & mesh.used
            start = [axes[k] for k in np.flatnonzero(moved)]
            for k, axis in zip(np.flatnonzero(moved), refit_axes(x[moved], observed, mesh.axis, start=start)):
                axes[k] = axis
        return axes


def _carried(axis: Axis, turn: np.ndarray, shift: np.ndarray, initial: Axis) -> Axis:
    """``axis`` fitted to markers that then moved rigidly (``turn`` (3, 3), ``shift`` (3,) m): the axis the fit finds
    for the moved markers, framed as ``step_axes.axes_from`` frames it (pointing along ``initial``, x' from its x')."""
    d = turn @ axis.direction
    d = -d if d @ initial.direction < 0 else d
    x_hint = initial.basis[0]
    x_axis = x_hint - (d @ x_hint) * d
    x_axis /= np.linalg.norm(x_axis)
    return Axis(origin=turn @ axis.origin + shift, basis=np.stack([x_axis, np.cross(d, x_axis), d]),
                radius=axis.radius, rms=axis.rms)
