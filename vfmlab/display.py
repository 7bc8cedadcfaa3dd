"""Numbers as people read them: rounded, with their unit, never ``-0`` (shared by the CLI, live view, report).

SI inside (docs/decisions/0001-units.md); these helpers are the edge: Pa -> kPa, rad -> degrees,
m -> mm, and a fixed number of significant digits, so ``0.0013000000000000002`` prints as ``0.0013``.
"""

from __future__ import annotations

import math
from typing import Any

__all__ = ["LOG_TIME_FORMAT", "UNLIMITED_WIDTH", "num", "fixed", "display_quantity", "quantity", "settings_text",
           "printable", "side_by_side_table"]

#: ISO 8601 time stamps in every log line (never the locale's month/day order).
LOG_TIME_FORMAT = "%Y-%m-%d %H:%M:%S"
#: Width a non-terminal console renders at: wide enough that no table or line ever folds.
UNLIMITED_WIDTH = 100_000


def num(value: Any, digits: int = 4) -> str:
    """A number rounded to ``digits`` significant digits for people: no ``-0``, ``–`` for missing/NaN.

    >>> num(0.0013000000000000002), num(-0.0), num(float("nan")), num(101325.0)
    ('0.0013', '0', '–', '1.013e+05')
    """
    if value is None:
        return "–"
    try:
        value = float(value)
    except (TypeError, ValueError):
        return str(value)
    if not math.isfinite(value):
        return "–" if math.isnan(value) else ("∞" if value > 0 else "-∞")
    text = f"{value:.{digits}g}"
    return "0" if float(text) == 0 else text


def fixed(value: Any, decimals: int) -> str:
    """``value`` with ``decimals`` decimals, never ``-0.0`` (a reading of -0.04 mmHg shows as 0.0)."""
    try:
        value = float(value)
    except (TypeError, ValueError):
        return "–"
    if not math.isfinite(value):
        return "–"
    text = f"{value:.{decimals}f}"
    return text.lstrip("-") if float(text) == 0 else text


def display_quantity(value: Any, unit: str) -> tuple[float, str]:
    """An SI value as people read it: Pa -> kPa, rad -> deg, m -> mm; "1" (dimensionless) -> "".

    >>> display_quantity(6580.0, "Pa"), display_quantity(0.5, "rad")[1], display_quantity(2.0, "1")
    ((6.58, 'kPa'), 'deg', (2.0, ''))
    """
    scale, shown = {"Pa": (1e-3, "kPa"), "rad": (180.0 / math.pi, "deg"), "m": (1e3, "mm"),
                    "1": (1.0, "")}.get(unit, (1.0, unit))
    try:
        return float(value) * scale, shown
    except (TypeError, ValueError):
        return float("nan"), shown


def parameter_unit(model: str, name: str) -> tuple[float, str]:
    """(SI value per display unit, display unit) of parameter ``name`` of ``model``, from the model's own SI
    unit: ``parameter_unit("hgo", "k1")`` -> ``(1000.0, 'kPa')``; ``(1.0, '')`` for a dimensionless one."""
    from identification.models import get_model

    m = get_model(model)
    per_si, shown = display_quantity(1.0, dict(zip(m.parameter_names, m.units)).get(name, "1"))
    return 1.0 / per_si, shown


def quantity(value: Any, unit: str, digits: int = 4) -> str:
    """``quantity(6580.0, "Pa")`` -> ``'6.58 kPa'``: the value in display units with its unit."""
    shown, label = display_quantity(value, unit)
    return "–" if not math.isfinite(shown) else f"{num(shown, digits)} {label}".rstrip()


def settings_text(settings: dict, keys: tuple[str, ...] | None = None) -> str:
    """``key=value, ...`` of stored settings for people: floats rounded to 6 significant digits.

    >>> settings_text({"thickness": 0.0013000000000000002, "model": "fung", "smoothing": [4, 2]})
    'model=fung, smoothing=[4, 2], thickness=0.0013'
    """
    items = [(k, settings[k]) for k in keys if k in settings] if keys else sorted(settings.items())
    return ", ".join(f"{k}={_setting(v)}" for k, v in items)


def _setting(value: Any) -> str:
    if isinstance(value, bool) or value is None:
        return str(value).lower() if value is not None else "none"
    if isinstance(value, float):
        return num(value, 6)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_setting(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + settings_text(value) + "}"
    return str(value)


#: Characters that act on a terminal instead of printing: C0 controls but tab and newline, DEL, C1 controls
#: (0x9b is a one-byte CSI) and the bidirectional overrides that reorder what a line shows.
_UNPRINTABLE = {c: (f"\\x{c:02x}" if c < 0x100 else f"\\u{c:04x}")
                for c in [*range(0x00, 0x09), *range(0x0b, 0x20), *range(0x7f, 0xa0), *range(0x202a, 0x202f),
                          *range(0x2066, 0x206a)]}


def printable(text: str) -> str:
    """``text`` with every character that a terminal would act on written as a visible escape
    (ESC -> ``\\x1b``, CR -> ``\\x0d``): text read from files can neither clear the screen, retitle the
    window nor overwrite a line. Tabs and newlines are kept."""
    return text.translate(_UNPRINTABLE)


def side_by_side_table(table: dict[str, Any]):
    """A ``rich`` table of :func:`vfmlab.results.side_by_side`: a row per identification, a column per parameter
    (value +- standard error in display units; "?" marks a parameter judged doubtful), cost and verdict."""
    from rich.markup import escape
    from rich.table import Table

    t = Table(title="Models side by side (± standard error; ? = parameter judged doubtful)")
    for col in ("result", "model", *(f"{p['name']} ({p['unit'] or '1'})" for p in table["parameters"]), "cost",
                "verdict"):
        t.add_column(escape(col), justify="left" if col in ("result", "model", "verdict") else "right")
    for r in table["rows"]:
        cells = []
        for p in table["parameters"]:
            v = r["values"].get(p["name"])
            cells.append("" if v is None else f"{quantity(v['value'], p['unit'])} ± "
                         f"{quantity(v['stderr'], p['unit'], 2)}" + (" ?" if v["verdict"] == "doubtful" else ""))
        verdict = escape(r["verdict"] or "–")
        t.add_row(escape(r["name"]), escape(f"{r['model']} ({r['wall']})"), *[escape(c) for c in cells],
                  num(r["cost"], 3) + ("" if r["converged"] else " [red](not converged)[/]"),
                  f"[yellow]{verdict}[/]" if r["verdict"] == "doubtful" else verdict)
    return t
