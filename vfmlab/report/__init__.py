"""Session reports: a self-contained HTML page with matplotlib figures (also written as PNG files)."""

from vfmlab.report.build import SECTION_FAILED, ReportError, build_report

__all__ = ["build_report", "ReportError", "SECTION_FAILED"]
