"""The defaults of an identification: one definition shared by the library, the command line, ``reprocess``,
the live results and the demo.

``identification.identify(positions, pressure, force, thickness=..., model=...)`` and ``vfmlab identify S.h5``
both run with :data:`DEFAULTS`; ``vfmlab.stages.settings.IdentifySettings`` takes its defaults from here.
This module imports nothing (``vfmlab --help`` reads it without loading the numerical packages).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["DEFAULTS", "IdentifyDefaults", "PREFERRED_WALL", "UNCERTAINTIES", "uncertainty_for"]

#: What ``uncertainty`` may say: "auto" is "gls" for ``weighting="efficient"``, "bootstrap" otherwise.
UNCERTAINTIES = ("auto", "gls", "bootstrap", "gauss-newton")


def uncertainty_for(uncertainty: str, weighting: str) -> str:
    """The uncertainty method ``uncertainty`` means for ``weighting``: "auto" -> "gls" (the efficient fit's own
    generalised least-squares covariance, ``efficient_uncertainty``) for "efficient", else "bootstrap"."""
    if uncertainty not in UNCERTAINTIES:
        raise ValueError(f"uncertainty must be one of {UNCERTAINTIES}; got {uncertainty!r}")
    if uncertainty == "auto":
        return "gls" if weighting == "efficient" else "bootstrap"
    if uncertainty == "gls" and weighting != "efficient":
        raise ValueError(f"uncertainty='gls' is the covariance of weighting='efficient'; got weighting={weighting!r} "
                         "(use 'bootstrap' or 'auto')")
    return uncertainty


#: The wall form preferred when neither the user nor the data decide: an artery has a wall.
PREFERRED_WALL = "thick"


@dataclass(frozen=True)
class IdentifyDefaults:
    """What an identification assumes when not told.

    Attributes
    ----------
    model : str
        Constitutive law.
    wall : str or None
        "thick" or "membrane" as stated; None: ``PREFERRED_WALL`` unless the data contradict it (both wall
        forms are fitted and judged against the noise, ``identification.verdict``).
    ends : str or None
        "clamped" or "free" as stated; None: the data decide, and where they cannot, the result is given
        under both and marked doubtful.
    optimizer, smoothing, uncertainty, weighting : str
        As ``identification.identify``: the efficient (generalised least-squares) weighting with its own
        covariance's intervals ("auto": "gls" for it, "bootstrap" for the others; issue 24,
        docs/validation/efficiency.md). The reading noise the bootstrap simulates (below) is the one the
        efficient weighting models (``efficient.EfficientSettings``: 0.1 %, 3 Pa, 2 mN).
    pressure_noise, force_noise : float
        Standard deviation of a pressure reading (Pa, ~0.02 mmHg: a controller-grade transducer averaged
        over the dwell) and of a load-cell reading (N), simulated by the bootstrap.
    load_noise_fraction : float
        Further noise of each reading as a fraction of it (0.1 %, a transducer's accuracy), in quadrature.
    """

    model: str = "fung"
    wall: str | None = None
    ends: str | None = None
    optimizer: str = "lsq"
    smoothing: str | None = "auto"
    uncertainty: str = "auto"
    weighting: str = "efficient"
    pressure_noise: float = 3.0
    force_noise: float = 0.002
    load_noise_fraction: float = 1e-3


#: The one set of defaults.
DEFAULTS = IdentifyDefaults()
