"""Regional identification stage: per-band parameter profiles from a session, stored as a "regional" result.

Session I/O here; the computation is ``identification.regional`` (pure). Units SI in the file (m, Pa), with the unit
on every dataset.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from acquisition.session import SessionError, write_result
from vfmlab.pipeline import StageError, read_identification_inputs, resolve_ends

__all__ = ["identify_regional_stored"]


def _result_arrays(model, result, rd, rows) -> tuple[dict, dict]:
    """Datasets of the stored result and their units."""
    units = dict(zip(model.parameter_names, model.units))
    arrays = {
        "band_edges": rd.edges, "band_centres": rd.centres, "band_edges_world": rd.world_points(rd.edges),
        "differs": result.differs.astype(np.int8), "residuals": result.residuals, "step_index": rows,
        "regional_names": np.array(result.regional, dtype=object).astype(str),
        "shared_names": np.array(list(result.parameters), dtype=object).astype(str),
        "shared_parameters": np.array(list(result.parameters.values()), dtype=float),
        "shared_stderr": np.array(list(result.parameter_stderr.values()), dtype=float),
        "homogeneous_parameters": np.array(list(result.homogeneous.parameters.values()), dtype=float),
        "homogeneous_stderr": np.array(list(result.homogeneous.stderr.values()), dtype=float),
    }
    out_units = {"band_edges": "m", "band_centres": "m", "band_edges_world": "m", "differs": "1", "residuals": "1"}
    for n in result.regional:
        arrays[n], arrays[f"{n}_stderr"] = result.profiles[n], result.stderr[n]
        arrays[f"{n}_z_score"] = result.z_score[n]
        out_units.update({n: units[n], f"{n}_stderr": units[n], f"{n}_z_score": "1"})
    return arrays, out_units


def identify_regional_stored(path: str | os.PathLike, *, n_bands: int, model: str = "fung", wall: str = "membrane",
                             ends: str | None = None, smoothing: tuple[int, int] | None = None,
                             markers: str | None = None, invoked_by: str = "pipeline") -> tuple[str, Any, dict]:
    """Identify per-band profiles of ``model``'s stress-like parameters from the session; store a "regional" result.

    Parameters
    ----------
    path : session file.
    n_bands : number of equal axial bands between the measured ends.
    model, wall, ends, smoothing, markers, invoked_by : as ``pipeline.identify_stored`` (ends None: the session's).

    Returns
    -------
    (group name e.g. "regional_001", the ``RegionalResult``, the inputs used).
    """
    from identification import IdentificationError, get_model
    from identification.regional import identify_regional, prepare_regional

    data = read_identification_inputs(path, markers)
    ends, ends_source, ends_notes, ends_warnings = resolve_ends(data["session_ends"], ends)
    data["notes"] = list(data["notes"]) + ends_notes + ends_warnings
    try:
        rd = prepare_regional(data["positions"], data["pressure"], data["force"], thickness=data["thickness"],
                              n_bands=n_bands, wall=wall, ends=ends, smoothing=smoothing)
        result = identify_regional(rd, model)
    except (IdentificationError, ValueError) as exc:
        raise StageError(f"{path}: cannot identify regional {model} with {n_bands} bands: {exc}") from None
    arrays, units = _result_arrays(get_model(model), result, rd, data["rows"])
    settings = {"model": model, "wall": wall, "ends": ends, "ends_source": ends_source, "n_bands": int(n_bands),
                "smoothing": smoothing,
                "markers_result": data["markers_result"], "thickness": data["thickness"],
                "force_correction": data["notes"]}
    attrs = {"model": model, "wall": wall, "cost": result.cost, "converged": result.converged,
             "flags": list(result.flags), "message": result.message, "regional": list(result.regional),
             "field_names": list(result.field_names), "invoked_by": invoked_by}
    try:
        group = write_result(path, "regional", arrays, settings, attrs=attrs, units=units)
    except SessionError as exc:
        raise StageError(str(exc)) from None
    return group, result, data
