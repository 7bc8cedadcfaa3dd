"""Hyperelastic membrane models: one module each, one shared way to get stresses.

Adding a model: write ``models/<name>.py`` with its energy (equation in the docstring), call
``register(Model(...))`` there and import the module below.
"""

from ._base import Model, available_models, cauchy_stress, get_model, pk2_stress, register, strain_energy
from .delfino import DELFINO
from .fung import FUNG
from .hgo import HGO
from .neohookean import NEOHOOKEAN

__all__ = [
    "Model", "available_models", "cauchy_stress", "get_model", "pk2_stress", "register", "strain_energy",
    "DELFINO", "FUNG", "HGO", "NEOHOOKEAN",
]
