"""Several captures of the stress-free reference averaged into one (issue 24, ``[reference] repeats``).

Every displacement is measured from the reference configuration, so the reference markers' noise is shared by all
loaded steps, and what is left of the efficient estimator's loss is mostly that noise (docs/validation/efficiency.md
"Where the information is lost"). Capturing the reference N times at the same setpoint (p = 0, L/L0 = 1) and
averaging the captures marker by marker divides its noise by sqrt(N): the mean of N independent captures is all
they say about the reference positions (a sufficient statistic for Gaussian noise), so nothing else is needed.

Pure functions over arrays: which steps are repeats is the caller's knowledge (the session's protocol, or the
user's ``reference_repeats``). Units SI; NaN for a marker not observed.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import Any, Callable, Mapping

import numpy as np

__all__ = ["average_reference", "averaged_marker_sigma", "check_repeats", "identify_repeated", "input_steps",
           "kept_steps", "reference_marker_sigma"]

log = logging.getLogger(__name__)

#: Per-step options (first axis ``n_steps``) that the averaging shortens.
PER_STEP_OPTIONS = ("marker_weights",)


def check_repeats(n_repeats: Any, n_steps: int) -> int:
    """``n_repeats`` as an int, or a ValueError naming it: at least 1, and at least one loaded step left."""
    if isinstance(n_repeats, bool) or not isinstance(n_repeats, (int, np.integer)) or n_repeats < 1:
        raise ValueError(f"reference_repeats must be an integer >= 1 (captures of the reference); got {n_repeats!r}")
    if n_repeats >= n_steps:
        raise ValueError(f"reference_repeats = {n_repeats} leaves no loaded step: the positions have {n_steps} steps "
                         f"(expected reference_repeats <= {n_steps - 1})")
    return int(n_repeats)


def average_reference(positions: np.ndarray, n_repeats: int) -> tuple[np.ndarray, np.ndarray]:
    """Average the first ``n_repeats`` steps (captures of the reference) into one reference step.

    Parameters
    ----------
    positions : ndarray, shape (n_steps, n_markers, 3)
        Marker positions (m); steps ``0 .. n_repeats - 1`` are captures of the reference; NaN = not observed.
    n_repeats : int
        At least 1 (1: the positions unchanged, as a copy).

    Returns
    -------
    averaged : ndarray, shape (n_steps - n_repeats + 1, n_markers, 3)
        Step 0 is each marker's mean over the captures where it was observed (NaN where it was observed in none),
        then the loaded steps unchanged.
    n_seen : ndarray of int, shape (n_markers,)
        Captures in which each marker was observed (0 = none).
    """
    x = np.asarray(positions, dtype=float)
    if x.ndim != 3 or x.shape[-1] != 3:
        raise ValueError(f"positions must have shape (n_steps, n_markers, 3); got {x.shape}")
    n = check_repeats(n_repeats, x.shape[0])
    captures = x[:n]
    seen = np.all(np.isfinite(captures), axis=-1)  # (n, n_markers)
    n_seen = seen.sum(axis=0)
    total = np.where(seen[..., None], captures, 0.0).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(n_seen[:, None] > 0, total / np.maximum(n_seen, 1)[:, None], np.nan)
    return np.concatenate([mean[None], x[n:]]), n_seen.astype(int)


def kept_steps(n_steps: int, n_repeats: int) -> np.ndarray:
    """Indices (n_steps - n_repeats + 1,) of the input steps the averaged data keep: the first capture (whose
    readings stand for the averaged reference) and the loaded steps."""
    return np.r_[0, np.arange(int(n_repeats), int(n_steps))]


def averaged_marker_sigma(marker_sigma: np.ndarray, n_repeats: int) -> np.ndarray:
    """Per-marker noise (m) of the averaged steps: shape (n_steps, n_markers) -> (n_steps - n_repeats + 1, n_markers).

    The reference row is the standard deviation of the mean over the captures where the marker has a finite
    sigma, ``sqrt(sum sigma_i^2) / n``; NaN where it has none; the loaded rows unchanged."""
    s = np.asarray(marker_sigma, dtype=float)
    n = int(n_repeats)
    ok = np.isfinite(s[:n])
    count = ok.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        ref = np.where(count > 0, np.sqrt(np.where(ok, s[:n] ** 2, 0.0).sum(axis=0)) / np.maximum(count, 1), np.nan)
    return np.concatenate([ref[None], s[n:]])


def reference_marker_sigma(level: float, n_steps: int, n_captures: np.ndarray) -> np.ndarray:
    """Per-coordinate marker noise (m), shape (n_steps, n_markers): ``level`` at the loaded steps, ``level /
    sqrt(n_captures)`` at the reference (step 0) where a marker's reference is the mean of ``n_captures``
    (n_markers,) captures (``level`` where none)."""
    n_captures = np.asarray(n_captures, dtype=float)
    sigma = np.full((int(n_steps), n_captures.size), float(level))
    sigma[0] = level / np.sqrt(np.maximum(n_captures, 1.0))
    return sigma


def input_steps(steps, n_repeats: int) -> tuple[int, ...] | None:
    """Indices of the averaged steps (0 = the averaged reference) -> the input steps they stand for (the
    reference is the first capture, step 0)."""
    if steps is None:
        return None
    return tuple(0 if k == 0 else k + int(n_repeats) - 1 for k in steps)


def identify_repeated(identify: Callable, positions, pressure, axial_force, n_repeats: int, *,
                      uncertainty_options: Mapping | None = None, **options):
    """``identify`` on the data with the first ``n_repeats`` steps (captures of the reference) averaged.

    ``positions`` (n_steps, n_markers, 3) m, ``pressure`` and ``axial_force`` (n_steps,) Pa and N; the reference's
    readings are the first capture's. The per-step arrays among ``uncertainty_options`` (``marker_sigma``) and
    ``options`` (``marker_weights``) are averaged alike; ``identify`` is called with ``reference_captures`` (the
    captures each marker's reference averages, (n_markers,)) so that the weighting and the bootstrap know the
    reference's lower noise. The result's ``steps`` refer to the input steps (the reference: step 0).
    """
    x = np.asarray(positions, dtype=float)
    n = check_repeats(n_repeats, x.shape[0]) if x.ndim == 3 else n_repeats
    averaged, n_seen = average_reference(x, n)
    keep = kept_steps(x.shape[0], n)
    p = np.asarray(pressure, dtype=float).reshape(-1)[keep]
    f = np.asarray(axial_force, dtype=float).reshape(-1)[keep]
    unc = dict(uncertainty_options) if uncertainty_options is not None else None
    if unc is not None and unc.get("marker_sigma") is not None and np.ndim(unc["marker_sigma"]) == 2:
        unc["marker_sigma"] = averaged_marker_sigma(unc["marker_sigma"], n)
    for k in PER_STEP_OPTIONS:
        if options.get(k) is not None and np.ndim(options[k]) >= 2 and np.shape(options[k])[0] == x.shape[0]:
            options[k] = np.asarray(options[k])[keep]
    log.info("reference: %d captures averaged (markers seen in %d-%d of them)", n, n_seen.min(), n_seen.max())
    result = identify(averaged, p, f, uncertainty_options=unc, reference_captures=n_seen, **options)
    steps = getattr(result, "steps", None)
    return replace(result, steps=input_steps(steps, n) if steps is not None else tuple(int(k) for k in keep))
