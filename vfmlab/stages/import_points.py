"""Building a session from 3-D points measured elsewhere (``vfmlab import-markers``, ``vfmlab import-dic``): the
points (a marker CSV or another lab's DIC result) and the loads, checked (:func:`vfmlab.stages.imports.check_marker_inputs`),
written all or nothing (built under a temporary name, renamed onto OUT at the end) as a session whose "markers" result
holds the points. A point missing at a step is NaN there, as a marker is.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vfmlab.stages.errors import StageError, StageFailed
from vfmlab.stages.feedback import Notify, log_notes
from vfmlab.stages.imports import mm_to_m

__all__ = ["DIC_FORMATS", "DICSource", "ImportedPoints", "PointImportSettings", "import_dic", "import_markers",
           "import_point_session", "read_dic_table"]

#: ``--format`` of ``vfmlab import-dic``
DIC_FORMATS = ("duodic", "multidic", "vic3d", "table")


@dataclass(frozen=True)
class PointImportSettings:
    """What ``import-markers`` / ``import-dic`` record besides the points: the specimen (mm as on the command line;
    radius and length fitted to step 0 when None), what the load cell measures and how the ends were held."""

    thickness_mm: float
    radius_mm: float | None = None
    length_mm: float | None = None
    specimen_id: str = ""
    notes: str = ""
    force_is: str = "wall"
    ends: str | None = None
    overwrite: bool = False


    @classmethod
    def from_options(cls, options: dict, default_id: str) -> PointImportSettings:
        """From the command's parsed options (``specimen_id`` None: ``default_id``); other keys are ignored."""
        known = {k: options[k] for k in ("thickness_mm", "radius_mm", "length_mm", "notes", "force_is", "ends",
                                         "overwrite") if k in options}
        return cls(specimen_id=options.get("specimen_id") or default_id, **known)


@dataclass(frozen=True)
class ImportedPoints:
    """The session written: its "markers" result ``name``, counts, the specimen's geometry (m) and settings."""

    name: str
    n_markers: int
    n_steps: int
    radius: float
    length: float
    settings: PointImportSettings

    def summary(self, out: str | Path) -> dict:
        """The command's ``--json`` (SI)."""
        s = self.settings
        return {"out": str(out), "result": self.name, "n_markers": self.n_markers, "n_steps": self.n_steps,
                "radius_m": self.radius, "length_m": self.length, "thickness_m": mm_to_m(s.thickness_mm),
                "load_cell_measures": s.force_is, "ends": s.ends}

    def details(self) -> str:
        """The parenthesis of the command's sentence: result, geometry, load cell and ends."""
        s = self.settings
        return (f"result {self.name}; radius {self.radius * 1e3:.3f} mm, length {self.length * 1e3:.3f} mm, "
                f"wall thickness {s.thickness_mm:.3f} mm, load cell measures {s.force_is} force, "
                + (f"ends {s.ends}" if s.ends else "ends not recorded: identify lets the data decide unless --ends says"))


@dataclass(frozen=True)
class DICSource:
    """The DIC result to import: ``paths`` (one file; VIC-3D: one per step in step order, or their folder), its
    ``fmt`` (:data:`DIC_FORMATS`), the ``columns`` mapping of a table and the points' length ``unit``."""

    paths: tuple[Path, ...]
    fmt: str
    columns: str | None = None
    unit: str = "mm"


def import_markers(markers_csv: str, loads_csv: str, out: Path, s: PointImportSettings, *,
                   warn: Notify = log_notes) -> ImportedPoints:
    """``vfmlab import-markers``: the session ``out`` from a marker CSV and a loads CSV."""
    from acquisition.markers_csv import read_loads_csv, read_markers_csv

    table, loads = read_markers_csv(markers_csv), read_loads_csv(loads_csv)
    rig = {"source": "import-markers", "markers_csv": str(markers_csv), "loads_csv": str(loads_csv)}
    return import_point_session(out, table, loads, (markers_csv, loads_csv), s, rig, warn=warn)


def import_dic(src: DICSource, loads_csv: str, out: Path, s: PointImportSettings, *,
               warn: Notify = log_notes) -> ImportedPoints:
    """``vfmlab import-dic``: the session ``out`` from another lab's DIC points and a loads CSV."""
    from acquisition.markers_csv import read_loads_csv

    table = read_dic_table(list(src.paths), src.fmt, src.columns, src.unit)
    loads = read_loads_csv(loads_csv)
    files = ", ".join(map(str, src.paths))
    rig = {"source": "import-dic", "format": src.fmt, "dic_files": files, "unit": src.unit,
           "loads_csv": str(loads_csv)}
    return import_point_session(out, table, loads, (files, loads_csv), s, rig, warn=warn)


def _natural(path: Path) -> list:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", path.name)]


def _vic3d_files(paths: list[Path]) -> list[Path]:
    """VIC-3D exports in step order: the files as given, or a folder's ``*.csv`` in natural name order."""
    if len(paths) == 1 and paths[0].is_dir():
        files = sorted(paths[0].glob("*.csv"), key=_natural)
        if not files:
            raise StageError(f"{paths[0]}: no *.csv files (VIC-3D exports, one per step)")
        return files
    return paths


