"""Exceptions raised by the identification stage."""

from __future__ import annotations

__all__ = ["IdentificationError", "DegenerateDataError", "MeshError"]


class IdentificationError(ValueError):
    """Base class: the identification cannot proceed with the given input."""


class DegenerateDataError(IdentificationError):
    """The measured data cannot identify anything (too few markers, no pressure, missing force...)."""


class MeshError(IdentificationError):
    """The marker cloud cannot be meshed into a tube surface."""
