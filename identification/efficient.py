"""Efficient virtual-work balance: generalised least squares over the full covariance of the gaps (issue 24).

The paper's cost sums the squared gaps ``(IVW - EVW) / scale`` of its two fields at every step with one scale per
field; ``noise_weights`` weights each gap by its own noise. Neither uses how the gaps' errors are correlated: every
displacement is measured from the same reference configuration (its error is shared by all steps), the two fields
of a step see the same kinematics, and the readings' noise grows with the reading. This module builds the full
covariance of the gap vector and fits by generalised least squares (the Gauss-Markov estimator of the given
fields, the linear-noise-optimal weighting of Avril & Pierron 2007 applied to the balance equations), iterated
because the covariance depends on the parameters (the stiffness at the estimate).

The covariance is propagated to first order, not simulated: the smoothed displacement field of a step is a linear
function of its markers, so marker noise reaches the gaps only through the coefficients of the smoothing basis
(covariance ``sigma^2 (B^T B)^-1`` per component and step). The derivative of every gap with respect to every
coefficient comes from re-preparing the data with the field perturbed along that basis function, at all loaded
steps at once (a step's gaps depend only on its own field and the reference), and once more for the reference
configuration (treated as measured: its error enters every step's gaps, hence the correlation across steps); the
rigid basis functions are left out and the re-preparations reuse what the perturbation does not change
(``gap_jacobian``). The readings (pressure, force) enter the external work linearly, with standard deviation
``sqrt((relative x reading)^2 + floor^2)``, their derivatives in closed form. No forward model of the specimen is solved: the balance stays a
virtual fields method and works on heterogeneous data alike.

Units SI; gaps in the optimiser's normalised units (divided by ``VFMData.scale``).
"""

from __future__ import annotations

import copy
import dataclasses
import logging
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from .dense import DENSE_POINTS
from .checks import with_ends
from .errors import IdentificationError
from .fit import identify_prepared
from .gap_jacobian import Reprepare, reading_sensitivities, rigid_columns
from .perturbed_sets import concatenate_works, perturbed_works, set_works
from .kinematics import align_steps
from .resimulation import basis_size, fitted_positions, marker_noise_level, remeasured_mesh
from .smoothing import smoothing_basis
from .vfm import DenseParts, PrepareSettings, VFMData, default_fields, internal_virtual_work

