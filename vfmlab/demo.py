"""The zero-hardware demo: a complete simulated test, from the instruments to the parameters.

It runs the same commands an operator and a scientist run, in order, on the simulated rig:

1. ``vfmlab run --sim``: rig_sim instruments on pseudo-terminals and rendered cameras; the
   operator protocol runs unattended (calibration-board views, preconditioning, stress-free
   reference, 2 axial stretches x 8 pressure levels) into a session file;
2. ``vfmlab calibrate``: joint calibration of the camera ring from the board views;
3. ``vfmlab reconstruct``: 3-D marker reconstruction and tracking;
4. ``vfmlab identify`` for each model (Fung, Delfino, HGO by default);
5. ``vfmlab report``: the HTML report;

then prints identified against true parameters. The protocol and rig files it used are written
beside the session so the run can be repeated or varied by hand.
"""

from __future__ import annotations

import datetime as _dt
import logging
import time
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Sequence

import numpy as np
import tomli_w
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from acquisition.session import open_session
from vfmlab.display import parameter_unit
from vfmlab.stages.models import check_models, model_names

__all__ = ["DemoError", "DemoOutcome", "DemoSettings", "run_demo", "truth_table"]

log = logging.getLogger(__name__)

DEMO_MODELS = ("fung", "delfino", "hgo")


class DemoError(RuntimeError):
    """A demo stage failed; the message names the stage and the command to re-run it."""


@dataclass(frozen=True)
class DemoSettings:
    """Size of the simulated test (defaults: the full demo; tests use smaller ones)."""

    n_cameras: int = 6
    image_size: tuple[int, int] = (1224, 1024)
    n_markers: int = 300
    stretches: tuple[float, ...] = (1.1, 1.2)
    pressures_mmHg: tuple[float, ...] = (0, 20, 40, 60, 80, 100, 125, 150)
    calibration_views: int = 18
    material: str = "fung"
    clamped: bool = False
    models: tuple[str, ...] = DEMO_MODELS
    sim_speed: float = 10.0
    seed: int = 0


@dataclass
class DemoOutcome:
    session: Path
    report: Path
    results: dict[str, str] = field(default_factory=dict)  # model -> identification result name
    stage_seconds: dict[str, float] = field(default_factory=dict)
    stage_cpu_seconds: dict[str, float] = field(default_factory=dict)  # this process, all threads


def _data_file(name: str) -> dict:
    return tomllib.loads(resources.files("vfmlab.data").joinpath(name).read_text(encoding="utf-8"))


def write_demo_files(out_dir: Path, settings: DemoSettings) -> tuple[Path, Path]:
    """Write the demo's protocol and rig files (the packaged ones with ``settings`` applied)."""
    protocol = _data_file("demo-protocol.toml")
    protocol["test"]["stretches"] = list(settings.stretches)
    protocol["test"]["pressures_mmHg"] = list(settings.pressures_mmHg)
    protocol["calibration"]["views"] = settings.calibration_views
    rig = _data_file("demo-rig.toml")
    width, height = settings.image_size
    rig["camera"] = [{"name": f"cam{i}", "backend": "sim", "settings": {"width": width, "height": height}}
                     for i in range(settings.n_cameras)]
    rig["simulation"] = {"material": settings.material, "n_markers": settings.n_markers,
                         "clamped": settings.clamped, "seed": settings.seed}
    protocol_path, rig_path = out_dir / "demo-protocol.toml", out_dir / "demo-rig.toml"
    protocol_path.write_text("# Written by 'vfmlab demo'.\n" + tomli_w.dumps(protocol), encoding="utf-8")
    rig_path.write_text("# Written by 'vfmlab demo'.\n" + tomli_w.dumps(rig), encoding="utf-8")
    return protocol_path, rig_path


def _stage(console: Console, index: int, total: int, title: str, outcome: DemoOutcome, key: str, action) -> None:
    console.rule(f"[bold]{index}/{total}  {title}")
    start, cpu = time.perf_counter(), time.process_time()
    action()
    outcome.stage_seconds[key] = time.perf_counter() - start
    outcome.stage_cpu_seconds[key] = time.process_time() - cpu
    console.print(f"[dim]{title}: {outcome.stage_seconds[key]:.1f} s (CPU {outcome.stage_cpu_seconds[key]:.1f} s)[/]")


def _command(argv: list[str], stage: str) -> None:
    from vfmlab.cli import main

    rc = main(argv)
    if rc != 0:
        raise DemoError(f"{stage} failed (exit code {rc}); re-run it with: vfmlab {' '.join(argv)}")


