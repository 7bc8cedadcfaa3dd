"""What a test could reach: the 95 % half-width the Cramér-Rao bound allows each parameter (issue 24).

Two uses, one computation (``identification.design``, the bound of a homogeneous tube):

- after the test, :func:`session_reachable`: the bound for the session's own steps (the identification's step rows,
  their measured pressures and set stretches), its number of markers, the marker noise the data show
  (``identification.prepare``'s neighbour-mismatch estimate) and its specimen, at the identified parameters; the
  report and ``vfmlab results`` show it beside the achieved interval;
- before the test, :func:`protocol_reachable`: the bound for a protocol and a specimen with ``vfmlab design``'s
  defaults (300 markers at 0.17 mm, the seed paper's law), shown by ``vfmlab run`` beside the live estimates.

Neither ever raises for odd data: the reason the bound could not be computed is logged and kept in ``reason``.
Nothing is stored in the session.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

log = logging.getLogger(__name__)

__all__ = ["Reachable", "achieved_half_width", "protocol_reachable", "session_reachable", "with_reachable"]

#: ``vfmlab design``'s default marker count and marker noise (m): what ``run`` predicts before the test.
DESIGN_MARKERS, DESIGN_NOISE_M = 300, 0.17e-3
_Z95 = 1.959963984540054


@dataclass(frozen=True)
class Reachable:
    """The 95 % half-width (% of value) the bound allows each parameter, and what it was computed for.

    ``half_width`` is empty and ``reason`` says why when the bound could not be computed.
    """

    model: str
    half_width: dict[str, float] = field(default_factory=dict)
    n_markers: int = 0
    marker_noise_m: float = float("nan")
    n_steps: int = 0
    stretches: tuple[float, ...] = ()
    wall: str = ""
    reason: str = ""

    @property
    def available(self) -> bool:
        return bool(self.half_width) and not self.reason

    def describe(self) -> str:
        """One line: what the bound was computed for, or why it is not available."""
        if not self.available:
            return f"reachable n/a: {self.reason}"
        return (f"reachable = 1.96 x the Cramér-Rao bound for {self.n_steps} loaded steps at stretch "
                f"{'/'.join(f'{s:g}' for s in self.stretches)}, {self.n_markers} markers at "
                f"{self.marker_noise_m * 1e3:.3g} mm, loads at 0.1 % of reading, {self.wall} wall")


def achieved_half_width(values: ArrayLike, low: ArrayLike, high: ArrayLike) -> np.ndarray:
    """Half-width of achieved 95 % intervals, % of each value (NaN where the value is 0 or not finite)."""
    v = np.asarray(values, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = 100.0 * (np.asarray(high, float) - np.asarray(low, float)) / 2.0 / np.abs(v)
    return np.where(np.isfinite(out), out, np.nan)


@contextlib.contextmanager
def _quiet(name: str):
    """Only errors from logger ``name`` while the block runs (its level restored after)."""
    logger = logging.getLogger(name)
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)


def _bound(model: str, params: Mapping[str, float], steps, specimen, *, wall: str, force_measures: str,
           n_markers: int, noise_m: float) -> dict[str, float]:
    """``identification.design``'s half-widths (% of value); raises ValueError when the bound is meaningless."""
    from identification import DesignSpecimen, MeasurementNoise, design

    spec = DesignSpecimen(specimen.radius, specimen.thickness, specimen.length, wall, force_measures)
    result = design(steps, spec, model, dict(params), int(n_markers), MeasurementNoise(float(noise_m)))
    if result.bound.singular:
        raise ValueError(result.bound.warning)
    return {k: float(v) for k, v in result.half_width.items()}


def session_reachable(session, result: Mapping[str, Any]) -> Reachable:
    """The reachable half-widths of one stored "identification" result (``session.result(name)``).

    The bound is computed at the identified parameters, for the result's step rows (the first one the reference),
    the markers seen on average over those steps in the markers result it was identified from (its settings'
    ``markers_result``, else the newest), their noise as ``identification.prepare`` estimates it, the session's
    specimen (outer radius, wall, length), the result's wall form and the session's load-cell reading.
    """
    attrs = result.get("attrs", {})
    model = str(attrs.get("model", ""))
    try:
        return _session_reachable(session, result, model)
    except Exception as exc:  # noqa: BLE001 - a report or a listing never fails for want of the bound
        reason = f"{type(exc).__name__}: {exc}" if not isinstance(exc, ValueError) else str(exc)
        log.info("%s: reachable half-widths not computed: %s", result.get("name", "?"), reason)
        return Reachable(model, reason=reason)


