"""The loads export stage (``vfmlab export-loads``): a session's step loads as the CSV that ``import-markers``
reads, numbered as ``export-markers`` numbers the steps, so the two files rebuild the session elsewhere."""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vfmlab.stages.errors import StageError, StageFailed

__all__ = ["LoadsOutcome", "export_loads"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LoadsOutcome:
    """The loads written: ``out``, the number of steps, the markers result whose step numbers were used (or None:
    step = row of the step table) and what the session's load cell measures (``import-markers --force-is``)."""

    out: Path
    n_steps: int
    markers_result: str | None
    load_cell_measures: str

    def to_dict(self) -> dict[str, Any]:
        """What ``vfmlab export-loads --json`` prints."""
        return {"out": str(self.out), "n_steps": self.n_steps, "markers_result": self.markers_result,
                "load_cell_measures": self.load_cell_measures,
                "columns": ["step", "pressure_Pa", "axial_force_N", "stretch"]}


def _step_numbers(markers: dict | None, n_rows: int):
    """(rows of the step table, their step numbers): the numbering ``export-markers`` writes for ``markers``."""
    import numpy as np

    if markers is None:
        return np.arange(n_rows), np.arange(n_rows)
    arrays = markers["arrays"]
    n = len(arrays["positions"])
    index = np.asarray(arrays.get("step_index", np.arange(n)), int)
    if "step_number" not in arrays:
        return np.arange(n_rows), np.arange(n_rows)  # export-markers writes step_index: the row itself
    numbers = np.asarray(arrays["step_number"], int)
    if len(index) < n_rows:
        log.info("%d step(s) of the session are not in %s and are left out (they have no step number there)",
                 n_rows - len(index), markers["name"])
    return index, numbers


def export_loads(session_path: str | os.PathLike, out: str | os.PathLike, *,
                 markers_name: str | None = None) -> LoadsOutcome:
    """Write the step table's pressure (Pa), axial force (N) and stretch as ``step,pressure_Pa,axial_force_N,
    stretch`` to ``out``; steps are numbered as ``export-markers`` numbers them for ``markers_name`` (default:
    the latest markers result; none stored: the row of the step table)."""
    import numpy as np

    from acquisition.markers_csv import write_loads_csv
    from acquisition.session import open_session

    path = Path(session_path)
    with open_session(path) as session:
        if markers_name and markers_name not in session.results("markers"):
            raise StageError(f"{path}: no markers result {markers_name!r}; markers results are "
                             f"{', '.join(session.results('markers')) or 'none'}")
        markers = session.result(markers_name) if markers_name else session.latest("markers")
        steps = session.steps
        measures = str(session.load_cell_measures)
    rows, numbers = _step_numbers(markers, len(steps["pressure"]))
    try:
        write_loads_csv(out, numbers, np.asarray(steps["pressure"], float)[rows],
                        np.asarray(steps["force"], float)[rows], np.asarray(steps["stretch"], float)[rows])
    except OSError as exc:
        raise StageFailed(f"cannot write {out}: {exc}") from None
    return LoadsOutcome(Path(out), len(rows), None if markers is None else str(markers["name"]), measures)
