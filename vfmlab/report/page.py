"""The report page's HTML: style, small helpers for tables and absent data, and the page around the sections."""

from __future__ import annotations

import datetime as _dt
import html
from pathlib import Path
from typing import Any

from vfmlab import __version__
from vfmlab.display import num

__all__ = ["SECTION_FAILED", "Raw", "absent", "fmt", "page", "table"]

#: Marker text placed in a section whose drawing raised an unexpected error (tests look for it).
SECTION_FAILED = "This section could not be drawn"

CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',Helvetica,Arial,sans-serif;max-width:1100px;margin:2em auto;
padding:0 1em;color:#222;line-height:1.45}
h1{border-bottom:2px solid #345;padding-bottom:.2em}h2{margin-top:2em;border-bottom:1px solid #ccc;color:#234}
table{border-collapse:collapse;margin:.6em 0;font-size:.92em}th,td{border:1px solid #ccc;padding:.25em .6em;
text-align:left;vertical-align:top}th{background:#eef2f6}td.num{text-align:right;font-variant-numeric:tabular-nums}
figure{margin:1em 0}figure img{max-width:100%;height:auto;border:1px solid #eee}figcaption{font-size:.9em;color:#555}
pre{background:#f6f8fa;padding:.8em;overflow-x:auto;font-size:.85em;border:1px solid #e1e4e8}
.absent{color:#777;font-style:italic}.failed{color:#a00}.flag{color:#a60;font-weight:bold}
nav ul{columns:2;font-size:.92em}.caveat{color:#a00;font-weight:bold}.interval{color:#555;font-size:.9em}
.verdict.trusted{color:#060;font-weight:bold}.verdict.doubtful{color:#a00;font-weight:bold}
.row{display:flex;flex-wrap:wrap;gap:1em}.row figure{flex:1 1 460px;margin:.5em 0}
.part{margin-top:2.5em;color:#345;font-size:1.7em;border-bottom:3px double #345}
"""


def absent(sentence: str) -> str:
    return f'<p class="absent">{html.escape(sentence)}</p>'


def table(header: list[str], rows: list[list[Any]], numeric: frozenset[int] | set[int] = frozenset()) -> str:
    out = ["<table><tr>" + "".join(f"<th>{html.escape(str(h))}</th>" for h in header) + "</tr>"]
    for row in rows:
        cells = []
        for j, v in enumerate(row):
            cls = ' class="num"' if j in numeric else ""
            cells.append(f"<td{cls}>{v if isinstance(v, Raw) else html.escape(str(v))}</td>")
        out.append("<tr>" + "".join(cells) + "</tr>")
    return "".join(out) + "</table>"


class Raw(str):
    """Already-escaped HTML for a table cell."""


def fmt(value: float, digits: int = 4) -> str:
    return num(value, digits)


def page(specimen: str, session_path: Path, sections: list[tuple[str, str, str, str]]) -> str:
    """The whole page: title, a table of contents by part, then ``sections`` (anchor, title, body html, part)."""
    now = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    parts: dict[str, list[tuple[str, str, str]]] = {}
    for anchor, title, body, part in sections:
        parts.setdefault(part, []).append((anchor, title, body))
    nav = "".join(f"<li>{html.escape(part)}<ul>" + "".join(f'<li><a href="#{a}">{html.escape(t)}</a></li>'
                                                            for a, t, _ in items) + "</ul></li>"
                  for part, items in parts.items())
    body = "".join(f'<div class="part">{html.escape(part)}</div>' + "".join(
        f'<section id="{a}"><h2>{html.escape(t)}</h2>{b}</section>' for a, t, b in items) for part, items in parts.items())
    return (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>vfmlab report: {html.escape(specimen)}</title><style>{CSS}</style></head><body>"
            f"<h1>Inflation/extension test report: {html.escape(specimen)}</h1>"
            f"<p>Session <code>{html.escape(str(session_path))}</code>; report written {now} by vfmlab "
            f"{html.escape(__version__)}.</p><nav><ul>{nav}</ul></nav>{body}</body></html>")
