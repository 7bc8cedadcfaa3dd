"""``vfmlab design``'s work: a protocol and a specimen (parsed files) -> what the test can identify, and what helps.

The edge between the files (``acquisition.protocol``) and the pure prediction (``identification.design``).
"""

from __future__ import annotations

from acquisition.protocol import Protocol, SpecimenFile
from identification import PAPER_TABLE1, DesignSpecimen, MeasurementNoise, get_model, suggest_steps

__all__ = ["protocol_blocks", "parse_parameters", "design_report", "design_tables"]


def protocol_blocks(protocol: Protocol) -> list[tuple[float, tuple[float, ...]]]:
    """The loaded blocks ``[(stretch, pressures [Pa]), ...]`` of a protocol (its stress-free reference left out)."""
    blocks = protocol.blocks[1:] if protocol.has_reference else protocol.blocks
    if not blocks:
        raise ValueError(f"{protocol.source}: the protocol has no loaded block to design")
    return [(float(b.stretch), tuple(float(p) for p in b.pressures)) for b in blocks]


def parse_parameters(model: str, text: str | None) -> dict[str, float]:
    """``"beta=5000,alpha11=14.5"`` (SI) over the seed paper's Table 1 values of ``model``."""
    m = get_model(model)
    values = dict(PAPER_TABLE1.get(m.name, m.initial_guess))
    for item in filter(None, (s.strip() for s in (text or "").split(","))):
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or name not in m.parameter_names:
            raise ValueError(f"--params: expected NAME=VALUE with NAME in {list(m.parameter_names)}; got {item!r}")
        try:
            values[name] = float(value)
        except ValueError:
            raise ValueError(f"--params: {name} must be a number (SI); got {value.strip()!r}") from None
    return m.check_parameters(values)


def design_report(protocol: Protocol, specimen: SpecimenFile, *, model: str = "fung", params: dict | None = None,
                  n_markers: int = 300, noise_m: float = 0.17e-3, wall: str = "membrane",
                  force_measures: str = "wall") -> dict:
    """The prediction of a test, as plain data with SI keys.

    Returns a dict: ``model``, ``parameters`` (SI), ``units``, ``reference_repeats`` (the protocol's captures of the
    reference, averaged: its markers' noise / sqrt(N)), ``half_width_95_percent`` and ``std_percent``
    per parameter, ``condition``, ``warning``, and ``suggestions``: each candidate addition with its
    half-widths, best first.
    """
    m = get_model(model)
    params = params if params is not None else parse_parameters(m.name, None)
    spec = DesignSpecimen(specimen.radius, specimen.thickness, specimen.length, wall, force_measures)
    noise = MeasurementNoise(noise_m, reference_repeats=protocol.reference_repeats)
    blocks = protocol_blocks(protocol)
    before, suggestions = suggest_steps(blocks, spec, m.name, params, n_markers, noise)
    bound = before.bound
    return {
        "model": m.name, "wall": wall, "force_measures": force_measures, "n_markers": n_markers,
        "marker_noise_m": noise_m, "reference_repeats": noise.reference_repeats,
        "load_noise_relative": noise.load_relative,
        "pressure_floor_Pa": noise.pressure_floor, "force_floor_N": noise.force_floor,
        "blocks": [{"stretch": s, "pressures_Pa": list(p)} for s, p in blocks],
        "parameters": dict(params), "units": dict(zip(m.parameter_names, m.units)),
        "std_SI": dict(bound.std), "std_percent": dict(bound.std_percent),
        "half_width_95_percent": dict(before.half_width),
        "half_width_95_SI": {p: before.half_width[p] / 100.0 * abs(v) for p, v in params.items()},
        "condition": bound.condition, "singular": bound.singular, "warning": bound.warning,
        "suggestions": [{"label": s.label, "added_blocks": [{"stretch": st, "pressures_Pa": list(p)}
                                                            for st, p in s.added_blocks],
                         "n_markers": s.n_markers, "n_added_steps": s.n_added_steps,
                         "reference_repeats": s.reference_repeats,
                         "half_width_95_percent": dict(s.half_width), "score": s.score} for s in suggestions],
    }


def _shown(value: float, unit: str) -> str:
    from vfmlab.display import quantity

    return quantity(value, unit)


def design_tables(report: dict) -> list:
    """What ``vfmlab design`` prints: a summary line, the half-width table and the candidate additions (rich
    renderables, in order)."""
    from rich.markup import escape as esc
    from rich.table import Table

    from vfmlab.display import num

    out: list = []

    names = list(report["parameters"])
    stretches = ", ".join(f"{b['stretch']:g}" for b in report["blocks"])
    steps = sum(len(b["pressures_Pa"]) for b in report["blocks"])
    out.append(f"{esc(report['model'])} ({esc(report['wall'])}): {steps} steps at stretch {stretches}, "
                  f"{report['n_markers']} markers at {num(report['marker_noise_m'] * 1e3)} mm"
                  + (f" (reference captured {report['reference_repeats']} times)"
                     if report.get("reference_repeats", 1) > 1 else "") + ", "
                  f"loads at {num(report['load_noise_relative'] * 100)} % of reading")
    table = Table(title="95 % half-width each parameter can reach (1.96 x the Cramér-Rao bound)")
    for col in ("parameter", "value", "± 95 %", "± 95 % (value units)"):
        table.add_column(col, justify="left" if col == "parameter" else "right")
    for p in names:
        unit = report["units"][p]
        table.add_row(p, _shown(report["parameters"][p], unit), f"{num(report['half_width_95_percent'][p], 3)} %",
                      _shown(report["half_width_95_SI"][p], unit))
    out.append(table)
    if report["warning"]:
        out.append(f"[bold yellow]Warning:[/] {esc(report['warning'])}")
    if not report["suggestions"]:
        return out
    best = report["suggestions"][0]
    gains = ", ".join(f"{p} ±{num(report['half_width_95_percent'][p], 2)} % → ±{num(best['half_width_95_percent'][p], 2)} %"
                      for p in names)
    out.append(f"Best addition: {esc(best['label'])}: {gains}")
    table = Table(title="Candidate additions (95 % half-width, % of value)")
    table.add_column("addition")
    table.add_column("added steps", justify="right")
    for p in names:
        table.add_column(p, justify="right")
    for s in report["suggestions"]:
        table.add_row(esc(s["label"]), str(s["n_added_steps"]), *(num(s["half_width_95_percent"][p], 3) for p in names))
    out.append(table)
    return out
