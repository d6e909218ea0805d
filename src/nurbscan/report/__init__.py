"""A self-contained HTML scan report (issue 8): :func:`build_report`, :func:`write_report`."""

from .html import (
    build_report,
    detect_overlays,
    error_colours,
    find_overlays,
    report_html,
    vertex_errors,
    write_report,
)

__all__ = ["build_report", "detect_overlays", "error_colours", "find_overlays", "report_html",
           "vertex_errors", "write_report"]
