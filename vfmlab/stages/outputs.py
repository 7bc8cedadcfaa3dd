"""The report and export stages: what a session holds, as an HTML report with PNG figures, or as meshes and
fields per step that ParaView, PyVista and meshio open (VTU + .pvd series; legacy VTK or PLY on request) with the
latest parameter profile (CSV, VTK polyline).

Output folders default to ``<session stem>_report`` / ``<session stem>_export`` next to the session; files in SI.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vfmlab.stages.errors import StageError, StageFailed
from vfmlab.stages.feedback import ProgressFactory, no_progress
from vfmlab.stages.settings import ExportSettings, ReportSettings, settings_with

__all__ = ["ExportOutcome", "ReportOutcome", "default_out", "export", "hdf5_signature_offset", "latest_markers", "marker_labels",
           "report"]

_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def hdf5_signature_offset(path: str | os.PathLike) -> int | None:
    """Where the HDF5 signature of the file at ``path`` is, or None when it is no HDF5 file (or unreadable).

    The HDF5 specification (format signature, superblock) allows a user block before the superblock:
    the signature is then at 512, 1024, 2048, ... bytes (MATLAB v7.3 files have one of 512 bytes).
    """
    try:
        with open(path, "rb") as fh:
            size = os.fstat(fh.fileno()).st_size
            offset = 0
            while offset + len(_HDF5_SIGNATURE) <= size:
                fh.seek(offset)
                if fh.read(len(_HDF5_SIGNATURE)) == _HDF5_SIGNATURE:
                    return offset
                offset = 512 if offset == 0 else 2 * offset
    except OSError:
        return None
    return None


def marker_labels(result: dict, session_path: str | os.PathLike) -> Any:
    """The marker labels of a "markers" result (n_markers,): the imported labels, else the marker ids, else
    0..n-1. An imported result whose labels are gone is damaged (``DamagedSessionError``): numbering its
    markers afresh would silently rename them."""
    import numpy as np

    from acquisition.session import DamagedSessionError

    arrays, name = result["arrays"], result["name"]
    if "marker_label" in arrays:
        return arrays["marker_label"]
    if result.get("parameters", {}).get("source") == "import-markers":
        raise DamagedSessionError(
            f"{session_path}: the result {name!r} (/entry/results/{name}/marker_label) is damaged and cannot be read: "
            f"the imported marker labels are missing; 'vfmlab info {session_path}' shows what is still readable")
    return arrays.get("marker_id", np.arange(np.shape(arrays["positions"])[1]))


def default_out(session_path: str | os.PathLike, out: str | os.PathLike | None, kind: str) -> Path:
    """``out``, or ``<session stem>_<kind>`` next to the session."""
    path = Path(session_path)
    return Path(out) if out else path.with_name(path.stem + "_" + kind)


def latest_markers(session) -> dict:
    """The newest "markers" result of an open session, or a StageError saying how to make one."""
    result = session.latest("markers")
    if result is None:
        raise StageError(
            f"{session.path}: no marker tracks yet; run 'vfmlab reconstruct {session.path}' "
            "or build the session with 'vfmlab import-markers'"
        )
    return result


@dataclass(frozen=True)
class ReportOutcome:
    """The report written: ``html`` (its path), ``figures`` (PNG paths) and the time it took."""

    html: Path
    figures: list[Path]
    seconds: float

    def to_dict(self) -> dict[str, Any]:
        """What ``vfmlab report --json`` prints."""
        return {"report": str(self.html), "url": self.html.resolve().as_uri(), "figures": [str(f) for f in self.figures],
                "seconds": self.seconds}


def report(session_path: str | os.PathLike, settings: ReportSettings | None = None, *,
           progress: ProgressFactory = no_progress, **overrides: Any) -> ReportOutcome:
    """Write a self-contained HTML report of the session (figures embedded) and each figure as SVG, 300 dpi PNG
    and JSON data (``vfmlab report``; defaults: :class:`ReportSettings`). An earlier report in the output folder is
    replaced whole, atomically; ``progress`` counts the sections."""
    from vfmlab.report import build_report

    s = settings_with(ReportSettings, settings, overrides)
    t0 = time.perf_counter()
    with progress("report", None) as update:
        html = build_report(session_path, default_out(session_path, s.out, "report"), strain_scale=s.strain_scale,
                            progress=lambda done, total, what: update(done, total, f"report: {what}" if done < total else None))
    figures = sorted(Path(html).parent.glob("fig*.png"))
    return ReportOutcome(Path(html), figures, time.perf_counter() - t0)


@dataclass(frozen=True)
class ExportOutcome:
    """The files written: ``files`` (meshes per step, then the .pvd or .vtk.series indexes), ``profile`` (CSV and VTK
    polyline of the latest regional result, or none), the ``fields`` exported and where they came from."""

    out: Path
    fmt: str
    files: list[Path]
    profile: list[Path]
    fields: Any
    markers_result: str
    profile_result: str | None

    def to_dict(self) -> dict[str, Any]:
        """What ``vfmlab export --json`` prints."""
        return {"out": str(self.out), "format": self.fmt, "markers_result": self.markers_result,
                "n_steps": len(self.fields.positions), "files": [str(f) for f in self.files],
                "profile_files": [str(f) for f in self.profile], "profile_result": self.profile_result,
                "units": {"length": "m", "stress": "Pa", "strain": "1"}}


def export(session_path: str | os.PathLike, settings: ExportSettings | None = None, **overrides: Any) -> ExportOutcome:
    """Export the marker mesh of the session at every step with E11/E22/E12 strains and each identified model's
    stresses as cell data, and the latest parameter profile along the axis (``vfmlab export``; defaults:
    :class:`ExportSettings`). Lengths in m, stresses in Pa."""
    from acquisition.session import open_session
    import numpy as np

    from vfmlab.export import StepTimes, export_fields, export_profile
    from vfmlab.fields import FieldsError, compute_fields

    s = settings_with(ExportSettings, settings, overrides)
    path = Path(session_path)
    out_dir = default_out(path, s.out, "export")
    with open_session(path) as session:
        if s.markers_name:
            if s.markers_name not in session.results("markers"):
                raise StageError(f"{path}: no markers result {s.markers_name!r}; markers results are "
                                 f"{', '.join(session.results('markers')) or 'none'}")
            markers = session.result(s.markers_name)
        else:
            markers = latest_markers(session)
        latest = {}
        for name in session.results("identification"):
            r = session.result(name)
            latest[(r["attrs"].get("model"), r["attrs"].get("wall"))] = r
        try:
            fields = compute_fields(markers, session.steps, list(latest.values()))
        except (FieldsError, ValueError) as exc:  # MeshError is a ValueError
            raise StageError(f"{path}: cannot build the surface fields from {markers['name']}: {exc}") from None
        specimen = session.specimen.specimen_id
        clock = np.asarray(session.steps["t_monotonic"], float)[fields.steps]
        times = StepTimes(np.asarray(session.steps["block"], int)[fields.steps], clock - clock[0])
        regional = session.latest("regional") if session.results("regional") else None
    try:
        files = export_fields(fields, out_dir, fmt=s.fmt, specimen=specimen, times=times)
        profile = [] if regional is None else export_profile(regional, out_dir, specimen=specimen)
    except OSError as exc:
        raise StageFailed(f"cannot write to {out_dir}: {exc}") from None
    return ExportOutcome(out_dir, s.fmt, files, profile, fields, markers["name"],
                         None if regional is None else regional["name"])
