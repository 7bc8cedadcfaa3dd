"""The one list of constitutive models vfmlab offers: the identification package's registry.

Listed with the default first, then the registry's (alphabetical) order, as every option and message shows them.
"""

from __future__ import annotations

from collections.abc import Sequence

__all__ = ["DEFAULT_MODEL", "check_models", "model_names"]

#: The model of ``vfmlab identify`` without ``--model`` (the seed paper's).
DEFAULT_MODEL = "fung"


def model_names() -> list[str]:
    """``identification.available_models()``, the default model first: ["fung", "delfino", "hgo", "neohookean"]."""
    from identification import available_models

    names = available_models()
    return [DEFAULT_MODEL] + [n for n in names if n != DEFAULT_MODEL] if DEFAULT_MODEL in names else names


def check_models(names: Sequence[str]) -> list[str]:
    """The names of ``names`` that are not registered models (empty when all are)."""
    known = set(model_names())
    return [n for n in names if n not in known]
