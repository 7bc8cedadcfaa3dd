"""Operating a session from the command line: ``vfmlab run`` and ``vfmlab resume`` share this.

Loads and validates the files (before anything moves), assembles the rig (real or ``--sim``),
creates or reopens the session file, runs :class:`acquisition.runner.SessionRunner` under the
live view with Ctrl-C mapped to a pause, and reports the outcome.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import signal
import threading
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Callable

import numpy as np
from rich.console import Console
from rich.markup import escape as esc

from acquisition.cameras import CameraError
from acquisition.errors import ImplausibleInputError
from acquisition.protocol import (MMHG, ConfigError, Protocol, RigConfig, SpecimenFile, load_protocol, load_rig,
                                  load_specimen, parse_protocol, parse_rig)
from acquisition.runner import AutoOperator, RunnerState, SessionRunner, completed_steps
from acquisition.session import (CameraSpec, SessionError, SessionWriter, SpecimenInfo, incomplete_leftover,
                                open_session)
from vfmlab.bench import Bench, BenchError, open_bench
from vfmlab.display import fixed
from vfmlab.live import LiveView, TerminalOperator, format_duration
from vfmlab.preflight import keep_check, preflight

__all__ = ["OperateError", "Outcome", "run_session", "resume_session", "DEFAULT_SIM_RIG"]

log = logging.getLogger(__name__)

#: The simulated rig used by ``--sim`` when no ``--rig`` file is given (packaged copy of
#: examples/sim-rig.toml; tests/test_run_protocol.py checks they are the same file).
DEFAULT_SIM_RIG = resources.files("vfmlab.data").joinpath("sim-rig.toml").read_text(encoding="utf-8")


class OperateError(RuntimeError):
    """A user-facing failure (bad file, missing instrument, identity mismatch); exit code 1,
    or 2 (``exit_code``) for bad input the user must change."""

    def __init__(self, message: str, exit_code: int = 1):
        super().__init__(message)
        self.exit_code = exit_code


@dataclass
class Outcome:
    status: str  # complete | aborted | interrupted
    path: Path
    n_steps: int
    elapsed_s: float
    reason: str = ""  # why an aborted or failed run stopped ('' for complete or an operator's quit)
    resumable: bool = False
    ctrl_c: bool = False  # an unattended run (--yes) stopped by Ctrl-C: exit code 130 (decision 0007)

    @property
    def failed(self) -> bool:
        """Exit code 1: aborted, or stopped by a fault (disk full) although resumable."""
        return self.status == "aborted" or bool(self.reason)

    @property
    def exit_code(self) -> int:
        """0 complete (or an operator's quit), 1 failed, 130 an unattended run interrupted by Ctrl-C."""
        return 1 if self.failed else 130 if self.ctrl_c and self.status == "interrupted" else 0


def _sim_bench(rig: RigConfig, specimen: SpecimenFile, protocol: Protocol, sim_speed: float):
    from vfmlab.simrig import SimBench

    return SimBench(rig, specimen, protocol, time_scale=sim_speed)


def load_rig_config(rig_path: str | None, sim: bool, sim_seed: int | None = None) -> RigConfig:
    """The rig file (or with ``sim`` and no file the built-in simulated rig), ``sim_seed`` written in."""
    if rig_path:
        rig = load_rig(rig_path)
    elif sim:
        rig = parse_rig(DEFAULT_SIM_RIG, text=DEFAULT_SIM_RIG, source="<built-in simulated rig>")
    else:
        raise OperateError("no rig: give --rig RIG.toml (ports, cameras, limits) or --sim")
    if rig.simulated and not sim:
        raise OperateError(f"{rig.source} describes the simulated rig (port = \"sim\"); add --sim")
    if sim_seed is not None:
        rig = _with_sim_seed(rig, sim_seed)
    return rig


def _with_sim_seed(rig: RigConfig, seed: int) -> RigConfig:
    """``rig`` with ``[simulation] seed = seed`` written into its text too, so that the session records the
    seed it ran with and ``vfmlab resume`` re-creates the same simulated rig."""
    import tomllib

    import tomli_w

    data = tomllib.loads(rig.text) if rig.text else {}
    data.setdefault("simulation", {})["seed"] = int(seed)
    text = f"# {rig.source} with [simulation] seed = {int(seed)} (vfmlab run --sim-seed)\n" + tomli_w.dumps(data)
    return parse_rig(text, text=text, source=rig.source)


def _check_resources(protocol: Protocol, specs: list[CameraSpec], out: Path, console: Console) -> None:
    """Refuse (exit 2) a recording beyond the free disk or the memory, with the estimate; say how long it takes."""
    import shutil

    from acquisition.plausibility import check_session_resources

    frames = [(s.width, s.height, np.dtype(s.dtype).itemsize) for s in specs]
    memory = float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")) if hasattr(os, "sysconf") else math.inf
    try:
        check_session_resources(frames, protocol.n_steps + protocol.calibration.views, source=protocol.source,
                                free_disk=float(shutil.disk_usage(out.resolve().parent).free), memory=memory)
    except ImplausibleInputError as exc:
        raise OperateError(str(exc), exit_code=2) from None
    hours = protocol.min_duration_s(len(specs)) / 3600
    if hours >= 1:
        console.print(f"[yellow]This protocol takes at least {hours:.3g} h[/] (dwell and capture alone).")


def _camera_specs(bench: Bench) -> list[CameraSpec]:
    """Grab one frame per camera (they must all work before anything moves) -> CameraSpec."""
    specs = []
    for cam in bench.cameras:
        try:
            frame = cam.grab(5.0)
        except CameraError as exc:
            raise OperateError(f"camera check failed: {exc}") from exc
        h, w = frame.pixels.shape
        specs.append(CameraSpec(cam.name, cam.identity or cam.backend, w, h, str(frame.pixels.dtype)))
    return specs


@contextlib.contextmanager
def _sigint_pauses(runner: SessionRunner, console: Console, pending: dict[str, int]):
    """Ctrl-C -> pause at the next safe point; a second Ctrl-C before it is handled -> hard stop.
    ``pending["n"]`` counts the Ctrl-Cs."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        pending["n"] += 1
        if runner._pause_requested and pending["n"] > 1:
            raise KeyboardInterrupt
        console.print("[yellow]Ctrl-C: pausing at the next safe point (Ctrl-C again to stop at once)[/]")
        runner.request_pause()

    old = signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


def _execute(runner_kwargs: dict[str, Any], protocol: Protocol, writer: SessionWriter, bench: Bench,
             console: Console, yes: bool, start_step: int, precondition: bool, calibrate: bool,
             detector: Callable[[np.ndarray], int] | None,
             observer: Callable[[RunnerState, Bench], None] | None = None,
             results: Any = None) -> tuple[SessionRunner, bool]:
    """Run the protocol; the runner and whether an unattended run (``yes``) was stopped by Ctrl-C."""
    live = console.is_terminal
    view = (LiveView(console, title=f"vfmlab run · {esc(writer.path.name)}",
                     results=results.status if results else None) if live else None)
    if yes:
        operator = AutoOperator(set_pressure=bench.operator_pressure, set_stretch=bench.stage,
                                place_board=bench.place_board, remove_board=bench.remove_board)
    else:
        operator = TerminalOperator(console, view, hand_pressure=bench.operator_pressure, hand_stretch=bench.stage,
                                    hand_board=bench.place_board, hand_unboard=bench.remove_board)
    last = {"steps": start_step}

    def on_update(state: RunnerState) -> None:
        if observer is not None:
            observer(state, bench)
        if view is not None:
            view.update(state)
        elif state.steps_done != last["steps"]:
            last["steps"] = state.steps_done
            console.print(f"step {state.steps_done}/{state.n_steps}: block {state.block + 1}, "
                          f"L/L0 {state.stretch:.3f}, {fixed(state.pressure / MMHG, 1)} mmHg, "
                          f"{fixed(state.force, 4)} N, "
                          f"remaining ~{format_duration(state.remaining_s)}")

    runner = SessionRunner(protocol, writer, pressure=bench.pressure, sampler=bench.sampler, cameras=bench.cameras,
                           operator=operator, pressure_mode=bench.config.pressure.mode, stage=bench.stage,
                           safety=bench.config.safety, detector=detector, on_update=on_update,
                           on_step_captured=results.on_step if results is not None else None, **runner_kwargs)
    pending = {"n": 0}
    with _sigint_pauses(runner, console, pending), (view if view is not None else contextlib.nullcontext()):
        runner.run(start_step=start_step, precondition=precondition, calibrate=calibrate)
    runner.state.message = runner.status
    return runner, yes and pending["n"] > 0


def specimen_ends(rig, specimen, sim: bool, console: Console | None = None) -> tuple[str, str]:
    """How the specimen is held, and who says so: ``(ends, source)`` for the session record.

    The simulated specimen's ``[simulation] clamped`` decides on ``--sim`` (it is what the
    simulator does); otherwise the specimen file's ``ends``, else the rig file's ``[rig] ends``,
    else ``("", "")`` (unknown: identification then assumes clamped and says so).
    """
    said = [(specimen.ends, "specimen file"), (getattr(rig, "ends", ""), "rig file")]
    if sim:
        ends = "clamped" if rig.simulation.clamped else "free"
        source = f"simulated specimen, rig file simulation.clamped = {str(rig.simulation.clamped).lower()}"
        for value, where in said:
            if value and value != ends and console is not None:
                console.print(f"[yellow]warning:[/] the {where} says ends = {value!r} but the simulated specimen is "
                              f"{ends}; the session records {ends!r}")
        return ends, source
    for value, where in said:
        if value:
            return value, where
    return "", ""


def run_session(protocol_path: str, specimen_path: str, out: str, *, rig_path: str | None = None,
                sim: bool = False, yes: bool = False, sim_speed: float = 1.0, console: Console,
                detector: Callable[[np.ndarray], int] | None = None, sim_seed: int | None = None,
                observer: Callable[[RunnerState, Bench], None] | None = None, live_models: tuple[str, ...] = (),
                live_options: dict[str, Any] | None = None, check_seconds: float = 0.0,
                on_live_results: Callable[[Any], None] | None = None,
                **runner_kwargs: Any) -> Outcome:
    """``vfmlab run``: validate, assemble the rig, create the session file and run the protocol.

    ``observer(state, bench)`` is called at every runner update (tests inject faults with it).
    ``sim_seed``: with ``sim``, replaces the rig file's ``[simulation] seed`` (marker layout, camera-ring
    imperfections, image and instrument noise of the simulated rig); None keeps the file's.
    ``live_models``: models identified while the test runs (:mod:`vfmlab.live_results`; keyword
    arguments of :class:`~vfmlab.live_results.LiveResults` in ``live_options``); their final
    estimates are stored as "identification" results. ``check_seconds`` > 0: the pre-flight check
    (:mod:`vfmlab.preflight`) with that many seconds of readings, kept in the session.
    ``on_live_results(results)`` is called with the :class:`~vfmlab.live_results.LiveResults` once they start
    (the browser view, :mod:`vfmlab.web`).
    """
    try:
        rig = load_rig_config(rig_path, sim, sim_seed if sim else None)
        protocol = load_protocol(protocol_path, rig)
        specimen = load_specimen(specimen_path)
    except ConfigError as exc:
        raise OperateError(str(exc), exit_code=2) from None
    out_path = Path(out)
    replace_leftover = incomplete_leftover(out_path)
    if replace_leftover:
        console.print(f"{esc(str(out_path))}: replacing an incomplete file ({out_path.stat().st_size} bytes, no "
                      "data) left by a run killed while it created it")
    elif out_path.exists():
        raise OperateError(f"{out_path}: file exists; refusing to overwrite a session (choose another --out, "
                           f"or 'vfmlab resume {out_path}' to continue it)")
    pc = protocol.preconditioning
    test_blocks = protocol.blocks[int(protocol.has_reference):]
    console.print(f"[bold]{esc(protocol.name)}[/]: {protocol.n_steps} steps: "
                  + ("stress-free reference, then " if protocol.has_reference else "")
                  + f"{len(test_blocks)} block(s) at L/L0 {', '.join(f'{b.stretch:g}' for b in test_blocks)}; "
                  f"{protocol.calibration.views} calibration views; preconditioning "
                  f"{pc.pressure_cycles} x 0-{pc.pressure_max / MMHG:.0f} mmHg, {pc.stretch_cycles} x L/L0 "
                  f"1-{pc.stretch_max:g}; specimen {esc(specimen.specimen_id)}; rig {esc(rig.name)}")
    with contextlib.ExitStack() as stack:
        simbench = stack.enter_context(_sim_bench(rig, specimen, protocol, sim_speed)) if sim else None
        try:
            bench = stack.enter_context(open_bench(rig, simbench))
        except (BenchError, CameraError) as exc:
            raise OperateError(str(exc)) from None
        specs = _camera_specs(bench)
        names = protocol.camera_names(rig)
        specs = [s for s in specs if s.name in names]
        bench.cameras = [c for c in bench.cameras if c.name in names]
        _check_resources(protocol, specs, out_path, console)
        _stage_for_run(bench, specimen, protocol, console, yes, home=False)
        check = preflight(bench, rig, console, yes, check_seconds)
        if not yes and not TerminalOperator(console).choose("Start the test? Nothing has moved yet.",
                                                           ["start", "cancel"]) == "start":
            raise OperateError("cancelled by the operator before the start; no file written")
        _stage_for_run(bench, specimen, protocol, console, yes, home=True)
        try:
            ends, ends_source = specimen_ends(rig, specimen, sim, console)
            writer = SessionWriter.create(
                out_path, SpecimenInfo(specimen.specimen_id, specimen.radius, specimen.length, specimen.thickness,
                                       specimen.notes, ends, ends_source),
                cameras=specs, protocol_text=protocol.text, rig=bench.rig_record(), instruments=bench.instruments(),
                load_cell_measures=rig.load_cell.measures, overwrite=replace_leftover)
        except (SessionError, OSError) as exc:
            raise OperateError(str(exc)) from None
        for line in check.lines() if check is not None else []:
            writer.add_event("check", line)
        results = _live_results(out_path, specimen, rig, live_models, live_options, protocol, console)
        if results is not None and on_live_results is not None:
            on_live_results(results)
        try:
            runner, ctrl_c = _execute(runner_kwargs, protocol, writer, bench, console, yes, 0, True, True, detector,
                                      observer, results)
        except BaseException:
            if results is not None:
                results.close(cancel=True)
            raise
    outcome = _report(runner, out_path, console, ctrl_c)
    if check is not None:
        keep_check(check, out_path, console)
    if results is not None:
        _finish_live_results(results, out_path, console, cancel=outcome.status != "complete")
    return outcome


def _live_results(path: Path, specimen: SpecimenFile, rig: RigConfig, models: tuple[str, ...],
                  options: dict[str, Any] | None, protocol=None, console: Console | None = None):
    """The background reconstruction + identification of the steps, or None (no models, or no
    calibration to reconstruct with: no cameras given and no board views in the protocol)."""
    if not models:
        return None
    if protocol is not None and protocol.calibration.views == 0 and not (options or {}).get("cameras") \
            and not (options or {}).get("calibrate"):
        if console is not None:
            console.print("[dim]live results off: the protocol captures no calibration-board views to reconstruct "
                          "with ([calibration] views)[/]")
        return None
    from vfmlab.live_results import LiveResults

    kwargs = dict(thickness=specimen.thickness, radius=specimen.radius, models=tuple(models),
                  load_cell_measures=rig.load_cell.measures, ends=getattr(specimen, "ends", "") or None)
    if protocol is not None:  # what the protocol can reach, beside the live estimates (vfmlab design's prediction)
        from vfmlab.stages.reachable import protocol_reachable

        kwargs["reachable"] = protocol_reachable(protocol, specimen, models, force_measures=rig.load_cell.measures)
    kwargs.update(options or {})
    return LiveResults(path, **kwargs)


def _finish_live_results(results, path: Path, console: Console, cancel: bool = False) -> None:
    """Wait for the last steps' results, print and store them; a failure here is only reported.
    ``cancel``: the run ended early (quit, abort): do not wait for the steps still queued."""
    from vfmlab.live import render_live_results

    try:
        status = results.close(cancel=cancel)
        console.print(render_live_results(status))
        if status.estimates:
            names = results.store(path)
            console.print(f"live results stored as {', '.join(names)} in {path}")
    except Exception as exc:  # noqa: BLE001 - the test itself is complete and saved
        log.warning("live results could not be finished: %s", exc, exc_info=True)
        console.print(f"[yellow]live results could not be stored: {exc}[/]")


def resume_session(path: str, *, rig_path: str | None = None, sim: bool = False, yes: bool = False,
                   sim_speed: float = 1.0, console: Console, detector: Callable[[np.ndarray], int] | None = None,
                   observer: Callable[[RunnerState, Bench], None] | None = None, **runner_kwargs: Any) -> Outcome:
    """``vfmlab resume``: continue an interrupted session from its last completed step."""
    if incomplete_leftover(path):
        raise OperateError(f"{path}: holds no data ({Path(path).stat().st_size} bytes): a run was killed while it "
                           f"created the file; start the test again with 'vfmlab run ... --out {path}'")
    try:
        with open_session(path) as s:
            status = s.status
            protocol_text, rig_settings = s.protocol_text, s.rig_settings
            info = s.specimen
            stored = s.instruments
            camera_names = s.camera_names
            start = completed_steps(s.steps)
            kinds = [e["kind"] for e in s.events()]
    except SessionError as exc:
        raise OperateError(str(exc)) from None
    if status != "interrupted":
        raise OperateError(f"{path}: session status is {status!r}; only an interrupted session can be resumed")
    try:
        if rig_path:
            rig = load_rig(rig_path)
        else:
            text = rig_settings.get("config_text", "")
            if not text:
                raise OperateError(f"{path}: the session does not hold its rig file; give --rig RIG.toml")
            rig = parse_rig(text, text=text, source=f"{Path(path).name}:rig")
            _confirm_stored_devices(rig, path, yes, console)
        sim = sim or rig.simulated  # the session knows it was recorded on the simulated rig
        protocol = parse_protocol(protocol_text, text=protocol_text, source=f"{Path(path).name}:protocol", rig=rig)
    except ConfigError as exc:
        raise OperateError(str(exc), exit_code=2) from None
    specimen = SpecimenFile(info.specimen_id, info.radius, info.length, info.thickness, info.notes)
    done_pre = "preconditioning_done" in kinds or start > 0
    done_cal = "calibration_done" in kinds or "preconditioning" in kinds or start > 0
    console.print(f"Resuming {esc(str(path))}: {start}/{protocol.n_steps} steps done"
                  + ("" if done_pre else "; preconditioning will be redone"))
    if start >= protocol.n_steps:
        console.print("every step is already captured; closing the session as complete")
    with contextlib.ExitStack() as stack:
        simbench = stack.enter_context(_sim_bench(rig, specimen, protocol, sim_speed)) if sim else None
        try:
            bench = stack.enter_context(open_bench(rig, simbench))
        except (BenchError, CameraError) as exc:
            raise OperateError(str(exc)) from None
        for role, driver in (("pressure", bench.pressure), ("load_cell", bench.load_cell)):
            was = stored.get(role, {}).get("identity", "")
            if was and was != driver.identity:
                raise OperateError(f"{role}: the session was recorded with {was!r} but the port now answers "
                                   f"{driver.identity!r}; connect the same instrument (or start a new session)")
        bench.cameras = [c for c in bench.cameras if c.name in camera_names]
        missing = sorted(set(camera_names) - {c.name for c in bench.cameras})
        if missing:
            raise OperateError(f"cameras {missing} of the session are not in the rig file")
        _camera_specs(bench)
        _stage_for_run(bench, specimen, protocol, console, yes, home=False)
        _stage_for_run(bench, specimen, protocol, console, yes, home=True)
        try:
            writer = SessionWriter.resume(path)
        except SessionError as exc:
            raise OperateError(str(exc)) from None
        writer.add_event("resume", f"resuming at step {start}/{protocol.n_steps}; instruments "
                                   f"{bench.pressure.identity!r}, {bench.load_cell.identity!r}")
        runner, ctrl_c = _execute(runner_kwargs, protocol, writer, bench, console, yes, start, not done_pre,
                                  not done_cal, detector, observer)
    return _report(runner, Path(path), console, ctrl_c)


def device_endpoints(rig: RigConfig) -> list[str]:
    """The real devices a rig file would open: serial ports and camera sources (simulated ones excluded)."""
    out = [f"{role} port {port.port}" for role, port in (("pressure", rig.pressure), ("load cell", rig.load_cell))
           if port.port != "sim"]
    for cam in rig.cameras:
        if cam.backend != "sim":
            source = ", ".join(f"{k}={v}" for k, v in sorted(cam.settings.items())
                               if k in ("device", "index", "url", "path", "serial", "source"))
            out.append(f"camera {cam.name} ({cam.backend}{': ' + source if source else ''})")
    return out


def _confirm_stored_devices(rig: RigConfig, path: str, yes: bool, console: Console) -> None:
    """A session file is data from anywhere: never let it pick serial ports or video sources unasked."""
    devices = device_endpoints(rig)
    if not devices:
        return
    listing = "; ".join(devices)
    if yes:
        raise OperateError(f"{path}: the rig settings stored in the session would open {listing}. A session file "
                           "is not trusted to choose devices: resume with --rig RIG.toml (this machine's rig file)",
                           exit_code=2)
    console.print(f"The rig settings stored in {esc(str(path))} would open: {esc(listing)}. "
                  "They come from the session file, not from a rig file of this machine.")
    if TerminalOperator(console).choose("Use these devices?", ["no", "yes"]) != "yes":
        raise OperateError("resume cancelled: give --rig RIG.toml (this machine's rig file)", exit_code=2)


def _stage_for_run(bench: Bench, specimen: SpecimenFile, protocol: Protocol, console: Console, yes: bool,
                   home: bool) -> None:
    """:func:`vfmlab.axial.prepare_stage`, its errors as OperateError."""
    from vfmlab.axial import StageSetupError, prepare_stage

    try:
        prepare_stage(bench, specimen, protocol, TerminalOperator(console).choose, yes=yes, home=home,
                      say=console.print)
    except StageSetupError as exc:
        raise OperateError(str(exc), exit_code=exc.exit_code) from None


def _report(runner: SessionRunner, path: Path, console: Console, ctrl_c: bool = False) -> Outcome:
    with open_session(path) as s:
        n = s.n_steps
    status = runner.status
    style = {"complete": "green", "aborted": "red", "interrupted": "yellow"}[status]
    console.print(f"[bold {style}]Session {status}[/]: {esc(str(path))} ({n} step rows, "
                  f"{format_duration(runner.state.elapsed_s)})")
    if runner.stop_reason:
        console.print(f"Reason: {esc(runner.stop_reason)}")
    if status == "interrupted" or runner.resumable:
        console.print(f"Continue with: vfmlab resume {esc(str(path))}")
    return Outcome(status, path, n, runner.state.elapsed_s, runner.stop_reason,
                   status == "interrupted" or runner.resumable, ctrl_c)


def detector_from_reconstruction() -> Callable[[np.ndarray], int] | None:
    """Marker counter for the live view (reconstruction's detector), or None if unavailable."""
    try:
        from reconstruction import detect_markers
    except ImportError:
        return None

    def count(image: np.ndarray) -> int:
        try:
            return len(detect_markers(image))
        except Exception:  # noqa: BLE001 - the live view must not stop a test
            return -1

    return count


def as_json(outcome: Outcome) -> str:
    return json.dumps({"status": outcome.status, "path": str(outcome.path), "n_steps": outcome.n_steps,
                       "elapsed_s": outcome.elapsed_s})