def read_dic_table(paths: list[Path], fmt: str, columns: str | None = None, unit: str = "mm") -> Any:
    """Another lab's DIC points as a marker table (``acquisition.markers_csv.MarkerTable``: ``positions``
    (n_steps, n_points, 3) m, NaN where missing; ``labels`` the point indices "0".."n-1" in the reader's order;
    ``steps`` the step numbers, 0 first). ``fmt`` is one of :data:`DIC_FORMATS`; a bad file is a StageError
    carrying the reader's one-line message."""
    from acquisition import dic
    from acquisition.markers_csv import MarkerTable

    if fmt not in DIC_FORMATS:
        raise StageError(f"--format must be one of {list(DIC_FORMATS)}; got {fmt!r}")
    if fmt != "vic3d" and len(paths) != 1:
        raise StageError(f"--format {fmt} reads one file; got {len(paths)}")
    if (fmt == "table") != (columns is not None):
        raise StageError("--columns is needed with --format table (e.g. 'id=point,step=frame,x=X,y=Y,z=Z') "
                         "and only there")
    try:
        if fmt in ("duodic", "multidic"):
            points = dic.read_duodic_points(paths[0], unit=unit)
        elif fmt == "vic3d":
            points = dic.read_vic3d_csv(_vic3d_files(paths), unit=unit)
        else:
            points = dic.read_point_table(paths[0], str(columns), unit=unit)
    except (dic.DICImportError, OSError) as exc:
        raise StageError(str(exc)) from None
    steps = np.arange(points.n_steps)
    if fmt == "table":
        try:
            steps = np.array([int(float(s)) for s in points.step_names])
        except ValueError:
            raise StageError(f"{points.source}: step values must be integers; got {list(points.step_names)[:5]}") from None
        if steps[0] != 0:
            raise StageError(f"{points.source}: no points for step 0 (the reference); first step is {steps[0]}")
    labels = np.array([str(i) for i in range(points.n_points)])
    return MarkerTable(labels=labels, steps=steps, positions=points.points)


def import_point_session(out: Path, table: Any, loads: dict, sources: tuple[str, str], s: PointImportSettings,
                         provenance: dict, *, warn: Notify = log_notes) -> ImportedPoints:
    """Check ``table`` (points) against ``loads`` (``read_loads_csv``) and write the session ``out``: one step per
    table step, the points as its "markers" result. ``sources`` = (points file(s), loads file) as the messages name
    them; ``provenance`` is stored as the rig's and the result's description (e.g. ``{"source": "import-dic"}``)."""
    from acquisition.session import (SessionError, SessionWriter, SpecimenInfo, StepRecord, import_failure,
                                     staged_session)
    from vfmlab.stages.imports import check_marker_inputs

    points_src, loads_src = sources
    missing = sorted(set(table.steps.tolist()) - set(loads["step"].tolist()))
    if missing:
        raise StageError(f"{loads_src}: no loads for step(s) {missing} that appear in {points_src}")
    rows = np.searchsorted(loads["step"], table.steps)
    radius, length, warnings = check_marker_inputs(table, loads, rows, points_src, loads_src, s.thickness_mm,
                                                   s.radius_mm, s.length_mm, warn)
    try:
        specimen = SpecimenInfo(s.specimen_id, radius, length, mm_to_m(s.thickness_mm), s.notes, s.ends or "",
                                "import option --ends" if s.ends else "")
    except ValueError as exc:
        raise StageError(str(exc)) from None
    try:
        with staged_session(out, overwrite=s.overwrite) as staged:
            with SessionWriter.create(staged.path, specimen, protocol_text="", rig=provenance,
                                      load_cell_measures=s.force_is) as writer:
                for message in warnings:
                    writer.add_event("warning", message)
                for row in rows:
                    writer.add_step(StepRecord(
                        block=0, stretch=float(loads["stretch"][row]),
                        target_pressure=float(loads["pressure"][row]), pressure=float(loads["pressure"][row]),
                        force=float(loads["axial_force"][row]), t_monotonic=float("nan"), t_wall=float("nan")))
            name = staged.add_result("markers", _marker_arrays(table), _result_params(provenance),
                                     units={"positions": "m", "uncertainty": "m"})
    except SessionError as exc:
        raise StageFailed(str(exc)) from None
    except OSError as exc:
        raise StageFailed(import_failure(out, exc)) from None
    return ImportedPoints(name, len(table.labels), len(table.steps), radius, length, s)


def _marker_arrays(table: Any) -> dict:
    visible = ~np.isnan(table.positions).any(axis=2)
    return {"positions": table.positions, "visible": visible, "uncertainty": np.full(visible.shape, np.nan),
            "marker_id": np.arange(len(table.labels)), "marker_label": table.labels,
            "step_index": np.arange(len(table.steps)), "step_number": table.steps}


def _result_params(provenance: dict) -> dict:
    """The markers result's parameters: the provenance without the loads file (as import-markers always stored)."""
    return {k: v for k, v in provenance.items() if k != "loads_csv"}
