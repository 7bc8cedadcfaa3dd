"""Assemble the HTML report of a session: a first page that answers the question (the models, their verdicts and
fits), then the figures a paper prints, then the details; written into a staging folder and renamed into place."""

from __future__ import annotations

import html
import logging
import os
import time
from collections.abc import Callable
from pathlib import Path

from acquisition.errors import InputError
from acquisition.session import open_session
from vfmlab.report import figures, maps, profile, sections, summary
from vfmlab.report.context import Context
from vfmlab.report.output import ReportFiles, staged_dir
from vfmlab.report.page import SECTION_FAILED, page

log = logging.getLogger(__name__)

__all__ = ["build_report", "ReportError", "SECTION_FAILED", "SECTIONS"]

ANSWER, PAPER_FIGURES, DETAILS = "The answer", "Figures for a paper", "Details"
_SCALES = ("shared", "per-step")

#: (anchor, title, part, section function): the order of the page.
SECTIONS: list[tuple[str, str, str, Callable[[Context, ReportFiles], str]]] = [
    ("summary", "Identified models and their fits", ANSWER, summary.section),
    ("stress-strain", "Stress–strain curves", PAPER_FIGURES, sections.stress_strain),
    ("strain", "Strain maps", PAPER_FIGURES, maps.strain_section),
    ("stress", "Stress maps", PAPER_FIGURES, maps.stress_section),
    ("virtual-work", "Internal vs external virtual work", PAPER_FIGURES, sections.virtual_work),
    ("regional", "Parameters along the axis", PAPER_FIGURES, profile.section),
    ("parameters", "Identified parameters", DETAILS, sections.parameters),
    ("comparison", "Model comparison", DETAILS, sections.comparison),
    ("pressure-radius", "Pressure–radius at mid-span", DETAILS, sections.pressure_radius),
    ("specimen", "Specimen", DETAILS, sections.specimen),
    ("protocol", "Protocol", DETAILS, sections.protocol),
    ("instruments", "Instruments", DETAILS, sections.instruments),
    ("calibration", "Calibration quality", DETAILS, sections.calibration),
    ("markers", "Marker reconstruction", DETAILS, sections.markers),
    ("provenance", "Provenance", DETAILS, sections.provenance),
]


class ReportError(InputError):
    """The report cannot be written: the session cannot be read (exit code 2, decision 0007)."""


def build_report(session_path: str | os.PathLike, out_dir: str | os.PathLike | None = None, *,
                 strain_scale: str = "shared",
                 progress: Callable[[int, int, str], None] | None = None) -> Path:
    """Write ``report.html`` (self-contained: figures embedded as PNG) and each figure as SVG, 300 dpi PNG and its
    plotted data (JSON) into ``out_dir``.

    The files are written into a staging folder beside ``out_dir`` and renamed into place at the end: an earlier
    report in ``out_dir`` is replaced whole, an interrupted run leaves it as it was; a folder that is not a report
    folder (:func:`~vfmlab.report.output.is_report_dir`) receives the new files and keeps its others.

    Parameters
    ----------
    session_path : path of the session file.
    out_dir : output directory (its parent must exist); default ``<session stem>_report`` next to the session.
    strain_scale : "shared" (one colour scale for all steps of a surface map) or "per-step".
    progress : called as ``progress(done, total, what)`` before each section and once at the end.

    Returns
    -------
    Path of the HTML file.

    Raises
    ------
    ReportError
        When the session cannot be opened or ``strain_scale`` is unknown.
    """
    from acquisition.session import SessionError

    session_path = Path(session_path)
    out = Path(out_dir) if out_dir is not None else session_path.with_name(session_path.stem + "_report")
    if strain_scale not in _SCALES:
        raise ReportError(f"strain_scale must be one of {', '.join(_SCALES)}; got {strain_scale!r}")
    try:
        session = open_session(session_path)
    except SessionError as exc:
        raise ReportError(str(exc)) from None
    tell = progress or (lambda done, total, what: None)
    total = len(SECTIONS) + 1
    t0 = time.perf_counter()
    with session, staged_dir(out) as folder:
        tell(0, total, "surface fields")
        ctx = Context(session)
        rep = ReportFiles(folder, strain_scale=strain_scale)
        import matplotlib

        drawn = []
        with matplotlib.rc_context(figures._RC):
            for i, (anchor, title, part, fn) in enumerate(SECTIONS):
                tell(i + 1, total, title)
                drawn.append((anchor, title, _section(fn, ctx, rep, title), part))
        (folder / "report.html").write_text(page(session.specimen.specimen_id, session_path, drawn), encoding="utf-8")
        n_figures = len(rep.figures)
    tell(total, total, "done")
    log.info("report %s: %d figures, %.1f s", out / "report.html", n_figures, time.perf_counter() - t0)
    return out / "report.html"


def _section(fn: Callable[[Context, ReportFiles], str], ctx: Context, rep: ReportFiles, title: str) -> str:
    try:
        return fn(ctx, rep)
    except Exception as exc:  # one broken section must not cost the whole report
        log.warning("report section %r failed: %s: %s", title, type(exc).__name__, exc)
        log.debug("report section %r failed", title, exc_info=exc)
        return f'<p class="failed">{SECTION_FAILED}: {html.escape(type(exc).__name__)}: {html.escape(str(exc))}</p>'
