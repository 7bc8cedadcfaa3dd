"""The report's files: figures as SVG and 300 dpi PNG with their plotted data as JSON, written into a temporary
folder beside the target and renamed into place when complete (a Ctrl-C or a crash leaves the previous report).

A folder is a *report folder* when it holds only what this module writes (``report.html``, ``figNN_*`` files): such a
folder is replaced whole by a new report; any other folder is never deleted.
"""

from __future__ import annotations

import base64
import html
import json
import logging
import math
import os
import re
import shutil
import tempfile
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

log = logging.getLogger(__name__)

__all__ = ["PNG_DPI", "ReportFiles", "is_report_dir", "staged_dir"]

#: Resolution of the PNG figures (journals ask for 300 dpi or vector; the SVG beside each PNG is the vector one).
PNG_DPI = 300
_STALE_S = 3600.0  # a staging folder untouched this long was left by a killed run
_REPORT_FILE = re.compile(r"^(report\.html|fig\d{2}_[\w.-]+\.(png|svg|json))$")


def is_report_dir(path: Path) -> bool:
    """Whether ``path`` is a folder written by an earlier report (``report.html`` and figure files only)."""
    if not path.is_dir():
        return False
    names = [p.name for p in path.iterdir()]
    return "report.html" in names and all(_REPORT_FILE.match(n) for n in names)


def _jsonable(value: Any) -> Any:
    """Arrays as lists, NaN/inf as null, floats to 6 significant digits (no float noise in the data files)."""
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, np.ndarray | list | tuple):
        return [_jsonable(v) for v in (value.tolist() if isinstance(value, np.ndarray) else value)]
    if isinstance(value, float | np.floating):
        v = float(value)
        return float(f"{v:.6g}") if math.isfinite(v) else None
    if isinstance(value, np.integer | np.bool_):
        return value.item()
    return value


@dataclass
class ReportFiles:
    """Collects the figures of one report in ``folder`` (the staging folder) and returns their HTML."""

    folder: Path
    strain_scale: str = "shared"  # colour scale of the surface maps: "shared" by all steps or "per-step"
    figures: list[Path] = field(default_factory=list)

    def figure(self, fig, name: str, caption: str, data: Mapping[str, Any] | None = None, *,
               caveat: str | None = None) -> str:
        """Save ``fig`` as ``figNN_<name>.svg`` and ``.png`` (300 dpi), ``data`` (what is plotted, SI units named in
        the keys) as ``.json``; return a ``<figure>`` with the PNG embedded, its caption and links to the files."""
        stem = f"fig{len(self.figures) + 1:02d}_{name}"
        png, svg = self.folder / f"{stem}.png", self.folder / f"{stem}.svg"
        fig.savefig(png, dpi=PNG_DPI)
        fig.savefig(svg)
        self.figures.append(png)
        files = [f'<a href="{svg.name}">SVG</a>', f'<a href="{png.name}">PNG</a>']
        if data is not None:
            (self.folder / f"{stem}.json").write_text(json.dumps(_jsonable(data), indent=1), encoding="utf-8")
            files.append(f'<a href="{stem}.json">data</a>')
        b64 = base64.b64encode(png.read_bytes()).decode("ascii")
        warn = f'<p class="caveat">{html.escape(caveat)}</p>' if caveat else ""
        return (f'<figure id="{stem}" data-name="{html.escape(name)}">{warn}'
                f'<img alt="{html.escape(caption)}" style="width:{fig.get_figwidth() * 96:.0f}px" '
                f'src="data:image/png;base64,{b64}">'
                f"<figcaption>Figure {len(self.figures)}. {html.escape(caption)} ({' · '.join(files)})"
                "</figcaption></figure>")


@contextmanager
def staged_dir(out: Path, *, replace: bool = True) -> Iterator[Path]:
    """A temporary folder beside ``out``; when the block completes it becomes ``out``.

    ``replace``: an existing ``out`` that is a report folder is replaced whole; an existing folder that is not
    (``replace`` False or foreign files) receives the new files one by one instead (its other files are kept).
    On any exception (KeyboardInterrupt included) the temporary folder is removed and ``out`` is untouched.
    """
    out = Path(out)
    _remove_stale(out)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".part", dir=out.parent))
    try:
        os.chmod(tmp, 0o777 & ~_umask())
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    try:
        if not out.exists():
            os.rename(tmp, out)
        elif replace and is_report_dir(out):
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".old", dir=out.parent))
            os.rename(out, old / out.name)
            os.rename(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            for f in sorted(tmp.iterdir()):
                os.replace(f, out / f.name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _remove_stale(out: Path) -> None:
    """Staging folders a killed earlier run left beside ``out`` (never anything else)."""
    now = time.time()
    for p in out.parent.glob(f".{_glob_escape(out.name)}.*"):
        if p.is_dir() and p.suffix in (".part", ".old") and now - p.stat().st_mtime > _STALE_S:
            log.info("removing %s, left by an interrupted report", p)
            shutil.rmtree(p, ignore_errors=True)


def _glob_escape(name: str) -> str:
    return re.sub(r"([*?\[])", r"[\1]", name)
