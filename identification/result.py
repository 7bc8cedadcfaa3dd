"""The result of an identification: parameters, their statistics, the fit's gaps and plain-words flags."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["IdentificationResult"]


@dataclass(frozen=True)
class IdentificationResult:
    """Outcome of a VFM identification.

    Attributes
    ----------
    model, wall, optimizer : str
    parameters : dict
        Identified values, SI (Pa, rad, 1), keyed by the paper's names.
    stderr : dict
        Gauss-Newton standard errors from the residual scatter (0 on exact data).
    correlation : ndarray, shape (n_params, n_params)
    resolution : dict
        Change of each parameter (relative for positive ones, else in units of its typical
        magnitude) that the others can compensate within a 1 % RMS virtual-work gap: large values
        mean the data hardly constrain the parameter.
    flags : tuple of str
        Plain-words warnings (poorly identifiable parameters, non-convergence, poor fit).
    cost : float
        1/2 sum of squared normalised gaps.
    residuals : ndarray, shape (n_fields, n_steps)
        Normalised gaps (IVW - EVW) / scale.
    ivw, evw : ndarray, shape (n_fields, n_steps)
        Internal and external virtual work (J) at the solution (paper Figs. 5-6).
    field_names : tuple of str
    converged : bool
    message : str
    n_evaluations : int
        Evaluations of the virtual work: for ``"lsq"`` each gives the residuals and their exact
        Jacobian; for ``"nelder-mead"`` each is one cost.
    starts : tuple of dict
        Initial guesses tried.
    uncertainty : uncertainty.Uncertainty or None
        Bootstrap uncertainty (intervals, bias, model-error factor) when asked for
        (``identify(..., uncertainty="bootstrap")``); ``stderr`` is then the bootstrap's.
    smoothing : tuple or None
        Smoothing degrees used by ``identify`` (three (axial degree, harmonics) pairs for r, theta, z).
    steps : tuple of int or None
        Indices of the input steps in the balance (``identify`` leaves out steps seen only in part);
        the step axis of ``residuals``, ``ivw`` and ``evw``.
    data : VFMData or None
        The virtual-work data fitted (set by ``identify``; ``identification.checks`` uses it).
    verdict : str or None
        "trusted" or "doubtful" (``identification.identify`` judges every result; None: not judged).
    verdict_reasons : tuple of str
        One line each: why the result is doubtful, or what the judgement found (notes).
    parameter_verdicts, parameter_reasons : dict
        name -> "trusted" | "doubtful", and name -> one-line reason ("" when trusted).
    hypotheses : tuple of dict
        The settings the data were judged under: ``{"ends", "wall", "parameters", "gap_noise_units",
        "chosen"}`` each (``gap_noise_units``: the RMS virtual-work gap over its noise, the bootstrap spread).
    """

    model: str
    wall: str
    optimizer: str
    parameters: dict
    stderr: dict
    correlation: np.ndarray
    resolution: dict
    flags: tuple
    cost: float
    residuals: np.ndarray
    ivw: np.ndarray
    evw: np.ndarray
    field_names: tuple
    converged: bool
    message: str
    n_evaluations: int
    starts: tuple = field(default=())
    uncertainty: object = None
    smoothing: tuple | None = None
    steps: tuple | None = None
    data: Any = field(default=None, repr=False, compare=False)  # the VFMData fitted (set by ``identify``)
    verdict: str | None = None
    verdict_reasons: tuple = ()
    parameter_verdicts: dict = field(default_factory=dict)
    parameter_reasons: dict = field(default_factory=dict)
    hypotheses: tuple = field(default=(), compare=False)

    @property
    def residual_per_step(self) -> np.ndarray:
        """RMS normalised gap of each step over the fields, shape (n_steps,)."""
        return np.sqrt(np.mean(self.residuals**2, axis=0))

    @property
    def residual_per_field(self) -> np.ndarray:
        """RMS normalised gap of each field over the steps, shape (n_fields,)."""
        return np.sqrt(np.mean(self.residuals**2, axis=1))

    @property
    def parameter_names(self) -> tuple:
        return tuple(self.parameters)
