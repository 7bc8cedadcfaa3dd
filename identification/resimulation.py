"""Re-simulated measurements: the displacement field as identification saw it, re-measured with noise.

The shared ground of ``uncertainty`` (the parametric bootstrap) and ``noise_weights`` (the gap noise):
the fitted (smoothed) marker positions (``fitted_positions``), the marker noise level the data show
(``marker_noise_level``), the same triangulation on a noisy reference (``remeasured_mesh``) and the
generator of noisy replicates (``resimulated_measurements``). Units SI; shapes in the docstrings.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .dense import cached_fit, step_coordinates
from .errors import IdentificationError
from .kinematics import align_steps, step_cylindrical
from .mesh import SurfaceMesh, to_cylindrical
from .outliers import marker_outliers
from .smoothing import smooth_cylindrical, smoothing_basis
from .vfm import VFMData

__all__ = ["fitted_positions", "marker_noise_level", "remeasured_mesh", "resimulated_measurements"]


def _specimen_frame_to_world(r, theta, z, axes) -> np.ndarray:
    """Cylindrical coordinates (n_steps, n_markers) about each step's axis -> positions (n_steps, n_markers, 3)."""
    local = np.stack([r * np.cos(theta), r * np.sin(theta), z], -1)
    basis = np.stack([a.basis for a in axes])  # (s, 3, 3)
    origin = np.stack([a.origin for a in axes])  # (s, 3)
    return np.einsum("snj,sji->sni", local, basis) + origin[:, None]


def remeasured_mesh(mesh: SurfaceMesh, reference: np.ndarray) -> SurfaceMesh:
    """The same triangulation on re-measured reference positions (n_markers, 3), m: the reference
    coordinates (and the innermost boundary positions of the virtual fields) follow the new markers."""
    r, theta, z = to_cylindrical(reference, mesh.axis)
    used = mesh.used & np.all(np.isfinite(reference), axis=-1)
    if not np.array_equal(used, mesh.used):
        raise IdentificationError("a re-measured reference lost markers of the mesh")
    nan = np.where(mesh.used, 1.0, np.nan)
    r, theta, z = r * nan, theta * nan, z * nan
    return replace(mesh, r=r, theta=theta, z=z, z_bottom=float(z[np.unique(mesh.bottom_edges)].max()),
                   z_top=float(z[np.unique(mesh.top_edges)].min()))


