"""Regional identification stage: parameter profiles along the axis from a session, stored as a "regional" result.

Session I/O here; the computation is ``identification.regional`` and ``identification.regional_uncertainty`` (pure).
Units SI in the file (m, Pa), with the unit on every dataset.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from acquisition.session import SessionError, write_result
from vfmlab.pipeline import FORCE_NOISE, PRESSURE_NOISE, StageError, read_identification_inputs, resolve_ends
from vfmlab.results import round_floats

__all__ = ["RegionsSpec", "parse_regions", "identify_regional_stored", "AUTO_MAX_BANDS"]

#: ``--regions auto`` chooses between 1 and this many bands.
AUTO_MAX_BANDS = 6


@dataclass(frozen=True)
class RegionsSpec:
    """What ``--regions`` asks for: ``kind`` "bands" (``n`` bands), "auto" (bands chosen from the data, at most
    ``n``) or "legendre" (``n`` Legendre coefficients of log beta)."""

    kind: str
    n: int

    def __str__(self) -> str:
        return {"bands": f"{self.n}", "auto": "auto", "legendre": f"legendre:{self.n}"}[self.kind]


def parse_regions(text: str | int) -> RegionsSpec:
    """``--regions`` text: N (1-12 bands), "auto" or "legendre:K" (K 1-8) -> RegionsSpec; ValueError otherwise."""
    s = str(text).strip().lower()
    try:
        if s == "auto":
            return RegionsSpec("auto", AUTO_MAX_BANDS)
        if s.startswith("legendre:"):
            k = int(s.split(":", 1)[1])
            if 1 <= k <= 8:
                return RegionsSpec("legendre", k)
        elif 1 <= int(s) <= 12:
            return RegionsSpec("bands", int(s))
    except ValueError:
        pass
    raise ValueError(f"--regions must be a number of bands from 1 to 12, 'auto' or 'legendre:K' with K from 1 to 8 "
                     f"coefficients; got {text!r}")


def _result_arrays(model, result, rd, rows, choice) -> tuple[dict, dict]:
    """Datasets of the stored result and their units."""
    units = dict(zip(model.parameter_names, model.units))
    hom_names = list(result.homogeneous.parameters)
    arrays = {
        "band_edges": rd.edges, "band_centres": rd.centres, "band_edges_world": rd.world_points(rd.edges),
        "band_centres_world": rd.world_points(rd.centres), "axis_direction": rd.data.mesh.axis.direction,
        "differs": result.differs.astype(np.int8), "residuals": result.residuals, "step_index": rows,
        "regional_names": np.array(result.regional, dtype=object).astype(str),
        "shared_names": np.array(list(result.parameters), dtype=object).astype(str),
        "shared_parameters": np.array(list(result.parameters.values()), dtype=float),
        "shared_stderr": np.array(list(result.parameter_stderr.values()), dtype=float),
        "homogeneous_names": np.array(hom_names, dtype=object).astype(str),
        "homogeneous_parameters": np.array(list(result.homogeneous.parameters.values()), dtype=float),
        "homogeneous_stderr": np.array([result.homogeneous.stderr[n] for n in hom_names], dtype=float),
    }
    out_units = {"band_edges": "m", "band_centres": "m", "band_edges_world": "m", "band_centres_world": "m",
                 "axis_direction": "1", "differs": "1", "residuals": "1"}
    for n in result.regional:
        arrays[n], arrays[f"{n}_stderr"] = result.profiles[n], result.stderr[n]
        arrays[f"{n}_interval_low"], arrays[f"{n}_interval_high"] = result.interval[n][:, 0], result.interval[n][:, 1]
        arrays[f"{n}_z_score"], arrays[f"{n}_coefficients"] = result.z_score[n], result.coefficients[n]
        out_units.update({n: units[n], f"{n}_stderr": units[n], f"{n}_interval_low": units[n],
                          f"{n}_interval_high": units[n], f"{n}_z_score": "1",
                          f"{n}_coefficients": "1 (log of the value in SI)" if model.positive[
                              model.parameter_names.index(n)] else units[n]})
    if choice is not None:
        arrays.update({"auto_candidates": choice.candidates, "auto_chi2": choice.chi2,
                       "auto_criterion": choice.criterion})
        out_units.update({"auto_candidates": "1", "auto_chi2": "1", "auto_criterion": "1"})
    return arrays, out_units


def _identify(data, spec: RegionsSpec, model, wall, ends, smoothing, uncertainty, progress=None):
    """(RegionalData, RegionalResult with its uncertainty, BandChoice or None); ``progress(done, total, what)``."""
    from identification.regional import identify_regional, prepare_regional
    from identification.regional_uncertainty import choose_bands, with_bootstrap

    options = dict(thickness=data["thickness"], wall=wall, ends=ends, smoothing=smoothing)
    boot = {"marker_sigma": data["uncertainty"], "pressure_noise": PRESSURE_NOISE, "force_noise": FORCE_NOISE}
    args = (data["positions"], data["pressure"], data["force"])
    choice = None
    if spec.kind == "auto":
        choice = choose_bands(*args, model=model, n_max=spec.n, bootstrap_options=boot, progress=progress, **options)
        profile = {"n_bands": choice.n_bands}
    else:
        profile = {"n_bands": spec.n} if spec.kind == "bands" else {"legendre": spec.n}
    rd = prepare_regional(*args, **profile, **options)
    if choice is not None and choice.n_bands == spec.n:
        result = choice.finest
    else:
        if progress is not None:
            progress(0, 1, f"fitting {rd.n_bands} bands")
        result = identify_regional(rd, model)
        if uncertainty == "bootstrap":
            result = with_bootstrap(result, rd, data["positions"], **boot, progress=progress)
    return rd, result, choice


def _settings_from_data(data, model, wall, ends, smoothing) -> tuple[str, str, list[str]]:
    """The wall form and end conditions not given, as the judged homogeneous fit (``identification.identify``)
    decides them, and what it said."""
    from identification import identify

    r = identify(data["positions"], data["pressure"], data["force"], thickness=data["thickness"], model=model,
                 wall=wall, ends=ends, smoothing=smoothing, uncertainty="gauss-newton", weighting="paper")
    return r.data.wall, r.data.ends, [f"settings from the homogeneous fit: {x}" for x in r.verdict_reasons]


def identify_regional_stored(path: str | os.PathLike, *, regions: RegionsSpec | int | str, model: str = "fung",
                             wall: str | None = None, ends: str | None = None,
                             smoothing: str | tuple[int, int] | None = "auto", markers: str | None = None,
                             uncertainty: str = "bootstrap", invoked_by: str = "pipeline",
                             progress: Callable[[int, int, str], None] | None = None) -> tuple[str, Any, dict]:
    """Identify profiles of ``model``'s stress-like parameters along the axis from the session; store a "regional"
    result.

    Parameters
    ----------
    path : session file.
    regions : RegionsSpec, or what ``parse_regions`` reads (a band count, "auto", "legendre:K").
    uncertainty : "bootstrap" (default; "auto" says the same here: standard errors and 95 % intervals that cover the
        truth) or "gauss-newton". ("gls" is the efficient homogeneous fit's: refused.)
    model, wall, ends, smoothing, markers, invoked_by : as ``pipeline.identify_stored`` (ends None: the session's).
    progress : called as ``progress(done, total, what)`` by the fits and the bootstrap (which take the time).

    Returns
    -------
    (group name e.g. "regional_001", the ``RegionalResult``, the inputs used; ``data["choice"]`` the
    ``BandChoice`` of "auto").
    """
    from identification import IdentificationError, get_model

    try:
        spec = regions if isinstance(regions, RegionsSpec) else parse_regions(regions)
    except ValueError as exc:
        raise StageError(str(exc)) from None
    if uncertainty not in ("auto", "bootstrap", "gauss-newton"):
        raise StageError(f"regional fits take uncertainty 'auto' (the bootstrap), 'bootstrap' or 'gauss-newton'; "
                         f"got {uncertainty!r}")
    uncertainty = "bootstrap" if uncertainty == "auto" else uncertainty
    data = read_identification_inputs(path, markers)
    ends, ends_source, ends_notes, ends_warnings = resolve_ends(data["session_ends"], ends)
    data["notes"] = list(data["notes"]) + ends_notes + ends_warnings
    try:
        if ends is None or wall is None:
            wall, ends, said = _settings_from_data(data, model, wall, ends, smoothing)
            data["notes"] += said
            ends_source = ends_source if ends_source != "the data" else "the data (homogeneous fit)"
        rd, result, choice = _identify(data, spec, model, wall, ends, smoothing, uncertainty, progress)
    except (IdentificationError, ValueError) as exc:
        raise StageError(f"{path}: cannot identify regional {model} with --regions {spec}: {exc}") from None
    data["choice"] = choice
    arrays, units = _result_arrays(get_model(model), result, rd, data["rows"], choice)
    settings = {"model": model, "wall": wall, "ends": ends, "ends_source": ends_source, "regions": str(spec),
                "n_bands": int(result.n_bands), "smoothing": smoothing, "markers_result": data["markers_result"],
                "thickness_m": round_floats(data["thickness"]), "force_correction": data["notes"]}
    attrs = {"model": model, "wall": wall, "cost": result.cost, "converged": result.converged,
             "flags": list(result.flags), "message": result.message, "regional": list(result.regional),
             "profile_kind": result.kind, "uncertainty": result.uncertainty, "confidence": 0.95,
             "axial_coordinate": "band_edges/band_centres: reference axial coordinate (m) along axis_direction from "
                                 "the mean reference marker position; *_world: the same points in the world frame",
             "smoothing_used": str(rd.data.smoothing),
             "field_names": list(result.field_names), "invoked_by": invoked_by}
    try:
        group = write_result(path, "regional", arrays, settings, attrs=attrs, units=units)
    except SessionError as exc:
        raise StageError(str(exc)) from None
    return group, result, data
