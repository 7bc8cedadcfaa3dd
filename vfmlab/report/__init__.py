"""Session reports: a self-contained HTML page (figures embedded) with each figure as SVG, 300 dpi PNG and JSON data."""

from vfmlab.report.build import SECTION_FAILED, ReportError, build_report
from vfmlab.report.output import is_report_dir

__all__ = ["build_report", "is_report_dir", "ReportError", "SECTION_FAILED"]
