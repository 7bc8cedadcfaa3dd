"""The run and reprocess stages: a test protocol on the rig into a new session (:mod:`vfmlab.operate`), and
stages re-run on stored sessions with new settings (:mod:`vfmlab.reprocess`), in parallel if asked."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Sequence
from typing import Any

from vfmlab.stages.errors import StageError, StageFailed
from vfmlab.stages.feedback import ProgressFactory, no_progress
from vfmlab.stages.settings import ReprocessSettings, RunSettings, settings_with

__all__ = ["check_sim_seed", "parse_set", "plan", "reprocess", "run", "split_list"]


def split_list(value: str | Sequence[str], name: str, allowed: Sequence[str] | None = None) -> list[str]:
    """``"a,b"`` (or a sequence) -> ["a", "b"]; a StageFailed names ``name`` when empty or not among ``allowed``."""
    items = [v.strip() for v in (value.split(",") if isinstance(value, str) else value) if v.strip()]
    if not items:
        raise StageFailed(f"{name} must list at least one value; got {value!r}")
    if allowed is not None:
        bad = [v for v in items if v not in allowed]
        if bad:
            raise StageFailed(f"{name} must be among {', '.join(allowed)}; got {', '.join(bad)}")
    return items


def parse_set(pairs: Iterable[str]) -> dict:
    """``("KEY=VALUE", ...)`` -> {KEY: JSON value, or the text when it is no JSON}."""
    import json

    out = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key.isidentifier():
            raise StageFailed(f"--set expects KEY=VALUE with KEY an identifier; got {pair!r}")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def plan(s: ReprocessSettings) -> list:
    """The runs (:class:`vfmlab.reprocess.Run`) the settings ask for, in pipeline order."""
    from vfmlab.pipeline import STAGES
    from vfmlab.reprocess import plan_runs
    from vfmlab.stages.identify import parse_smooth
    from vfmlab.stages.models import model_names

    stage_list = split_list(s.stages, "--stages", tuple(STAGES))
    smoothing = parse_smooth(s.smooth)
    try:
        return plan_runs(stage_list, models=split_list(s.models, "--model", tuple(model_names())),
                         walls=(None,) if s.walls is None else split_list(s.walls, "--wall", ("membrane", "thick")),
                         identify_settings={"ends": s.ends, "optimizer": s.optimizer, "smoothing": smoothing,
                                            "weighting": s.weighting},
                         reconstruct_settings=parse_set(s.set_pairs))
    except ValueError as exc:
        raise StageFailed(f"--set: {exc}" if s.set_pairs else str(exc)) from None


def reprocess(sessions: Iterable[str | os.PathLike], settings: ReprocessSettings | None = None, *,
              runs: list | None = None, on_done: Callable[[Any], None] | None = None,
              progress: ProgressFactory = no_progress, **overrides: Any) -> list:
    """Re-run the stages on each session, appending new results (``vfmlab reprocess``; defaults:
    :class:`ReprocessSettings`); the outcomes (:class:`vfmlab.reprocess.SessionOutcome`), and the CSV
    ``settings.summary`` written when given. A session that fails is reported in its outcome; ``progress`` counts
    the runs (session × stage)."""
    from vfmlab.reprocess import reprocess as run_batch, write_summary

    s = settings_with(ReprocessSettings, settings, overrides)
    runs = plan(s) if runs is None else runs
    sessions = [str(p) for p in sessions]
    try:
        with progress("reprocess", None) as update:
            outcomes = run_batch(sessions, runs, workers=s.workers, scheduler=s.scheduler, on_done=on_done,
                                 progress=lambda done, total, what: update(done, total, f"reprocess: {what}"))
    except (OSError, RuntimeError, ValueError, TimeoutError) as exc:
        raise StageFailed(f"cannot run the batch: {exc}") from None
    if s.summary:
        write_summary(outcomes, s.summary)
    return outcomes


def run(protocol: str | os.PathLike, specimen: str | os.PathLike, out: str | os.PathLike,
        settings: RunSettings | None = None, *, console=None, hooks: dict[str, Any] | None = None, **overrides: Any):
    """Run ``protocol`` (TOML) on the rig (``sim=True``: the simulated rig) into the new session file ``out``
    (``vfmlab run``; defaults: :class:`RunSettings`); the :class:`vfmlab.operate.Outcome`. Unattended
    unless a terminal can answer: pass ``yes=True`` from scripts and notebooks. ``hooks``: keyword arguments of
    :func:`vfmlab.operate.run_session` that watch the run (the browser view's ``on_live_results``)."""
    from rich.console import Console

    from vfmlab.operate import detector_from_reconstruction, run_session
    from vfmlab.stages.models import check_models, model_names

    s = settings_with(RunSettings, settings, overrides)
    check_sim_seed(s)
    models = tuple(m.strip() for m in s.live_models.split(",") if m.strip() and m.strip() != "none")
    unknown = check_models(models)
    if unknown:
        raise StageError(f"--live-models must be among {', '.join(model_names())} or 'none'; got {unknown}")
    return run_session(os.fspath(protocol), os.fspath(specimen), os.fspath(out), rig_path=s.rig, sim=s.sim, yes=s.yes,
                       sim_speed=s.sim_speed, console=console or Console(stderr=True), sim_seed=s.sim_seed,
                       detector=detector_from_reconstruction() if s.detect else None, live_models=models,
                       check_seconds=s.check_seconds, **(hooks or {}))


def check_sim_seed(s: RunSettings) -> None:
    """A StageError when a simulator seed is given without the simulated rig."""
    if s.sim_seed is not None and not s.sim:
        raise StageError(f"--sim-seed sets the simulated rig's seed and needs --sim; got --sim-seed {s.sim_seed} "
                         "without --sim")
