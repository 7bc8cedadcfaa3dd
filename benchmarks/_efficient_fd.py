"""The gap covariance of ``weighting="efficient"`` as it was first built (issue 24): every derivative by re-preparing
the data with ``vfm.prepare`` (the readings, every smoothing basis function of the loaded steps and of the
reference, rigid ones included). Kept only as the yardstick of ``bench_efficiency --part speed``, which times the
efficient path with it and with ``identification.efficient.GapCovariance`` side by side on the same data.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from identification.efficient import EfficientSettings, _directions
from identification.kinematics import align_steps
from identification.resimulation import basis_size, fitted_positions, marker_noise_level, remeasured_mesh
from identification.smoothing import smoothing_basis
from identification.vfm import VFMData, internal_virtual_work, prepare


class FiniteDifferenceGapCovariance:
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
            pass  # unsmoothed: the readings' noise only
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
