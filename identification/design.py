"""Design a test before running it: the 95 % half-width each parameter can reach, and which added steps help.

Pure functions over the Cramér-Rao bound of the homogeneous-tube measurement (``information``): no files.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace

import numpy as np

from .information import BoundResult, TubeExperiment, cramer_rao_bound
from .models import get_model
from .tube_forward import MeasurementNoise, TubeGeometry, TubeSteps, uniform_markers

__all__ = ["PAPER_NOISE", "PAPER_TABLE1", "DesignSpecimen", "DesignResult", "Suggestion", "design", "suggest_steps",
           "CANDIDATE_STRETCHES"]

#: The seed paper's Table 1 (Avril et al. 2010), SI: the default law of a prediction.
PAPER_TABLE1: dict[str, dict[str, float]] = {
    "fung": {"beta": 5.0e3, "alpha11": 14.5, "alpha22": 7.0, "alpha12": 0.1},
    "delfino": {"beta": 1.5e3, "alpha": 4.6},
    "hgo": {"c": 0.4e3, "k1": 8.7e3, "k2": 5.4, "phi": math.radians(27.0)},
    "neohookean": {"mu": 300.0e3},
}
#: The seed paper's marker accuracy, 0.1 % readings (floors 3 Pa, 2 mN): the default noise of a prediction.
PAPER_NOISE = MeasurementNoise(0.17e-3)
#: Axial stretches tried as added blocks by ``suggest_steps``.
CANDIDATE_STRETCHES = (1.05, 1.1, 1.15, 1.2)
#: Captures of the stress-free reference tried by ``suggest_steps`` (``[reference] repeats``): 4 halve its noise.
CANDIDATE_REFERENCE_REPEATS = 4


@dataclass(frozen=True)
class DesignSpecimen:
    """The specimen of a planned test (m): reference radius of the marker surface, wall, marked length.

    ``marker_margin`` leaves unmarked length at each cannula; ``wall`` and ``force_measures`` as ``TubeGeometry``;
    ``fixed``: which point does not move when the stretch is set (``uniform_markers``: one cannula, "end").
    """

    radius: float
    thickness: float
    length: float
    wall: str = "membrane"
    force_measures: str = "wall"
    marker_margin: float = 0.0
    fixed: str = "end"

    def geometry(self) -> TubeGeometry:
        return TubeGeometry(self.radius, self.thickness, self.wall, self.force_measures)


@dataclass(frozen=True)
class DesignResult:
    """The prediction for one protocol: ``half_width`` = 1.96 x the bound, % of each parameter's value."""

    model: str
    parameters: dict
    half_width: dict
    bound: BoundResult
    n_markers: int
    steps: TubeSteps


@dataclass(frozen=True)
class Suggestion:
    """A candidate addition to the protocol and the half-widths (% of value) it would give; ``reference_repeats``:
    the captures of the reference it assumes (more than the protocol's for "capture the reference N times")."""

    label: str
    added_blocks: tuple
    n_markers: int
    n_added_steps: int
    half_width: dict
    score: float
    reference_repeats: int = 1


def _as_steps(protocol_steps) -> TubeSteps:
    if isinstance(protocol_steps, TubeSteps):
        return protocol_steps
    return TubeSteps.from_blocks(protocol_steps)


def design(protocol_steps, specimen: DesignSpecimen, model: str = "fung", params=None, n_markers: int = 300,
           noise: MeasurementNoise = PAPER_NOISE, stretch_per: str = "step") -> DesignResult:
    """The 95 % half-width each parameter can reach with a protocol.

    Parameters
    ----------
    protocol_steps : TubeSteps or sequence of (stretch, pressures [Pa])
        The loaded steps (the stress-free reference is always added).
    specimen : DesignSpecimen
    model : str
    params : mapping, optional
        The law at which to predict (SI); default the seed paper's Table 1 (``PAPER_TABLE1``).
    n_markers : int
        Markers, quasi-uniform over the circumference and the marked length.
    noise : MeasurementNoise
    stretch_per : {"step", "block"}

    Returns
    -------
    DesignResult
    """
    model = get_model(model)
    if params is None:
        if model.name not in PAPER_TABLE1:
            raise ValueError(f"params: no default for model {model.name!r}; give the parameters")
        params = PAPER_TABLE1[model.name]
    params = model.check_parameters(params)
    steps = _as_steps(protocol_steps)
    theta, z = uniform_markers(int(n_markers), specimen.length, margin=specimen.marker_margin, fixed=specimen.fixed)
    experiment = TubeExperiment(specimen.geometry(), steps, theta, z, noise, stretch_per)
    bound = cramer_rao_bound(model, params, experiment)
    return DesignResult(model.name, params, bound.half_width_percent(), bound, int(n_markers), steps)