def fitted_positions(data: VFMData, positions: np.ndarray, reference_step: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The marker positions as the identification saw them, and their scatter about them (``_fitted_positions``;
    of a dense cloud reused for the same markers, mesh, axes and smoothing: ``dense.cached_fit``)."""
    if data.quadrature is not None and data.smoothing is not None:
        q = data.quadrature
        return cached_fit(("fitted positions", reference_step, repr(data.smoothing)), data.mesh,
                          (np.asarray(positions, dtype=float), np.stack([a.origin for a in q.axes]),
                           np.stack([a.basis for a in q.axes]), q.outliers),
                          lambda: _fitted_positions(data, positions, reference_step))
    return _fitted_positions(data, positions, reference_step)


def _fitted_positions(data: VFMData, positions: np.ndarray, reference_step: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The marker positions as the identification saw them, and their scatter about them.

    Parameters
    ----------
    data : VFMData
        From ``prepare`` on ``positions``.
    positions : ndarray, shape (n_steps, n_markers, 3)
        The measured positions (m), NaN = not observed.

    Returns
    -------
    fitted : ndarray, shape (n_steps, n_markers, 3)
        Smoothed positions (rigidly aligned on the reference step) where ``data.smoothing`` is set,
        else the aligned measured positions; NaN where not observed.
    residual : ndarray, shape (n_steps, n_markers, 3)
        Measured minus fitted displacements (m; zeros if unsmoothed, NaN where not observed or
        mis-tracked).
    """
    x = np.asarray(positions, dtype=float)
    aligned, _, _ = align_steps(x, x[reference_step])
    observed = np.all(np.isfinite(aligned), axis=-1)
    if data.smoothing is None:
        return aligned, np.where(observed[..., None], 0.0, np.nan)
    mesh = data.mesh
    if data.quadrature is not None:  # a dense cloud: the axes and outliers of its preparation
        axes, outliers = data.quadrature.axes, data.quadrature.outliers
        r, th, z = step_coordinates(aligned, axes)
    else:
        r, th, z, axes = step_cylindrical(mesh, aligned)
        outliers, _ = marker_outliers(mesh, r, th, z)
    r, th, z = (np.where(outliers, np.nan, a) for a in (r, th, z))
    smoothed = smooth_cylindrical(mesh, r, th, z, data.smoothing)
    rs, ts, zs = smoothed
    # the reference surface's own noise is re-simulated too: take its smooth shape as the truth
    basis, ok_ref = smoothing_basis(mesh, max(data.smoothing[0], (4, 2)))
    coef, *_ = np.linalg.lstsq(basis[ok_ref], mesh.r[ok_ref], rcond=None)
    rs = rs + np.where(ok_ref, basis @ coef - mesh.r, 0.0)[None]
    fitted = _specimen_frame_to_world(rs, ts, zs, axes)
    keep = observed & mesh.used[None]
    fitted = np.where(keep[..., None], fitted, np.nan)
    fitted_disp = _specimen_frame_to_world(*smoothed, axes)
    residual = np.where((keep & ~outliers)[..., None], aligned - fitted_disp, np.nan)
    return fitted, residual


def marker_noise_level(data: VFMData, residual: np.ndarray, n_basis: int | None = None,
                       reference_variance: float = 1.0) -> float:
    """Per-coordinate marker noise (m) to simulate: the RMS scatter of the displacements about the
    smoothed field (corrected for the ``n_basis`` functions fitted per component and step; it also
    holds whatever the basis misses), or the neighbour-mismatch estimate ``data.marker_noise`` for
    unsmoothed data (measured: 5-10 % high at 0.17 mm). ``reference_variance``: the reference step's noise
    variance relative to a loaded step's (1 / N for N captures averaged, ``reference_repeats``)."""
    level = float(data.marker_noise) if np.isfinite(data.marker_noise) else 0.0
    res = residual[1:]  # the reference step's displacement is zero by construction
    n = int(np.sum(np.isfinite(res[..., 0])))
    if data.smoothing is not None and n:
        p = (n_basis or 0) * res.shape[0]
        rss = float(np.nansum(res**2)) / 3.0
        # a displacement carries the noise of its step and of the reference: variance (1 + reference_variance) sigma^2
        level = float(np.sqrt(rss / max(n - p, 1) / (1.0 + reference_variance)))
    return level


def basis_size(smoothing) -> int:
    if smoothing is None:
        return 0
    return int(np.mean([(nz + 1) * (2 * nt + 1) for nz, nt in smoothing]))


def resimulated_measurements(data: VFMData, positions: np.ndarray, *, marker_sigma: np.ndarray | None = None,
                             pressure_noise: float = 0.0, force_noise: float = 0.0, n_replicates: int = 16,
                             seed: int = 0, load_noise_fraction: float = 0.0,
                             reference_captures: np.ndarray | None = None):
    """The measurements ``bootstrap`` re-simulates, for identifications other than ``identify_prepared``
    (e.g. ``identification.regional``): the fitted field plus noise at the level the data show.

    Parameters are those of ``bootstrap``; ``reference_captures`` (n_markers,): captures averaged into the
    reference step (its noise / sqrt(captures), ``reference_repeats``). Returns ``(level, replicates)``: the simulated per-coordinate
    marker noise (m) and a generator of ``(positions (n_steps, n_markers, 3) m, pressure (n_steps,) Pa,
    axial_force (n_steps,) N, mesh)`` with ``mesh`` the same triangulation on the replicate's reference
    (``remeasured_mesh``; an ``IdentificationError`` when a replicate loses markers of the mesh).
    """
    if int(n_replicates) < 5:
        raise ValueError(f"n_replicates must be at least 5; got {n_replicates!r}")
    fitted, residual = fitted_positions(data, positions)
    captures = None if reference_captures is None else np.maximum(np.asarray(reference_captures, dtype=float), 1.0)
    level = marker_noise_level(data, residual, basis_size(data.smoothing),
                               1.0 if captures is None else float(np.mean(1.0 / captures)))
    shape = np.ones(fitted.shape[:2])
    if marker_sigma is not None:
        ms = np.asarray(marker_sigma, dtype=float)
        if ms.shape != fitted.shape[:2]:
            raise ValueError(f"marker_sigma must have shape {fitted.shape[:2]} (n_steps, n_markers); got {ms.shape}")
        med = np.nanmedian(ms)
        if np.isfinite(med) and med > 0:
            shape = np.where(np.isfinite(ms) & (ms > 0), ms / med, 1.0)
    sigma = level * shape
    if captures is not None and marker_sigma is None:
        sigma[0] = sigma[0] / np.sqrt(captures)
    # a reading's noise: the sensor's floor and a fraction of the reading (a transducer's accuracy)
    sd_p = np.hypot(pressure_noise, load_noise_fraction * np.abs(data.pressure))
    sd_f = np.hypot(force_noise, load_noise_fraction * np.abs(data.axial_force))

    def replicates():
        rng = np.random.default_rng(seed)
        for _ in range(int(n_replicates)):
            pos = fitted + sigma[..., None] * rng.standard_normal(fitted.shape)
            p = data.pressure + sd_p * rng.standard_normal(data.pressure.shape) * (data.pressure != 0)
            f = data.axial_force + sd_f * rng.standard_normal(data.axial_force.shape)
            try:
                with np.errstate(all="ignore"):
                    mesh = remeasured_mesh(data.mesh, pos[0])
            except IdentificationError:
                mesh = None
            yield pos, p, f, mesh

    return level, replicates()
