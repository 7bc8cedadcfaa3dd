"""The gaps' noise for judging settings: the efficient weighting's full covariance, per wall form.

The verdict tells two settings (ends, wall form) or two laws apart by how far their virtual-work gaps are from
the noise. The gaps of one test are far from independent: every step's displacement is measured from the same
reference configuration, so its error is shared by every step's gaps, and the two fields of a step see the same
kinematics. A sum of squared gaps over their separate spreads counts that shared error once per step and calls
small differences between settings decisive: on a membrane-law tube, one axial stretch, 0.17 mm, 2 of 30 tests
were judged "thick wall" with confidence and had a trusted alpha11 ~27 % off (docs/validation/trust.md).

Here the gaps are judged over their full first-order covariance (``efficient.GapCovariance``), floored at
``NOISE_FLOOR`` of the external-work scale per gap (the discretisation of the balance), and each setting is
refitted by generalised least squares with that covariance's whitening before its chi-square is read: the
smallest whitened sum each setting can reach. The covariance is built once per wall form; the other end
condition's comes from the same moved sets (``GapCovariance.for_ends``: the end condition changes the covariance a
lot, through the clamped ends' strip force, measured from the end markers), and on a dense cloud the other wall
form's too (``GapCovariance.for_wall``: the moved sets' smoothed states balanced again). Pure functions over
arrays.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from .efficient import NOISE_FLOOR, EfficientSettings, GapCovariance, floored, whitening_matrix
from .errors import IdentificationError
from .fit import identify_prepared
from .optimize import with_reference_sigma
from .vfm import VFMData

__all__ = ["NOISE_FLOOR", "SettingNoise", "setting_noise"]

log = logging.getLogger(__name__)

#: ``identify`` options that are not ``prepare``'s (the covariance re-prepares the data with the rest).
_NOT_PREPARE = ("efficient", "reference_captures", "n_starts", "initial", "optimizer", "wall", "ends")


@dataclass(frozen=True)
class SettingNoise:
    """The gaps' covariance of one wall form (``covariance``: a ``GapCovariance``, None where it could not be
    built: the floor alone), the scales (n_fields,) of the data it was built on, their number of steps and wall
    form."""

    covariance: GapCovariance | None
    scale: np.ndarray
    n_steps: int
    wall: str | None = None

    def whitening(self, model, parameters: Mapping[str, float], scale: np.ndarray) -> np.ndarray:
        """W (n_res, n_res) for gaps normalised by ``scale`` (n_fields,): the covariance at ``parameters``
        (in the units of the data it was built on), rescaled to ``scale``, plus the floor on the loaded gaps."""
        to_here = np.repeat(self.scale / np.asarray(scale, dtype=float), self.n_steps)  # gap here / gap there
        n = to_here.size
        c = np.zeros((n, n)) if self.covariance is None else (
            np.asarray(self.covariance.at(model, parameters), dtype=float) * np.outer(to_here, to_here))
        return whitening_matrix(floored(c, self.n_steps))


def setting_noise(data: VFMData, positions: np.ndarray, *, options: Mapping | None = None,
                  like: SettingNoise | None = None) -> SettingNoise:
    """The gaps' covariance of ``data``'s setting from the measured ``positions`` (n_steps, n_markers, 3) m, as
    ``identify(..., weighting="efficient")`` would build it from its ``options`` (``efficient`` settings, the
    reference's ``reference_captures``, ``prepare``'s options); the floor alone when it cannot be built.
    ``like``: the noise of another setting of the same markers, whose moved sets give this one without a
    re-preparation: the same wall form's under the other end condition (``GapCovariance.for_ends``), a dense
    cloud's under the other wall form (``GapCovariance.for_wall``: only the balance again); built afresh where they
    cannot."""
    scale, n_steps = np.asarray(data.scale, dtype=float), int(data.evw.shape[1])
    if like is not None:
        cov = like.covariance
        if like.wall == data.wall:
            return SettingNoise(None if cov is None else cov.for_ends(data), scale, n_steps, data.wall)
        derived = None if cov is None else cov.for_wall(data)
        if derived is not None:
            return SettingNoise(derived, scale, n_steps, data.wall)
    given = dict(options or {})
    prepare_options = {k: v for k, v in given.items() if k not in _NOT_PREPARE}
    try:
        with np.errstate(all="ignore"):
            cov = GapCovariance(data, positions, _settings(given, data, positions), prepare_options)
    except (IdentificationError, ValueError, np.linalg.LinAlgError) as exc:
        log.info("the gaps' covariance not built (%s): the floor %g alone judges the settings", exc, NOISE_FLOOR)
        cov = None
    return SettingNoise(cov, scale, n_steps, data.wall)


def _settings(given: Mapping, data: VFMData, positions: np.ndarray) -> EfficientSettings:
    """The efficient weighting's settings as ``identify`` would take them (the reference's captures counted)."""
    settings = given.get("efficient") or EfficientSettings()
    captures = given.get("reference_captures")
    if captures is not None and data.smoothing is not None:
        settings = with_reference_sigma(settings, data, positions, captures)
    return settings


def whitened_fit(data: VFMData, model, noise: SettingNoise, initial: Mapping[str, float]):
    """The generalised least-squares fit of ``data`` with ``noise``'s whitening at ``initial`` and its chi-square
    (the summed squared whitened gaps). Returns (IdentificationResult, W, chi2)."""
    W = noise.whitening(model, initial, data.scale)
    fit = identify_prepared(data, model, initial=initial, n_starts=1, whitening=W)
    return fit, W, float(np.sum(np.where(np.isfinite(fit.residuals), fit.residuals, 1e6) ** 2))