def _session_reachable(session, result: Mapping[str, Any], model: str) -> Reachable:
    from identification import TubeSteps, get_model, prepare
    from vfmlab.pipeline import load_identification_inputs

    a, attrs = result["arrays"], result.get("attrs", {})
    names = [str(n) for n in np.atleast_1d(a.get("parameter_names", []))]
    values = np.asarray(a.get("parameters", []), float).ravel()
    m = get_model(model)
    if sorted(names) != sorted(m.parameter_names) or len(values) != len(names):
        raise ValueError(f"the result's parameters {names} are not those of model {m.name!r}")
    markers = dict(result.get("parameters", {})).get("markers_result")
    inputs = load_identification_inputs(session, str(markers) if markers in session.results("markers") else None)
    # a result that does not say which steps it used (no step_index) used every step of its markers
    rows = np.asarray(a["step_index"] if "step_index" in a else inputs["rows"], int).ravel()
    where = {int(r): i for i, r in enumerate(inputs["rows"])}
    missing = [int(r) for r in rows if int(r) not in where]
    if missing or rows.size < 2:
        raise ValueError(f"the markers result {inputs['markers_result']} lacks step rows {missing} of the result"
                         if missing else "the result used fewer than two steps")
    idx = [where[int(r)] for r in rows]
    positions = inputs["positions"][idx]
    wall = str(attrs.get("wall", "")) if str(attrs.get("wall", "")) in ("thick", "membrane") else "membrane"
    with _quiet("identification"):  # the mesh's and the balance's notes were the identification's to give
        data = prepare(positions, inputs["pressure"][idx], inputs["force"][idx], thickness=inputs["thickness"],
                       wall="membrane", ends="free")
    noise = float(data.marker_noise)
    if not (np.isfinite(noise) and noise > 0):
        raise ValueError("the marker noise could not be estimated from the data")
    n_markers = int(round(float(np.mean(np.isfinite(positions).all(axis=-1).sum(axis=1)))))
    table = session.steps
    loaded = rows[1:]
    stretch = np.asarray(table["stretch"], float)[loaded]
    steps = TubeSteps(np.asarray(table["pressure"], float)[loaded], stretch,
                      np.unique(np.asarray(table["block"])[loaded], return_inverse=True)[1])
    hw = _bound(m.name, dict(zip(names, values)), steps, session.specimen, wall=wall,
                force_measures=session.load_cell_measures, n_markers=n_markers, noise_m=noise)
    return Reachable(m.name, hw, n_markers, noise, int(loaded.size), tuple(float(s) for s in np.unique(stretch)), wall)


def protocol_reachable(protocol, specimen, models: Sequence[str], *, wall: str | None = None,
                       force_measures: str = "wall", n_markers: int = DESIGN_MARKERS,
                       noise_m: float = DESIGN_NOISE_M) -> dict[str, Reachable]:
    """``vfmlab design``'s prediction for each model, before the test (computed once, a fraction of a second each).

    ``protocol`` : ``acquisition.protocol.Protocol``; ``specimen`` : its specimen file (radius, thickness,
    length, m). The law is the seed paper's Table 1 (``identification.PAPER_TABLE1``); ``wall`` None: the wall
    form the identification prefers when the data do not say (``identification.defaults``).
    """
    from identification import PAPER_TABLE1, TubeSteps, defaults
    from vfmlab.stages.design import protocol_blocks

    wall = wall or defaults.DEFAULTS.wall or defaults.PREFERRED_WALL
    out: dict[str, Reachable] = {}
    for model in models:
        try:
            if model not in PAPER_TABLE1:
                raise ValueError(f"no default law for model {model!r} to predict at")
            blocks = protocol_blocks(protocol)
            steps = TubeSteps.from_blocks(blocks)
            hw = _bound(model, PAPER_TABLE1[model], steps, specimen, wall=wall, force_measures=force_measures,
                        n_markers=n_markers, noise_m=noise_m)
            out[model] = Reachable(model, hw, n_markers, noise_m, steps.n_steps,
                                   tuple(float(s) for s, _ in blocks), wall)
        except Exception as exc:  # noqa: BLE001 - the test runs whether or not the prediction can be made
            log.info("reachable half-widths of %s not computed: %s", model, exc)
            out[model] = Reachable(model, reason=str(exc))
    return out


def with_reachable(session, rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """``vfmlab results``' rows (:func:`vfmlab.results.list_results`) with, for each identification, ``reachable``:
    ``{"half_width_95_percent": {name: %} (empty when n/a), "n_markers", "marker_noise_m", "note"}``."""
    for row in rows:
        if row.get("kind") != "identification":
            continue
        r = session_reachable(session, session.result(row["name"]))
        row["reachable"] = {"half_width_95_percent": dict(r.half_width) if r.available else {},
                            "n_markers": r.n_markers, "marker_noise_m": r.marker_noise_m, "note": r.describe()}
    return rows
