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
configuration (treated as measured: its error enters every step's gaps, hence the correlation across steps). The
readings (pressure, force) enter the external work linearly, with standard deviation
``sqrt((relative x reading)^2 + floor^2)``. No forward model of the specimen is solved: the balance stays a
virtual fields method and works on heterogeneous data alike.

Units SI; gaps in the optimiser's normalised units (divided by ``VFMData.scale``).
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from .errors import IdentificationError
from .fit import identify_prepared
from .kinematics import align_steps
from .resimulation import basis_size, fitted_positions, marker_noise_level, remeasured_mesh
from .smoothing import smoothing_basis
from .vfm import VFMData, internal_virtual_work, prepare

__all__ = ["EfficientSettings", "GapCovariance", "whitening_matrix"]

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
    zero = np.zeros_like(th)
    e = np.stack([np.stack([np.cos(th), np.sin(th), zero], -1), np.stack([-np.sin(th), np.cos(th), zero], -1),
                  np.stack([zero, zero, np.ones_like(th)], -1)])
    return np.nan_to_num(e @ basis)


class GapCovariance:
    """First-order covariance of the normalised gaps of ``data`` (shape (n_res, n_res), n_res = n_fields n_steps).

    Built once from the perturbed preparations (about ``2 x basis size + 2`` calls of ``prepare``); ``at(params)``
    then evaluates the covariance at any parameters with a few virtual-work evaluations.
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
        mesh = data.mesh

        def prep(pos, pressure=p, force=f, m=mesh):
            with np.errstate(all="ignore"):
                return prepare(pos, pressure, force, thickness=data.thickness, mesh=m, **opts)

        self.base = prep(aligned)
        eps = settings.step
        # the readings: all loaded steps at once (a step's external work depends on its own readings only)
        dp = eps * np.maximum(np.abs(p), 100.0)
        df = eps * np.maximum(np.abs(f), 0.1)
        self.d_pressure, self.d_force = prep(aligned, p + dp), prep(aligned, force=f + df)
        self.dp, self.df = dp, df
        self.sp = np.hypot(settings.pressure_relative * p, settings.pressure_floor) * (np.arange(p.size) > 0)
        self.sf = np.hypot(settings.force_relative * f, settings.force_floor) * (np.arange(p.size) > 0)
        # the markers: the smoothing coefficients of the loaded steps and of the reference
        self.modes: list[tuple] = []  # (component basis covariance (n_b, n_b), [loaded VFMData], [reference VFMData])
        self.reference_sets: list[VFMData] = []  # re-measured references (``reference_replicates``)
        if data.smoothing is None:
            log.info("efficient weighting of unsmoothed data: the readings' noise only")
            return
        sigma = self._marker_sigma(positions)
        e = _directions(mesh, aligned)
        ok = mesh.used & np.all(np.isfinite(aligned), axis=-1).all(axis=0)
        for j, degree in enumerate(data.smoothing):
            B, ok_ref = smoothing_basis(mesh, degree)
            use = ok & ok_ref
            Bu = B[use]
            pinv = np.linalg.solve(Bu.T @ Bu, Bu.T)  # coefficients of a field sampled at the used markers
            s2 = sigma[:, use] ** 2  # (n_steps, n_used)
            cov = np.einsum("bn,sn,cn->sbc", pinv, s2, pinv)  # (n_steps, n_b, n_b)
            loaded = []
            for i in range(B.shape[1]):
                pos = aligned.copy()
                pos[1:] += eps * B[:, i, None] * e[j][1:]
                loaded.append(prep(pos))
            self.modes.append((cov * (np.arange(len(cov)) > 0)[:, None, None], loaded, []))
        # the reference configuration: its error is shared by all steps
        if settings.reference_replicates:
            rng = np.random.default_rng(settings.seed)
            for _ in range(int(settings.reference_replicates)):
                ref = aligned.copy()
                ref[0] += sigma[0][:, None] * rng.standard_normal(ref[0].shape)
                self.reference_sets.append(prep(ref, m=remeasured_mesh(mesh, ref[0])))
            return
        for j, degree in enumerate(data.smoothing):  # linearised on a basis of at least ``reference_degree``
            degree = (max(degree[0], settings.reference_degree[0]), max(degree[1], settings.reference_degree[1]))
            B, ok_ref = smoothing_basis(mesh, degree)
            use = ok & ok_ref
            Bu = B[use]
            pinv = np.linalg.solve(Bu.T @ Bu, Bu.T)
            cov = np.einsum("bn,sn,cn->sbc", pinv, sigma[:1, use] ** 2, pinv)
            reference = []
            for i in range(B.shape[1]):
                ref = aligned.copy()
                ref[0] += eps * B[:, i] [:, None] * e[j][0]
                reference.append(prep(ref, m=remeasured_mesh(mesh, ref[0])))
            self.modes.append((cov, [], reference))

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

    def at(self, model, params: Mapping[str, float]) -> np.ndarray:
        """Covariance (n_res, n_res) of the normalised gaps (field-major ravel of (n_fields, n_steps))."""
        self.model = model
        n_f, n_s = self.data.evw.shape
        g0 = self._gaps(self.base, params)
        cov = np.zeros((n_f, n_s, n_f, n_s))
        # readings: independent per step
        gp = (self._gaps(self.d_pressure, params) - g0) / self.dp * self.sp
        gf = (self._gaps(self.d_force, params) - g0) / self.df * self.sf
        step_cov = np.einsum("ks,ls->skl", gp, gp) + np.einsum("ks,ls->skl", gf, gf)
        for c_b, loaded, reference in self.modes:
            if loaded:  # a loaded step's own noise: (f, s, b)
                G = np.stack([(self._gaps(d, params) - g0) / self.settings.step for d in loaded], -1)
                step_cov += np.einsum("ksb,sbc,lsc->skl", G, c_b, G)
            if reference:
                H = np.stack([(self._gaps(d, params) - g0) / self.settings.step for d in reference], -1)
                cov += np.einsum("ksb,bc,ltc->kslt", H, c_b[0], H)
        if self.reference_sets:  # re-measured references: their spread about the data (n_f, n_s)
            D = np.stack([(self._gaps(d, params) - g0).ravel() for d in self.reference_sets])
            cov += (D.T @ D / len(D)).reshape(n_f, n_s, n_f, n_s)
        idx = np.arange(n_s)
        cov[:, idx, :, idx] += step_cov
        cov[:, 0], cov[:, :, :, 0] = 0.0, 0.0  # the reference step: no load, no information (its gap ~ 0)
        return cov.reshape(n_f * n_s, n_f * n_s)


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
                       prepare_options: Mapping | None = None):
    """Generalised least squares from the paper's fit ``first`` (an ``IdentificationResult`` of ``identify`` on
    ``positions``, shape (n_steps, n_markers, 3), the steps it used): ``settings.n_iterations`` fits, each with the
    gaps' covariance at the previous estimate. Returns (result with whitened residuals, the last whitening)."""
    settings = settings or EfficientSettings()
    data = first.data
    cov = GapCovariance(data, positions, settings, prepare_options)
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