def run_demo(out_dir: str | Path, *, console: Console, settings: DemoSettings = DemoSettings()) -> DemoOutcome:
    """Run the complete simulated test into ``out_dir``; returns where the session and report are."""
    from vfmlab.operate import OperateError, run_session

    unknown = check_models(settings.models)
    if unknown:
        raise DemoError(f"models must be among {', '.join(model_names())}; got {unknown}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    session = out_dir / f"demo-{stamp}.h5"
    report_dir = out_dir / f"demo-{stamp}_report"
    protocol_path, rig_path = write_demo_files(out_dir, settings)
    outcome = DemoOutcome(session=session, report=report_dir / "report.html")
    total = 4 + len(settings.models)
    specimen = resources.files("vfmlab.data").joinpath("demo-specimen.toml")

    def run() -> None:
        try:
            result = run_session(str(protocol_path), str(specimen), str(session), rig_path=str(rig_path), sim=True,
                                 yes=True, sim_speed=settings.sim_speed, console=console)
        except OperateError as exc:
            raise DemoError(f"the simulated session failed: {exc}") from None
        if result.status != "complete":
            raise DemoError(f"the simulated session ended {result.status}; see {session}")

    _stage(console, 1, total, "Simulated rig: operator protocol over pseudo-terminals", outcome, "run", run)
    _stage(console, 2, total, "Camera calibration from the board views", outcome, "calibrate",
           lambda: _command(["calibrate", str(session), "--fix-k3"], "calibration"))
    _stage(console, 3, total, "Marker reconstruction and tracking", outcome, "reconstruct",
           lambda: _command(["reconstruct", str(session)], "reconstruction"))
    for k, model in enumerate(settings.models):
        _stage(console, 4 + k, total, f"Identification: {model} (VFM)", outcome, f"identify {model}",
               lambda model=model: _command(["identify", str(session), "--model", model],
                                            f"identification of {model}"))
    _stage(console, total, total, "Report", outcome, "report",
           lambda: _command(["report", str(session), "-o", str(report_dir)], "report"))
    with open_session(session) as s:
        for name in s.results("identification"):
            outcome.results[str(s.result(name)["attrs"].get("model"))] = name
    return outcome


def truth_table(session: Path, material: str) -> tuple[Table, list[dict]]:
    """Identified vs true parameters of every identification in ``session``.

    The simulated specimen follows ``material`` with the seed paper's Table-1 parameters; the
    other models have no true values (their fit quality is the comparison).
    """
    from rig_sim.mechanics import PAPER_PARAMETERS

    truth = PAPER_PARAMETERS[material]
    table = Table(title=f"Identified vs true (simulated specimen: {material}, paper Table 1 values)")
    for column, justify in (("model", "left"), ("parameter", "left"), ("identified", "right"), ("± std. err.", "right"),
                            ("true", "right"), ("error", "right"), ("fit / flags", "left")):
        table.add_column(column, justify=justify)
    rows = []
    with open_session(session) as s:
        latest = {}
        for name in s.results("identification"):
            result = s.result(name)
            latest[str(result["attrs"].get("model"))] = result
        for model, result in latest.items():
            names = [str(n) for n in result["arrays"]["parameter_names"]]
            values, errors = result["arrays"]["parameters"], result["arrays"]["stderr"]
            flags = result["attrs"].get("flags") or []
            for i, pname in enumerate(names):
                true = truth.get(pname) if model == material else None
                err = None if true is None else (values[i] - true) / true
                rows.append({"model": model, "parameter": pname, "value": float(values[i]),
                             "stderr": float(errors[i]), "true": true, "relative_error": err})
                scale, unit = parameter_unit(model, pname)
                table.add_row(
                    model if i == 0 else "", f"{pname} [{unit}]" if unit else pname,
                    f"{values[i] / scale:.4g}", f"{errors[i] / scale:.2g}",
                    "—" if true is None else f"{true / scale:.4g}",
                    "—" if err is None else f"{100 * err:+.2f} %",
                    (f"cost {float(result['attrs'].get('cost', np.nan)):.3g}; {len(flags)} flag(s)" if i == 0 else ""),
                )
            table.add_section()
    return table, rows


def summarize(console: Console, outcome: DemoOutcome, settings: DemoSettings) -> None:
    """Print the truth table, the flags in words, the stage times and where the files are."""
    table, _ = truth_table(outcome.session, settings.material)
    console.print(table)
    with open_session(outcome.session) as s:
        for model, name in outcome.results.items():
            for flag in s.result(name)["attrs"].get("flags") or []:
                console.print(f"[yellow]{model}[/]: {escape(str(flag))}")
    times = ", ".join(f"{k} {v:.1f} s" for k, v in outcome.stage_seconds.items())
    console.print(f"[dim]Stage times: {times}; total {sum(outcome.stage_seconds.values()):.1f} s "
                  f"(CPU {sum(outcome.stage_cpu_seconds.values()):.1f} s)[/]")
    console.print(f"Session: [bold]{escape(str(outcome.session))}[/]")
    console.print(f"Report:  [bold]{escape(str(outcome.report))}[/]")


def parse_models(text: str) -> tuple[str, ...]:
    models = tuple(m.strip() for m in text.split(",") if m.strip())
    if not models:
        raise ValueError("--models must name at least one model")
    return models


def parse_size(text: str) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--resolution must be WIDTHxHEIGHT, e.g. 1224x1024; got {text!r}") from None
    return width, height


def parse_levels(text: str) -> Sequence[float]:
    return tuple(float(v) for v in text.split(","))
