"""The shared machinery of the membrane models: one registry, one way to differentiate.

Every model supplies only its strain energy density ``W(C11, C22, C12, C33; parameters)`` [Pa] as
an elementwise numpy expression of the components of the right Cauchy-Green tensor in the local
(circumferential = 1, axial = 2) frame, C33 being the through-thickness component. Incompressible
plane stress (S33 = 0) is imposed by substituting ``C33 = 1 / (C11 C22 - C12^2)``; the membrane
second Piola-Kirchhoff stress is then

    S_ab = 2 dW_hat / dC_ab,    W_hat(C11, C22, C12) = W(C11, C22, C12, 1 / det C)

which equals ``2 dW/dC_ab - p C^-1_ab`` with the pressure ``p`` eliminated by ``S33 = 0``. The
derivative is taken by forward-mode automatic differentiation (vector dual numbers, ``_dual.py``:
exact, one evaluation for all three components), for every model alike; a new model is one small
module with its energy and a registry entry. Energies must therefore be written with arithmetic,
``np.exp/log/sqrt/sin/cos``, ``np.where`` and ``np.real`` only.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Model", "register", "get_model", "available_models", "pk2_stress", "cauchy_stress", "strain_energy",
           "seed_virtual_strains", "virtual_work_sensitivities"]

from ._dual import seed
from ._hyperdual import HyperDual, seed_directions, seed_parameters


@dataclass(frozen=True)
class Model:
    """A hyperelastic membrane law.

    Attributes
    ----------
    name : str
        Registry key (``"fung"``...).
    parameter_names : tuple of str
        The paper's names, in order.
    units : tuple of str
        SI unit of each parameter (``"Pa"``, ``"1"``, ``"rad"``).
    energy : callable
        ``energy(c11, c22, c12, c33, **parameters) -> W`` [Pa], elementwise (works on dual numbers).
    initial_guess : dict
        A generic starting point for the optimiser (SI).
    positive : tuple of bool
        Parameters that must be > 0 (optimised on a log scale).
    linear : tuple of bool
        Stress-like parameters W is proportional to (the optimiser fits them linearly at each start).
    lower, upper : tuple of float
        Bounds for the parameters that are not log-scaled (ignored for positive ones).
    work_features, work : callable, optional
        A closed-form shortcut of the identification's hot path: ``work_features(c11, c22, c12,
        d11, d22, d12)`` precomputes what does not depend on the parameters (C components
        ``(...)``, virtual-strain directions ``(k, ...)``), and ``work(features, **nonlinear)``
        returns ``{linear name: (virtual work (k, ...[:-1]), its derivatives by the nonlinear
        parameters (k, n_nonlinear, ...[:-1]))}`` summed over the last axis, for W with that
        linear parameter 1 and the others 0. It must equal the shared AD path
        (``virtual_work_sensitivities``; tests/test_ident_models.py checks it); linear parameters it
        leaves out go through the AD path.
    """

    name: str
    parameter_names: tuple[str, ...]
    units: tuple[str, ...]
    energy: Callable[..., np.ndarray]
    initial_guess: Mapping[str, float]
    positive: tuple[bool, ...]
    linear: tuple[bool, ...] = field(default=())
    lower: tuple[float, ...] = field(default=())
    upper: tuple[float, ...] = field(default=())
    description: str = ""
    work_features: Callable[..., object] | None = None
    work: Callable[..., dict] | None = None

    def __post_init__(self) -> None:
        n = len(self.parameter_names)
        if not self.linear:
            object.__setattr__(self, "linear", (False,) * n)
        if not self.lower:
            object.__setattr__(self, "lower", (-np.inf,) * n)
        if not self.upper:
            object.__setattr__(self, "upper", (np.inf,) * n)
        for name, value in (("units", self.units), ("positive", self.positive), ("linear", self.linear), ("lower", self.lower),
                            ("upper", self.upper)):
            if len(value) != n:
                raise ValueError(f"Model {self.name!r}: {name} needs {n} entries; got {len(value)}")

    def check_parameters(self, parameters: Mapping[str, float]) -> dict[str, float]:
        """Validate a parameter mapping and return it as ``{name: float}`` in model order."""
        missing = [p for p in self.parameter_names if p not in parameters]
        extra = [p for p in parameters if p not in self.parameter_names]
        if missing or extra:
            raise ValueError(
                f"parameters for model {self.name!r} must be exactly {list(self.parameter_names)}; "
                f"missing {missing}, unexpected {extra}"
            )
        return {p: float(parameters[p]) for p in self.parameter_names}


_REGISTRY: dict[str, Model] = {}


def register(model: Model) -> Model:
    """Add a model to the registry (its module calls this once at import)."""
    _REGISTRY[model.name] = model
    return model


def get_model(name: str | Model) -> Model:
    """Look a model up by name (one of ``available_models()``)."""
    if isinstance(name, Model):
        return name
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ValueError(f"model must be one of {sorted(_REGISTRY)}; got {name!r}") from None


def available_models() -> list[str]:
    """Names of the registered models: THE list of identifiable models (sorted)."""
    return sorted(_REGISTRY)


def _components(C: np.ndarray):
    C = np.asarray(C)
    if C.shape[-2:] != (2, 2):
        raise ValueError(f"C must have shape (..., 2, 2); got {C.shape}")
    return C[..., 0, 0], C[..., 1, 1], 0.5 * (C[..., 0, 1] + C[..., 1, 0])


def _energy_hat(model: Model, c11, c22, c12, parameters):
    c33 = 1.0 / (c11 * c22 - c12 * c12)
    return model.energy(c11, c22, c12, c33, **parameters)


def strain_energy(model: str | Model, C: np.ndarray, parameters: Mapping[str, float]) -> np.ndarray:
    """Strain energy density W [Pa] at in-plane ``C`` of shape ``(..., 2, 2)``."""
    model = get_model(model)
    return np.asarray(_energy_hat(model, *_components(C), model.check_parameters(parameters)), dtype=float)


def pk2_components(model: Model, c11, c22, c12, parameters: Mapping[str, np.ndarray]):
    """``(S11, S22, S12)`` [Pa] from C components; parameters may be arrays that broadcast.

    This is the hot path of the identification (no validation). Parameter arrays must not have
    more dimensions than the C components (prepend axes of length 1 to C for batches).
    """
    w = _energy_hat(model, *seed(c11, c22, c12), parameters)
    grad = np.broadcast_to(w.d, (3,) + np.shape(w.v))
    # c12 stands for both off-diagonal entries of C: dW/dc12 = 2 dW/dC_12 = S_12.
    return 2.0 * grad[0], 2.0 * grad[1], grad[2]


def seed_virtual_strains(c11, c22, c12, weights) -> tuple[HyperDual, HyperDual, HyperDual, HyperDual]:
    """The in-plane C components (and C33 = 1 / det C) varying along the virtual strains.

    ``S : dE* dV0 = dW/dt (C + 2 t dE*) dV0``: the internal virtual work density of a field is the
    derivative of W along its virtual strain. ``weights`` has shape ``(k, ...) + (3,)``:
    dV0 (dE*11, dE*22, 2 dE*12) of k fields (``VFMData.work_density``); C components ``(...)``.
    The result is parameter-independent: compute it once per data set.
    """
    w = np.asarray(weights, dtype=float)
    # c12 stands for both off-diagonal entries: its direction is 2 dE*12 (= weights[..., 2]).
    c11 = seed_directions(c11, 2.0 * w[..., 0])
    c22 = seed_directions(c22, 2.0 * w[..., 1])
    c12 = seed_directions(c12, w[..., 2])
    return c11, c22, c12, 1.0 / (c11 * c22 - c12 * c12)


def virtual_work_sensitivities(model: Model, seeds, parameters: Mapping[str, float], nonlinear: tuple[str, ...]):
    """Internal virtual work density and its derivatives with respect to the ``nonlinear`` parameters.

    Parameters
    ----------
    seeds : from ``seed_virtual_strains`` (values of shape ``(...)``, k virtual strains)
    parameters : the model's parameters (floats); those named in ``nonlinear`` are differentiated.

    Returns
    -------
    work : ndarray, shape ``(k, ...)``
        dW along each virtual strain (J per quadrature point, summed by the caller).
    d_work : ndarray, shape ``(k, len(nonlinear), ...)``
        Its exact derivatives with respect to the nonlinear parameters.
    constant : bool
        True if the derivatives of W by the nonlinear parameters vanish identically (its work can be cached).
    """
    c11 = seeds[0]
    ndim = np.ndim(c11.v)
    values = dict(parameters)
    for name, dual in zip(nonlinear, seed_parameters([parameters[n] for n in nonlinear], ndim)):
        values[name] = dual
    w = model.energy(*seeds, **values)
    k = c11.a.shape[0]
    shape = np.shape(c11.v)
    work = np.zeros((k,) + shape) if w.a is None else np.broadcast_to(w.a, (k,) + shape)
    d_work = (np.zeros((k, len(nonlinear)) + shape) if w.ab is None
              else np.broadcast_to(w.ab, (k, len(nonlinear)) + shape))
    # exactly zero parameter derivatives at every point: the part does not depend on them (e.g. HGO's
    # matrix term, whose fibre terms are multiplied by k1 = 0)
    constant = (w.b is None or not np.any(w.b)) and (w.ab is None or not np.any(w.ab))
    return work, d_work, constant


def pk2_stress(model: str | Model, C: np.ndarray, parameters: Mapping[str, float]) -> np.ndarray:
    """Membrane second Piola-Kirchhoff stress.

    Parameters
    ----------
    model : str or Model
    C : ndarray, shape (..., 2, 2)
        Right Cauchy-Green tensor in the local (circumferential, axial) frame.
    parameters : mapping
        The model's parameters (SI).

    Returns
    -------
    S : ndarray, shape (..., 2, 2)
        Pa, local frame, plane stress (S33 = 0) and incompressibility imposed.
    """
    model = get_model(model)
    s11, s22, s12 = pk2_components(model, *_components(C), model.check_parameters(parameters))
    return np.stack([np.stack([s11, s12], -1), np.stack([s12, s22], -1)], -2)


def cauchy_stress(model: str | Model, F: np.ndarray, parameters: Mapping[str, float]) -> np.ndarray:
    """Cauchy stress ``sigma = F S F^T`` (J = 1) [Pa].

    Parameters
    ----------
    F : ndarray, shape (..., m, 2)
        In-plane deformation gradient from the local reference frame to ``m``-dimensional current
        components (m = 2 for a local current frame, 3 for world components).

    Returns
    -------
    sigma : ndarray, shape (..., m, m)
    """
    F = np.asarray(F, dtype=float)
    C = np.swapaxes(F, -1, -2) @ F
    S = pk2_stress(model, C, parameters)
    return F @ S @ np.swapaxes(F, -1, -2)
