"""The operator's live terminal view (rich) and the terminal operator (prompts).

:func:`render_state` turns a :class:`acquisition.runner.RunnerState` into a rich renderable:
pressure (mmHg and kPa) and force (N), the current block/step and its stability, a progress
bar for the whole protocol with the time remaining, markers detected per camera at the last
capture, and warnings. :class:`LiveView` keeps it on screen (``rich.live.Live``) while the
runner works; :class:`TerminalOperator` asks the operator (pausing the live display).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Sequence

import click
from rich.console import Console, Group
from rich.live import Live
from rich.markup import escape
from rich.panel import Panel
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn
from rich.table import Table
from rich.text import Text

from acquisition.protocol import MMHG
from acquisition.runner import RunnerState

__all__ = ["render_state", "LiveView", "TerminalOperator", "format_duration"]

_PHASE_STYLE = {"paused": "bold yellow", "done": "bold green", "capturing": "bold cyan", "stabilising": "cyan",
                "preconditioning": "magenta", "setting": "blue", "calibrating": "magenta"}


def format_duration(seconds: float) -> str:
    """``125.3`` -> ``'2:05'``; NaN -> ``'--:--'``."""
    if seconds is None or not math.isfinite(seconds):
        return "--:--"
    s = int(round(seconds))
    h, rem = divmod(s, 3600)
    m, s = divmod(rem, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


def _num(value: float, fmt: str) -> str:
    if value is None or not math.isfinite(value):
        return "—"
    text = format(value, fmt)
    return text.replace("-", " ", 1) if float(text) == 0 else text  # never "-0.00"


def _reachable_cell(reach, name: str) -> str:
    """The 95 % half-width (% of value) the protocol can reach for one parameter, or "n/a"."""
    if reach is None or not reach.available or name not in reach.half_width:
        return "n/a"
    from vfmlab.display import num

    return f"{num(reach.half_width[name], 3)} %"


def render_live_results(status) -> Group:
    """The "results while the test runs" panel: the latest parameters of each model with their
    standard errors (kPa, degrees or dimensionless), steps reconstructed, markers tracked."""
    from vfmlab.display import num, parameter_unit

    head = Text(f"{status.steps_reconstructed} steps reconstructed · {status.tracked} markers tracked · "
                f"{status.message}", style="dim")
    parts = [head]
    if status.estimates:
        table = Table(box=None, padding=(0, 2), show_edge=False)
        for column, justify in (("model", "left"), ("parameter", "left"), ("value", "right"), ("± std. err.", "right"),
                                ("± 95 %", "right"), ("reachable", "right"), ("steps", "right"), ("verdict", "left")):
            table.add_column(column, justify=justify)
        reach = getattr(status, "reachable", None) or {}
        for model, est in status.estimates.items():
            can = reach.get(model)
            for i, name in enumerate(est.names):
                scale, unit = parameter_unit(model, name)
                got = 196.0 * est.stderr[i] / abs(est.values[i]) if est.values[i] else float("nan")
                table.add_row(model if i == 0 else "", escape(f"{name} [{unit}]") if unit else name,
                              f"{est.values[i] / scale:.4g}", f"{est.stderr[i] / scale:.2g}", f"{num(got, 3)} %",
                              _reachable_cell(can, name), str(len(est.rows)) if i == 0 else "",
                              (getattr(est.result, "parameter_verdicts", None) or {}).get(name, ""))
        parts.append(table)
        notes = {r.describe() for r in reach.values()} if reach else set()
        for note in sorted(notes):
            parts.append(Text(note + " (design's prediction before the test: 'vfmlab design')", style="dim"))
    left_out = [f"rows {list(status.skipped_rows)} failed (not in the estimates)" if status.skipped_rows else "",
                f"rows {list(status.partial_rows)} seen only in part" if status.partial_rows else ""]
    if any(left_out):
        parts.append(Text("⚠ steps: " + "; ".join(t for t in left_out if t), style="yellow"))
    if status.error:
        parts.append(Text("⚠ live results: " + status.error, style="yellow"))
    return Group(*parts)


def render_state(state: RunnerState, title: str = "vfmlab run", results=None):
    """A rich renderable of the runner's state (see module docstring); ``results`` (a
    :class:`vfmlab.live_results.LiveStatus`) adds the parameters identified so far."""
    readings = Table.grid(padding=(0, 2))
    readings.add_column(justify="right", style="bold")
    readings.add_column()
    readings.add_row("Pressure", f"{_num(state.pressure / MMHG, '7.2f')} mmHg   {_num(state.pressure / 1e3, '7.3f')} kPa")
    readings.add_row("Force", f"{_num(state.force, '8.4f')} N")
    target = (f"{_num(state.target / MMHG, '.1f')} mmHg" if math.isfinite(state.target) else "—")
    step_txt = (f"block {state.block + 1}  ·  L/L0 = {_num(state.stretch, '.3f')}  ·  target {target}"
                if state.block >= 0 else "—")
    readings.add_row("Step", f"{min(state.step + 1, state.n_steps)} / {state.n_steps}   {step_txt}")
    stable = Text("stable", style="bold green") if state.stable else Text("settling", style="yellow")
    readings.add_row("Stability", stable)
    phase = Text(state.phase, style=_PHASE_STYLE.get(state.phase, ""))
    if state.message:
        phase.append(f"  {state.message}", style="")
    readings.add_row("Phase", phase)
    if state.markers:
        readings.add_row("Markers", Text("   ".join(f"{name}: {n}" for name, n in state.markers.items())))

    progress = Progress(TextColumn("Protocol"), BarColumn(bar_width=None), MofNCompleteColumn(),
                        TextColumn("elapsed {task.fields[elapsed]}  ·  remaining ~{task.fields[remaining]}"),
                        expand=True)
    progress.add_task("protocol", total=max(state.n_steps, 1), completed=state.steps_done,
                      elapsed=format_duration(state.elapsed_s), remaining=format_duration(state.remaining_s))
    parts = [readings, progress]
    if state.warnings:
        warn = Text()
        for w in state.warnings[-3:]:
            warn.append("⚠ " + w + "\n", style="yellow")
        parts.append(warn)
    if results is not None:
        parts.append(Panel(render_live_results(results), title="Results while the test runs", border_style="green"))
    border = "yellow" if state.phase == "paused" else "blue"
    return Panel(Group(*parts), title=title, border_style=border, subtitle="Ctrl-C: pause")


class LiveView:
    """Keeps :func:`render_state` on screen; ``update`` is the runner's ``on_update`` callback.

    Updates are rate-limited to ``max_fps``; :meth:`suspend` hides the view for a prompt.
    """

    def __init__(self, console: Console, title: str = "vfmlab run", max_fps: float = 8.0, results=None):
        self.console, self.title = console, title
        self.results = results  # callable () -> LiveStatus, or None
        self._min_dt = 1.0 / max_fps
        self._last = 0.0
        self.state = RunnerState()
        self._live = Live(render_state(self.state, title), console=console, refresh_per_second=max_fps,
                          transient=False, auto_refresh=False)
        self._lock = threading.Lock()
        self._active = False

    def __enter__(self) -> LiveView:
        self._live.start()
        self._active = True
        return self

    def __exit__(self, *exc: object) -> None:
        self._live.update(self._render(self.state), refresh=False)
        self._live.stop()
        self._active = False

    def update(self, state: RunnerState) -> None:
        self.state = state
        now = time.monotonic()
        if not self._active or (now - self._last < self._min_dt and state.phase not in ("paused", "done")):
            return
        self._last = now
        with self._lock:
            self._live.update(self._render(state), refresh=True)

    def _render(self, state: RunnerState):
        return render_state(state, self.title, self.results() if self.results is not None else None)

    def suspend(self):
        """Context manager: stop the live display while prompting the operator."""
        view = self

        class _Suspend:
            def __enter__(self_inner):
                if view._active:
                    view._live.stop()

            def __exit__(self_inner, *exc):
                if view._active:
                    view._live.start()

        return _Suspend()


class TerminalOperator:
    """Asks the operator at the terminal (click prompts), with the live view suspended.

    ``hand_pressure`` / ``hand_stretch``: optional callables run after the operator confirms
    (the simulated rig's valve and stage, so ``--sim`` without ``--yes`` behaves like the rig).
    """

    def __init__(self, console: Console, view: LiveView | None = None, hand_pressure=None, hand_stretch=None,
                 hand_board=None, hand_unboard=None):
        self.console, self.view = console, view
        self.hand_pressure, self.hand_stretch = hand_pressure, hand_stretch
        self.hand_board, self.hand_unboard = hand_board, hand_unboard

    def _suspended(self):
        return self.view.suspend() if self.view is not None else _Null()

    def set_pressure(self, target: float) -> None:
        with self._suspended():
            click.prompt(f"Set the pressure to {target / MMHG:.1f} mmHg ({target / 1e3:.2f} kPa), then press Enter",
                         default="", show_default=False)
        if self.hand_pressure is not None:
            self.hand_pressure(target)

    def set_stretch(self, stretch: float) -> None:
        with self._suspended():
            click.prompt(f"Set the axial stretch to L/L0 = {stretch:.3f}, then press Enter", default="",
                         show_default=False)
        if self.hand_stretch is not None:
            self.hand_stretch(stretch)

    def precondition(self, message: str) -> None:
        with self._suspended():
            click.prompt(f"{message} (press Enter when done)", default="", show_default=False)

    def place_board(self, index: int, n_views: int) -> None:
        with self._suspended():
            click.prompt(f"Calibration: place the board in pose {index + 1}/{n_views} (vary position and tilt; "
                         "seen by at least two cameras), then press Enter", default="", show_default=False)
        if self.hand_board is not None:
            self.hand_board(index, n_views)

    def remove_board(self) -> None:
        with self._suspended():
            click.prompt("Calibration done: remove the board, then press Enter", default="", show_default=False)
        if self.hand_unboard is not None:
            self.hand_unboard()

    def choose(self, reason: str, options: Sequence[str]) -> str:
        with self._suspended():
            self.console.print(reason, style="bold yellow", markup=False)
            return click.prompt("Choose", type=click.Choice(list(options)), default=options[0])

    def notify(self, message: str) -> None:
        self.console.log(message, markup=False)

    def ask_text(self, prompt: str) -> str:
        with self._suspended():
            return click.prompt(prompt, default="", show_default=False)


class _Null:
    def __enter__(self):
        return None

    def __exit__(self, *exc):
        return None
