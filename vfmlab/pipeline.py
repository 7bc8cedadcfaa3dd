"""Pipeline stages over session files: the functions the CLI commands, ``reprocess`` and the demo share.

Each stage reads what it needs from a session file, runs a stage package on the arrays and appends
one new result group (never overwriting); it returns the group's name. The registry ``STAGES`` maps
stage names to these functions so that ``vfmlab reprocess --stages reconstruct,identify`` runs
exactly the code ``vfmlab reconstruct`` / ``vfmlab identify`` run.

Errors: :class:`StageError` with one readable sentence (session path first).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.session import SessionError, open_session, write_result

log = logging.getLogger(__name__)

__all__ = ["STAGES", "StageError", "StageUnavailable", "identify_session", "load_identification_inputs",
           "reconstruct_session"]


class StageError(Exception):
    """A stage could not run on a session (missing input, failed computation)."""


class StageUnavailable(StageError):
    """The stage's implementation is not installed in this build."""


def load_identification_inputs(session, markers: str | None = None) -> dict[str, Any]:
    """What the identification needs from an open session, from the latest (or named) markers result.

    Returns positions (n_steps, n_markers, 3) m (NaN where not visible), pressure (n_steps,) Pa,
    force (n_steps,) N (wall force: a "total" load-cell reading is corrected by + p pi r_i^2 with
    the reference lumen radius r_i = radius - thickness, decision 0003), thickness m, rows
    (n_steps,) rows of the step table, markers_result name and notes (corrections applied).
    """
    names = session.results("markers")
    if markers is not None and markers not in names:
        raise StageError(f"{session.path}: no markers result {markers!r}; markers results are {names}")
    if not names:
        raise StageError(f"{session.path}: no marker tracks yet; run 'vfmlab reconstruct' first "
                         "(or build the session with 'vfmlab import-markers')")
    result = session.result(markers or names[-1])
    arrays = result["arrays"]
    if "positions" not in arrays:
        raise StageError(f"{session.path}: the markers result {result['name']} has no 'positions' array")
    positions = np.asarray(arrays["positions"], dtype=float)
    if "visible" in arrays:
        positions = np.where(np.asarray(arrays["visible"], bool)[..., None], positions, np.nan)
    rows = np.asarray(arrays.get("step_index", np.arange(positions.shape[0])), int)
    if rows.size != positions.shape[0] or (rows.size and (rows.max() >= session.n_steps or rows.min() < 0)):
        raise StageError(f"{session.path}: markers result {result['name']} refers to steps {rows.tolist()} but the "
                         f"session has {session.n_steps} steps")
    steps = session.steps
    pressure = np.asarray(steps["pressure"], float)[rows]
    force = np.asarray(steps["force"], float)[rows]
    specimen = session.specimen
    notes = []
    if session.load_cell_measures == "total":
        r_i = specimen.radius - specimen.thickness
        force = force + pressure * np.pi * r_i**2
        notes.append(f"load cell measures total force: wall force = total + p*pi*r_i^2 with r_i = {r_i * 1e3:.3f} mm")
    return {"positions": positions, "pressure": pressure, "force": force, "thickness": float(specimen.thickness),
            "markers_result": result["name"], "rows": rows, "notes": notes}


def identify_session(path: str | os.PathLike, *, model: str = "fung", wall: str = "membrane", ends: str = "clamped",
                     optimizer: str = "lsq", markers: str | None = None, invoked_by: str = "pipeline") -> str:
    """Identify ``model`` from the session's marker tracks with the VFM and store an "identification" result.

    Parameters
    ----------
    path : session file.
    model : "fung" | "delfino" | "hgo" | "neohookean".
    wall : "membrane" | "thick".
    ends : "clamped" | "free".
    optimizer : "lsq" | "nelder-mead".
    markers : markers result to use (default: the latest).
    invoked_by : recorded in the result's attributes (e.g. "identify", "reprocess").

    Returns
    -------
    Name of the new result group, e.g. "identification_003".
    """
    try:
        from identification import IdentificationError, identify
    except ImportError as exc:  # pragma: no cover - the identification package ships with vfmlab
        raise StageUnavailable(f"the identification package is not available: {exc}") from None
    try:
        with open_session(path) as session:
            data = load_identification_inputs(session, markers)
    except SessionError as exc:
        raise StageError(str(exc)) from None
    try:
        result = identify(data["positions"], data["pressure"], data["force"], thickness=data["thickness"],
                          model=model, wall=wall, ends=ends, optimizer=optimizer)
    except (IdentificationError, ValueError) as exc:
        raise StageError(f"{path}: cannot identify {model}: {exc}") from None
    names = list(result.parameters)
    arrays = {
        "parameters": np.array([result.parameters[n] for n in names]),
        "stderr": np.array([result.stderr[n] for n in names]),
        "parameter_names": np.array(names, dtype=object).astype(str),
        "correlation": result.correlation,
        "ivw": result.ivw,
        "evw": result.evw,
        "residuals": result.residuals,
        "step_index": data["rows"],
    }
    settings = {"model": model, "wall": wall, "ends": ends, "optimizer": optimizer,
                "markers_result": data["markers_result"], "thickness": data["thickness"],
                "force_correction": data["notes"]}
    attrs = {"model": model, "wall": wall, "cost": result.cost, "converged": result.converged,
             "flags": list(result.flags), "message": result.message, "n_evaluations": result.n_evaluations,
             "field_names": list(result.field_names), "invoked_by": invoked_by}
    try:
        return write_result(path, "identification", arrays, settings, attrs=attrs,
                            units={"ivw": "J", "evw": "J", "residuals": "1"})
    except SessionError as exc:
        raise StageError(str(exc)) from None


def reconstruct_session(path: str | os.PathLike, **settings: Any) -> str:
    """Reconstruct and track the 3-D markers of a session; store a "markers" result and return its name.

    Delegates to ``vfmlab.cli.cmd_reconstruct.reconstruct_session(path, **settings)``, the function
    behind ``vfmlab reconstruct``.
    """
    try:
        from vfmlab.cli.cmd_reconstruct import reconstruct_session as impl  # type: ignore[attr-defined]
    except ImportError as exc:
        raise StageUnavailable(f"{path}: the reconstruct stage is not available in this build ({exc})") from None
    try:
        return impl(path, **settings)
    except SessionError as exc:
        raise StageError(str(exc)) from None


#: Stage name -> function(path, **settings) -> result group name.
STAGES: dict[str, Callable[..., str]] = {
    "reconstruct": reconstruct_session,
    "identify": identify_session,
}

#: Order in which stages run when several are requested.
STAGE_ORDER = ("reconstruct", "identify")


def session_label(path: str | os.PathLike) -> str:
    return Path(path).name