def _blocks(steps: TubeSteps) -> list[tuple[float, tuple[float, ...]]]:
    return [(float(steps.stretch[steps.block == b][0]), tuple(steps.pressure[steps.block == b].tolist()))
            for b in np.unique(steps.block)]


def _candidates(blocks, n_markers: int, stretches, more_markers: int, repeats: int = 1):
    """(label, added blocks, markers, captures of the reference) of the additions to try."""
    have = {round(s, 6) for s, _ in blocks}
    levels = blocks[0][1]
    new = [s for s in stretches if round(s, 6) not in have]
    out = []
    for r in (1, 2):
        for combo in itertools.combinations(new, r):
            label = ("a second" if len(blocks) == 1 and r == 1 else "an added") if r == 1 else "added"
            word = "stretch" if r == 1 else "stretches"
            out.append((f"{label} {word} at {' and '.join(f'{s:g}' for s in combo)}",
                        tuple((s, levels) for s in combo), n_markers, repeats))
    if more_markers > n_markers:
        out.append((f"{more_markers} markers instead of {n_markers}", (), more_markers, repeats))
    if repeats < CANDIDATE_REFERENCE_REPEATS:
        out.append((f"capture the reference {CANDIDATE_REFERENCE_REPEATS} times ([reference] repeats = "
                    f"{CANDIDATE_REFERENCE_REPEATS})", (), n_markers, CANDIDATE_REFERENCE_REPEATS))
    return out


def suggest_steps(protocol_steps, specimen: DesignSpecimen, model: str = "fung", params=None, n_markers: int = 300,
                  noise: MeasurementNoise = PAPER_NOISE, *, target=None,
                  stretches=CANDIDATE_STRETCHES, more_markers: int | None = None) -> tuple[DesignResult, list]:
    """Evaluate added blocks (another stretch with the same pressure levels, two more, more markers) and more
    captures of the reference (``CANDIDATE_REFERENCE_REPEATS``, when ``noise.reference_repeats`` is fewer).

    Parameters
    ----------
    protocol_steps, specimen, model, params, n_markers, noise : as ``design``
    target : float or mapping, optional
        Half-width (% of value) every parameter (float) or the named ones (``{"alpha22": 2.0}``) should reach:
        the suggestions that reach it come first, the cheapest (fewest added steps) of them first.
    stretches : sequence of float
        Axial stretches of the candidate blocks.
    more_markers : int, optional
        Marker count of the "more markers" candidate (default 4 x ``n_markers``).

    Returns
    -------
    before : DesignResult
        The prediction for the protocol as it is.
    suggestions : list of Suggestion
        Best first. ``score`` is the mean over the parameters of log(after / before) half-width (lower is better).
    """
    before = design(protocol_steps, specimen, model, params, n_markers, noise)
    blocks = _blocks(before.steps)
    more = 4 * n_markers if more_markers is None else int(more_markers)
    out = []
    repeats = noise.reference_repeats
    for label, added, markers, n_ref in _candidates(blocks, n_markers, stretches, more, repeats):
        after = design(list(blocks) + list(added), specimen, before.model, before.parameters, markers,
                       noise if n_ref == repeats else replace(noise, reference_repeats=n_ref))
        score = float(np.mean([math.log(after.half_width[p] / before.half_width[p]) for p in before.half_width]))
        out.append(Suggestion(label, added, markers, sum(len(lv) for _, lv in added) + n_ref - repeats,
                              after.half_width, score, n_ref))
    if target is None:
        out.sort(key=lambda s: s.score)
    else:
        goal = dict(target) if isinstance(target, dict) else {p: float(target) for p in before.half_width}
        unknown = sorted(set(goal) - set(before.half_width))
        if unknown:
            raise ValueError(f"target names parameters {unknown} that model {before.model!r} does not have")

        def reach(s: Suggestion) -> bool:
            return all(s.half_width[p] <= t for p, t in goal.items())

        out.sort(key=lambda s: (not reach(s), s.n_added_steps if reach(s) else 0, s.score))
    return before, out
