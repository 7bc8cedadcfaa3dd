"""Listing and comparing the derived results stored in a session (``/entry/results/<kind>_NNN``), and the models
side by side (parameters with their units, cost, verdicts when stored).

Settings and figures are given with the unit in the key (``thickness_m``, ``rms_px``); floats are rounded to 12
significant digits (:func:`round_floats`), so that 1.3 mm typed by a user reads 0.0013, not 0.0013000000000000002.
"""

from __future__ import annotations

import json

from typing import Any

import numpy as np

from acquisition.session import Session, SessionError

__all__ = ["summarize_result", "list_results", "compare_results", "identification_parameters", "round_floats",
           "side_by_side", "stored_verdict", "unit_keys"]

#: stored setting names of older results -> the name with its unit (what newer results store)
UNIT_KEYS = {"thickness": "thickness_m"}


def round_floats(value: Any, digits: int = 12) -> Any:
    """``value`` with every float (also inside dicts, lists, tuples and numpy scalars) rounded to ``digits``
    significant digits: the noise of unit conversions (1.3 * 1e-3 = 0.0013000000000000002) removed before a value
    is stored or shown. Non-finite floats and other values pass through."""
    if isinstance(value, dict):
        return {k: round_floats(v, digits) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(round_floats(v, digits) for v in value)
    if isinstance(value, np.floating):
        value = float(value)
    if isinstance(value, float) and np.isfinite(value):
        return float(f"{value:.{digits}g}")
    return value


def unit_keys(settings: dict[str, Any]) -> dict[str, Any]:
    """Stored settings with the unit in each key (older results' ``thickness`` -> ``thickness_m``), floats
    rounded (:func:`round_floats`)."""
    return round_floats({UNIT_KEYS.get(k, k): v for k, v in settings.items()})


def parameter_units(model: str, names: list[str]) -> list[str]:
    """SI unit of each parameter of ``model`` ("Pa", "rad" or "1"); "" when the model is unknown."""
    try:
        from identification import get_model

        m = get_model(str(model))
        return [m.units[m.parameter_names.index(n)] if n in m.parameter_names else "" for n in names]
    except (ImportError, KeyError, ValueError):
        return [""] * len(names)


def identification_parameters(result: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """``{name: {"value", "stderr", "unit"}}`` of an "identification" result (SI; unit "Pa", "rad" or "1")."""
    a = result["arrays"]
    names = [str(n) for n in a.get("parameter_names", [])]
    values = np.asarray(a.get("parameters", []), float).ravel()
    stderr = np.asarray(a.get("stderr", np.full(len(values), np.nan)), float).ravel()
    if len(names) != len(values):
        names = [f"p{i}" for i in range(len(values))]
    if len(stderr) != len(values):
        stderr = np.full(len(values), np.nan)
    units = parameter_units(result["attrs"].get("model", ""), names)
    return {n: {"value": float(v), "stderr": float(s), "unit": u} for n, v, s, u in zip(names, values, stderr, units)}


def _scalar(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    return value


def stored_verdict(attrs: dict[str, Any]) -> dict[str, Any]:
    """The verdict stored with an identification result (``verdict``, ``verdict_reasons`` list,
    ``parameter_verdicts`` and ``parameter_reasons`` dicts); empty values for results stored before verdicts."""
    def load(key, empty):
        value = attrs.get(key, empty)
        if isinstance(value, bytes):
            value = value.decode()
        if isinstance(value, str):  # stored as JSON text (the contract); an older writer may have stored objects
            try:
                value = json.loads(value)
            except ValueError:
                return empty
        if isinstance(empty, list) and not isinstance(value, (dict, str)) and hasattr(value, "__iter__"):
            return [str(v) for v in value]  # a list stored as an array attribute
        return value if isinstance(value, type(empty)) else empty

    return {"verdict": str(attrs.get("verdict", "")), "verdict_reasons": load("verdict_reasons", []),
            "parameter_verdicts": load("parameter_verdicts", {}), "parameter_reasons": load("parameter_reasons", {})}


def summarize_result(result: dict[str, Any]) -> dict[str, Any]:
    """One row describing a result: name, kind, date, version, settings and the key figures of its kind."""
    attrs = result["attrs"]
    row: dict[str, Any] = {
        "name": result["name"], "kind": result["kind"], "date": str(attrs.get("date", "")),
        "version": str(attrs.get("version", "")), "settings": unit_keys(dict(result["parameters"])),
    }
    a = result["arrays"]
    kind = result["kind"]
    if kind == "identification":
        row.update(model=str(attrs.get("model", "")), wall=str(attrs.get("wall", "")),
                   cost=_scalar(attrs.get("cost")), converged=bool(attrs.get("converged", False)),
                   flags=attrs.get("flags", {}), parameters=identification_parameters(result),
                   **stored_verdict(attrs))
    elif kind == "markers" and "positions" in a:
        pos = np.asarray(a["positions"])
        visible = np.asarray(a.get("visible", np.isfinite(pos).all(axis=-1)), bool)
        row.update(n_steps=int(pos.shape[0]), n_markers=int(pos.shape[1]),
                   completeness=float(visible.mean()) if visible.size else 0.0)
    elif kind == "calibration" and "rms" in a:
        row.update(cameras=[str(c) for c in a.get("camera_names", [])],
                   rms_px=[float(v) for v in np.asarray(a["rms"], float).ravel()])
    return row


def side_by_side(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The identification summaries (:func:`summarize_result` rows) as one table: a row per result (model,
    wall), a column per parameter name (the union, in order of first appearance, each with its unit), the cost,
    convergence and the verdict when stored.

    Returns ``{"parameters": [{"name", "unit"}], "rows": [{"name", "model", "wall", "cost", "converged",
    "verdict", "values": {parameter: {"value", "stderr", "verdict"}}}]}`` (absent parameters are missing from
    ``values``; ``verdict`` None when not stored).
    """
    idents = [r for r in rows if r.get("kind") == "identification"]
    columns: dict[str, str] = {}
    for r in idents:
        for n, p in r["parameters"].items():
            columns.setdefault(n, p.get("unit", ""))
    table = []
    for r in idents:
        pv = r.get("parameter_verdicts") or {}
        table.append({"name": r["name"], "model": r["model"], "wall": r["wall"], "cost": r.get("cost"),
                      "converged": r.get("converged"), "verdict": r.get("verdict") or None,
                      "values": {n: {"value": p["value"], "stderr": p["stderr"], "verdict": pv.get(n)}
                                 for n, p in r["parameters"].items()}})
    return {"parameters": [{"name": n, "unit": u} for n, u in columns.items()], "rows": table}


def list_results(session: Session, kind: str | None = None) -> list[dict[str, Any]]:
    """Summaries of every result of the session (oldest first), optionally of one kind."""
    return [summarize_result(session.result(name)) for name in session.results(kind)]


def _diff_settings(a: dict[str, Any], b: dict[str, Any]) -> dict[str, dict[str, Any]]:
    keys = sorted(set(a) | set(b))
    return {k: {"a": a.get(k), "b": b.get(k)} for k in keys if a.get(k) != b.get(k)}


def compare_results(session: Session, name_a: str, name_b: str) -> dict[str, Any]:
    """Compare two results: settings that differ and, by kind, the differences of their outputs.

    identification: per parameter a, b, b - a, relative difference and the difference in units of
    the combined standard error; markers: RMS and max distance between the positions both measured.
    """
    known = session.results()
    for name in (name_a, name_b):
        if name not in known:
            raise SessionError(f"{session.path}: no result {name!r}; results are {known}")
    ra, rb = session.result(name_a), session.result(name_b)
    out: dict[str, Any] = {"a": summarize_result(ra), "b": summarize_result(rb),
                           "settings_diff": _diff_settings(unit_keys(ra["parameters"]), unit_keys(rb["parameters"]))}
    attr_keys = ("model", "wall", "cost", "converged", "version")
    out["attrs_diff"] = {k: {"a": _scalar(ra["attrs"].get(k)), "b": _scalar(rb["attrs"].get(k))} for k in attr_keys
                         if _scalar(ra["attrs"].get(k)) != _scalar(rb["attrs"].get(k))}
    if ra["kind"] != rb["kind"]:
        out["note"] = f"different kinds ({ra['kind']} vs {rb['kind']}): only settings are compared"
        return out
    if ra["kind"] == "identification":
        pa, pb = identification_parameters(ra), identification_parameters(rb)
        rows = {}
        for n in list(pa) + [n for n in pb if n not in pa]:
            va = pa.get(n, {}).get("value", np.nan)
            vb = pb.get(n, {}).get("value", np.nan)
            sa = pa.get(n, {}).get("stderr", np.nan)
            sb = pb.get(n, {}).get("stderr", np.nan)
            diff = vb - va
            se = float(np.hypot(sa, sb))
            unit = pa.get(n, pb.get(n, {})).get("unit", "")
            rows[n] = {"unit": unit, "a": va, "b": vb, "diff": diff, "rel_diff": diff / abs(va) if va else np.nan,
                       "diff_over_stderr": diff / se if se > 0 else np.nan}
        out["parameters"] = rows
    elif ra["kind"] == "markers":
        xa, xb = np.asarray(ra["arrays"]["positions"], float), np.asarray(rb["arrays"]["positions"], float)
        if xa.shape == xb.shape:
            d = np.linalg.norm(xb - xa, axis=-1)
            both = np.isfinite(d)
            out["positions"] = {"common_marker_steps": int(both.sum()),
                                "rms_distance_m": float(np.sqrt(np.mean(d[both] ** 2))) if both.any() else np.nan,
                                "max_distance_m": float(d[both].max()) if both.any() else np.nan}
        else:
            out["positions"] = {"note": f"shapes differ: {xa.shape} vs {xb.shape}"}
    return out