__all__ = ["NOISE_FLOOR", "EfficientSettings", "GapCovariance", "floored", "whitening_matrix"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class EfficientSettings:
    """Noise model and iterations of ``weighting="efficient"``.

    Attributes
    ----------
    pressure_relative, force_relative : float
        Standard deviation of a reading as a fraction of the reading (default 0.1 %).
    pressure_floor : float
        Pa, added in quadrature (default 3 Pa).
    force_floor : float
        N, added in quadrature (default 2 mN).
    marker_sigma : float or ndarray of shape (n_steps, n_markers), optional
        Per-coordinate marker noise (m), e.g. what the reconstruction reports per marker and step; default: the
        level the data show (``resimulation.marker_noise_level``).
    refine_reference : bool
        Estimate every marker's material coordinates from all steps (``reference.refine_reference``) instead of
        taking the reference step's measured positions as exact.
    reference_degree : (int, int)
        The reference configuration's error is propagated on a basis of at least these (axial degree, harmonics).
    reference_replicates : int
        The reference step's share of the covariance from this many re-measurements of the reference markers
        (their noise reaches the gaps beyond first order and outside the smoothing basis: the linear modes gave
        70 % of the axial field's measured standard deviation); 0: linearised on the smoothing basis.
    seed : int
        Of the re-measurements.
    n_iterations : int
        Generalised least-squares fits, each with the covariance at the previous estimate (default 2).
    step : float
        Finite-difference step of the perturbed fields (m) and of the readings (relative).
    """

    pressure_relative: float = 1e-3
    pressure_floor: float = 3.0
    force_relative: float = 1e-3
    force_floor: float = 2e-3
    marker_sigma: float | np.ndarray | None = None
    refine_reference: bool = False
    reference_degree: tuple[int, int] = (0, 0)
    reference_replicates: int = 0
    seed: int = 0
    n_iterations: int = 2
    step: float = 1e-6

    def __post_init__(self) -> None:
        for name in ("pressure_relative", "pressure_floor", "force_relative", "force_floor"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a finite number >= 0; got {v!r}")
        if int(self.n_iterations) < 1:
            raise ValueError(f"n_iterations must be >= 1; got {self.n_iterations!r}")
        if not (self.step > 0):
            raise ValueError(f"step must be > 0; got {self.step!r}")


def _directions(mesh, aligned: np.ndarray) -> np.ndarray:
    """Unit vectors (radial, circumferential, axial) of every marker at every step, world frame:
    shape (3, n_steps, n_markers, 3)."""
    basis, origin = mesh.axis.basis, mesh.axis.origin
    local = (aligned - origin) @ basis.T
    th = np.arctan2(local[..., 1], local[..., 0])
    if aligned.shape[1] > DENSE_POINTS:  # written out: 6x faster than the stacks and the product (0.9 s at 50,000
        c, s = np.cos(th), np.sin(th)  # points x 25 steps), equal to 1e-16; below, the products of stored results
        out = np.empty((3,) + th.shape + (3,))
        for j in range(3):
            out[0, ..., j] = c * basis[0, j] + s * basis[1, j]
            out[1, ..., j] = -s * basis[0, j] + c * basis[1, j]
            out[2, ..., j] = basis[2, j]
        return np.nan_to_num(out, copy=False)
    zero = np.zeros_like(th)
    e = np.stack([np.stack([np.cos(th), np.sin(th), zero], -1), np.stack([-np.sin(th), np.cos(th), zero], -1),
                  np.stack([zero, zero, np.ones_like(th)], -1)])
    return np.nan_to_num(e @ basis)


class GapCovariance:
    """First-order covariance of the normalised gaps of ``data`` (shape (n_res, n_res), n_res = n_fields n_steps).

    Built once: the readings' part in closed form, the markers' from the perturbed preparations (per non-rigid
    smoothing basis function, the loaded steps moved, all functions prepared together, and the reference moved, one
    ``prepare`` each; ``perturbed_sets``, ``gap_jacobian``, computed in this process);
    ``at(params)`` then evaluates the covariance at any parameters with a few virtual-work evaluations.
    """

    def __init__(self, data: VFMData, positions: np.ndarray, settings: EfficientSettings,
                 prepare_options: Mapping | None = None):
        self.data, self.settings = data, settings
        opts = dict(prepare_options or {})
        for k in ("mesh", "smoothing", "reject_outliers", "marker_weights", "estimate_noise", "wall", "ends"):
            opts.pop(k, None)
        opts.update(wall=data.wall, ends=data.ends, smoothing=data.smoothing, reject_outliers=False,
                    estimate_noise=False)
        x = np.asarray(positions, dtype=float)
        aligned, _, _ = align_steps(x, x[0])
        p, f = data.pressure, data.axial_force
        prep = Reprepare(data, aligned, PrepareSettings.from_options(opts.pop("settings", None), **opts))
        # the data as prepared for the fit serve as the unperturbed set when they were prepared alike (no markers
        # rejected as outliers, equal weights): the same numbers to rounding, one ``prepare`` saved
        given = PrepareSettings.from_options(**{k: v for k, v in dict(prepare_options or {}).items()
                                                if k in ("settings", "marker_weights", "reference_noise_correction")})
        alike = not np.any(data.n_outliers) and given.marker_weights is None and not given.reference_noise_correction
        # a dense cloud: every moved set's smoothed state kept per job (its kind, its sets' ``vfm.DenseParts``) with
        # the settings they were prepared with; the other wall form's covariance comes from them (``for_wall``)
        self.dense_jobs: list | None = [] if data.quadrature is not None else None
        self.dense_settings: PrepareSettings = prep.settings
        self.base: VFMData = data
        self.base_parts: DenseParts | None = None
        if not alike:
            self.base, self.base_parts = self._prepared(prep, aligned, p)
        loaded = np.arange(p.size) > 0
        self.sp = np.hypot(settings.pressure_relative * p, settings.pressure_floor) * loaded
        self.sf = np.hypot(settings.force_relative * f, settings.force_floor) * loaded
        self.readings = self._reading_gaps(prep, aligned, p)  # (n_f, n_s) each: d gap / d reading x its sigma
        # the markers: per component, (coefficient covariance (n_steps or 1, n_b, n_b), loaded?, its columns)
        self.modes: list[tuple] = []
        self.loaded: list[VFMData] = []  # the loaded steps moved per loaded column, set-major, per job (``perturbed_sets``)
        self.reference: list[VFMData] = []  # every step per reference column, set-major, per job
        self.reference_sets: list[VFMData] = []  # re-measured references (``reference_replicates``)
        if data.smoothing is None:
            log.info("efficient weighting of unsmoothed data: the readings' noise only")
            self.dense_jobs = None
            return
        sigma = self._marker_sigma(positions)
        e = _directions(data.mesh, aligned)
        ok = data.mesh.used & np.all(np.isfinite(aligned), axis=-1).all(axis=0)
        moves = []  # the loaded steps' smoothing coefficients: the moves of steps 1.. per column
        for j, degree in enumerate(data.smoothing):
            cov, B, keep = _coefficient_covariance(data.mesh, degree, ok, sigma, j)
            moves += [settings.step * B[:, i, None] * e[j, 1:] for i in np.flatnonzero(keep)]
            self.modes.append((cov[:, keep][:, :, keep] * loaded[:, None, None], True, int(keep.sum())))
        if settings.reference_replicates:  # the reference configuration: its error is shared by all steps
            self.loaded = perturbed_works(prep, aligned, moves, [])[0]
            rng = np.random.default_rng(settings.seed)
            for _ in range(int(settings.reference_replicates)):
                ref = aligned.copy()
                ref[0] += sigma[0][:, None] * rng.standard_normal(ref[0].shape)
                self.reference_sets.append(prep(ref, m=remeasured_mesh(data.mesh, ref[0])))
            self.dense_jobs = None
            return
        columns = []  # linearised on a basis of at least ``reference_degree``
        for j, degree in enumerate(data.smoothing):
            degree = (max(degree[0], settings.reference_degree[0]), max(degree[1], settings.reference_degree[1]))
            cov, B, keep = _coefficient_covariance(data.mesh, degree, ok, sigma[:1], j)
            columns += [settings.step * B[:, i, None] * e[j, 0] for i in np.flatnonzero(keep)]
            self.modes.append((cov[:, keep][:, :, keep], False, int(keep.sum())))
        self.loaded, self.reference = perturbed_works(prep, aligned, moves, columns, self.dense_jobs)

    def _prepared(self, prep: Reprepare, aligned: np.ndarray, p: np.ndarray) -> tuple[VFMData, DenseParts | None]:
        """``prep(aligned, p)`` and, of a dense cloud, its smoothed state (``Reprepare.prepared``), else None."""
        if self.dense_jobs is None:
            return prep(aligned, p), None
        return prep.prepared(aligned, p, self.data.axial_force, self.data.mesh)

    def _reading_gaps(self, prep: Reprepare, aligned, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The gaps' derivatives with respect to the pressure and force readings times their standard deviations,
        (n_fields, n_steps) each, in closed form (``gap_jacobian.reading_sensitivities``)."""
        s = prep.s
        self.load_end = (s.fields if s.fields is not None else default_fields(self.data.mesh, self.data.wall)).load_end
        zero = p == 0
        self.unit: VFMData | None = None
        self.unit_parts: DenseParts | None = None
        if zero[1:].any():
            self.unit, self.unit_parts = self._prepared(prep, aligned, np.where(zero, 1.0, p))
        return self._scaled_readings()

    def _scaled_readings(self) -> tuple[np.ndarray, np.ndarray]:
        d_pressure, d_force = reading_sensitivities(self.base, self.load_end, self.unit)
        scale = self.data.scale[:, None]
        return -d_pressure / scale * self.sp, -d_force / scale * self.sf

    def for_ends(self, data: VFMData) -> "GapCovariance":
        """The covariance of ``data``: this one's data with the other end condition (``checks.with_ends``), from
        the same moved sets (the end condition changes only the force across the load end, by the clamped ends'
        strip force, which every moved set carries: no re-preparation)."""
        if data.ends == self.data.ends:
            return self
        out = copy.copy(self)
        sign = 1.0 if data.ends == "clamped" else -1.0  # clamped: end force = reading + strip force

        def moved(d: VFMData) -> VFMData:
            strip = np.zeros(d.evw.shape[1]) if d.strip_force is None else d.strip_force
            return dataclasses.replace(d, evw=d.evw + sign * np.asarray(self.load_end)[:, None] * strip[None],
                                       ends=data.ends)

        out.data = data
        out.base = data if self.base is self.data else with_ends(self.base, data.ends)
        out.unit = None if self.unit is None else with_ends(self.unit, data.ends)
        out.loaded, out.reference = [moved(d) for d in self.loaded], [moved(d) for d in self.reference]
        out.reference_sets = [with_ends(d, data.ends) for d in self.reference_sets]
        out.readings = out._scaled_readings()
        return out

    def for_wall(self, data: VFMData) -> "GapCovariance | None":
        """The covariance of ``data``: these markers prepared with the other wall form (any ends), from the moved
        sets' smoothed states (a dense cloud's ``vfm.DenseParts``: only the balance again, with that wall's
        settings and fields), equal to one built afresh; None where it cannot be derived (no dense cloud, the
        reference re-measured, a set on the full path, other readings or mesh): build it."""
        if data.wall == self.data.wall:
            return self.for_ends(data)
        jobs, base, unit, d0 = self.dense_jobs, self.base_parts, self.unit_parts, self.data
        if (jobs is None or any(parts is None for _, sets in jobs for parts in sets) or data.mesh is not d0.mesh
                or data.smoothing != d0.smoothing or data.thickness != d0.thickness
                or not (np.array_equal(data.pressure, d0.pressure) and np.array_equal(data.axial_force,
                                                                                        d0.axial_force))):
            return None
        if (base is None and self.base is not d0) or (unit is None and self.unit is not None):
            return None
        s = dataclasses.replace(self.dense_settings, wall=data.wall, ends=data.ends)

        def balanced(parts, p=data.pressure) -> VFMData:
            return parts.balanced(p, data.axial_force, float(data.thickness), s)

        def works(kind: str, sets: list) -> VFMData:
            c, wd, evw, strip = concatenate_works([set_works(balanced(parts), kind) for parts in sets])
            return dataclasses.replace(data, c=c, work_density=wd, evw=evw, strip_force=strip)

        out = copy.copy(self)
        out.data = data
        with np.errstate(all="ignore"):
            out.base = data if base is None else balanced(base)
            out.unit = None if unit is None else balanced(unit, np.where(data.pressure == 0, 1.0, data.pressure))
            out.loaded = [works(kind, sets) for kind, sets in jobs if kind == "loaded"]
            out.reference = [works(kind, sets) for kind, sets in jobs if kind == "reference"]
        out.load_end = (s.fields if s.fields is not None else default_fields(data.mesh, data.wall)).load_end
        out.readings = out._scaled_readings()
        return out

    def _marker_sigma(self, positions) -> np.ndarray:
        """Per-coordinate marker noise (m), shape (n_steps, n_markers)."""
        shape = (self.data.n_steps, self.data.mesh.n_markers)
        given = self.settings.marker_sigma
        if given is not None:
            s = np.broadcast_to(np.asarray(given, dtype=float), shape)
            if not np.all(np.isfinite(s) & (s >= 0)):
                raise ValueError(f"marker_sigma must be finite and >= 0, shape () or {shape}")
            return np.array(s)
        _, residual = fitted_positions(self.data, positions)
        return np.full(shape, marker_noise_level(self.data, residual, basis_size(self.data.smoothing)))

    def _gaps(self, d: VFMData, params) -> np.ndarray:
        return (internal_virtual_work(d, self.model, params) - d.evw) / self.data.scale[:, None]

    def _stacked_gaps(self, parts: list[VFMData], params) -> np.ndarray:
        return np.concatenate([self._gaps(d, params) for d in parts], axis=1)

    def at(self, model, params: Mapping[str, float]) -> np.ndarray:
        """Covariance (n_res, n_res) of the normalised gaps (field-major ravel of (n_fields, n_steps))."""
        self.model = model
        n_f, n_s = self.data.evw.shape
        g0 = self._gaps(self.base, params)
        cov = np.zeros((n_f, n_s, n_f, n_s))
        gp, gf = self.readings  # readings: independent per step
        step_cov = np.einsum("ks,ls->skl", gp, gp) + np.einsum("ks,ls->skl", gf, gf)
        n_loaded = sum(n for _, is_loaded, n in self.modes if is_loaded)
        G = H = None
        if self.loaded:  # the loaded steps' own noise: (f, s, b), the reference step's column 0
            g = self._stacked_gaps(self.loaded, params).reshape(n_f, n_loaded, n_s - 1)
            G = np.zeros((n_f, n_s, n_loaded))
            G[:, 1:] = np.swapaxes(g - g0[:, None, 1:], 1, 2) / self.settings.step
        if self.reference:  # the reference's noise, shared by all steps: (f, s, b)
            h = self._stacked_gaps(self.reference, params).reshape(n_f, -1, n_s)
            H = np.swapaxes(h - g0[:, None], 1, 2) / self.settings.step
        first = {True: 0, False: 0}
        for c_b, is_loaded, n in self.modes:
            cols = slice(first[is_loaded], first[is_loaded] + n)
            first[is_loaded] += n
            if is_loaded and G is not None:
                step_cov += np.einsum("ksb,sbc,lsc->skl", G[..., cols], c_b, G[..., cols])
            elif not is_loaded and H is not None:
                cov += np.einsum("ksb,bc,ltc->kslt", H[..., cols], c_b[0], H[..., cols])
        if self.reference_sets:  # re-measured references: their spread about the data (n_f, n_s)
            D = np.stack([(self._gaps(d, params) - g0).ravel() for d in self.reference_sets])
            cov += (D.T @ D / len(D)).reshape(n_f, n_s, n_f, n_s)
        idx = np.arange(n_s)
        cov[:, idx, :, idx] += step_cov
        cov[:, 0], cov[:, :, :, 0] = 0.0, 0.0  # the reference step: no load, no information (its gap ~ 0)
        return cov.reshape(n_f * n_s, n_f * n_s)


def _coefficient_covariance(mesh, degree, ok: np.ndarray, sigma: np.ndarray, component: int):
    """Covariance of the smoothing coefficients of one component (0, 1, 2: radial, circumferential, axial),
    ``sigma^2 (B^T B)^-1`` per step (shape (n_steps, n_b, n_b), sigma (n_steps, n_markers) m per coordinate), the
    basis B (n_markers, n_b) and the columns whose perturbation can change a gap (n_b,) bool: all but the rigid
    ones of the circumferential and axial components (``gap_jacobian.rigid_columns``), on the markers ``ok``."""
    B, ok_ref = smoothing_basis(mesh, degree)
    use = ok & ok_ref
    Bu = B[use]
    pinv = np.linalg.solve(Bu.T @ Bu, Bu.T)  # coefficients of a field sampled at the used markers
    cov = np.einsum("bn,sn,cn->sbc", pinv, sigma[:, use] ** 2, pinv)
    return cov, B, ~rigid_columns(B, use) if component > 0 else np.ones(B.shape[1], bool)


#: Smallest standard deviation of a loaded step's gap (fraction of the field's external-work scale): the
#: discretisation of the balance, added in quadrature where the gaps are judged (the verdict, ``setting_noise``);
#: not in the fit's own weighting nor its intervals (there it widened Delfino's at 0.17 mm by half:
#: docs/validation/trust.md, last section).
NOISE_FLOOR = 1e-3


def floored(cov: np.ndarray, n_steps: int) -> np.ndarray:
    """``cov`` (n_res, n_res) of the normalised gaps (field-major, ``n_steps`` per field) with ``NOISE_FLOOR``
    squared added to the variance of every loaded step's gap (a copy)."""
    out = np.array(cov, dtype=float)
    loaded = np.flatnonzero(np.tile(np.arange(n_steps) > 0, out.shape[0] // n_steps))
    out[loaded, loaded] += NOISE_FLOOR**2
    return out


def whitening_matrix(cov: np.ndarray, floor: float = 1e-10) -> np.ndarray:
    """W (n, n) with ``W cov W^T = I`` on the gaps that carry noise; zero rows for those that carry none (the
    reference step's gaps vanish identically)."""
    var = np.diag(cov)
    keep = var > floor * max(float(var.max()), 1e-300)
    W = np.zeros_like(cov)
    sub = cov[np.ix_(keep, keep)]
    d = np.sqrt(np.diag(sub))
    try:
        L = np.linalg.cholesky(sub / np.outer(d, d) + 1e-12 * np.eye(len(d)))
    except np.linalg.LinAlgError as exc:
        raise IdentificationError(f"the gaps' covariance is not positive definite: {exc}") from exc
    W[np.ix_(keep, keep)] = np.linalg.solve(L, np.diag(1.0 / d))
    return W


def identify_efficient(first, positions, model, settings: EfficientSettings | None = None,
                       prepare_options: Mapping | None = None, covariance: GapCovariance | None = None):
    """Generalised least squares from the paper's fit ``first`` (an ``IdentificationResult`` of ``identify`` on
    ``positions``, shape (n_steps, n_markers, 3), the steps it used): ``settings.n_iterations`` fits, each with the
    gaps' covariance at the previous estimate. ``covariance``: the ``GapCovariance`` of these data and settings
    when already built (the verdict's, ``setting_noise``). Returns (result with whitened residuals, the last
    whitening); the whitening is None for exact data."""
    settings = settings or EfficientSettings()
    data = first.data
    cov = covariance if covariance is not None else GapCovariance(data, positions, settings, prepare_options)
    params, result, W = dict(first.parameters), None, None
    for _ in range(int(settings.n_iterations)):
        sigma = cov.at(model, params)
        if not np.any(np.diag(sigma) > 0):  # exact markers and readings: nothing to weight, the paper's fit stands
            log.info("efficient weighting: the gaps carry no noise (exact data); the paper's fit is kept")
            return first, None
        W = whitening_matrix(sigma)
        result = identify_prepared(data, model, initial=params, n_starts=1, whitening=W)
        params = result.parameters
    if result is None:
        raise IdentificationError(f"n_iterations must be >= 1; got {settings.n_iterations!r}")
    return dataclasses.replace(result, smoothing=data.smoothing, data=data, steps=first.steps), W
