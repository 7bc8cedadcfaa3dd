"""Re-run pipeline stages on stored sessions, serially, on a local process pool or on a Dask cluster.

Every run appends new result groups (with their settings and software version) and never
overwrites. A session that fails (corrupt file, missing input, failed fit) is reported in its
:class:`SessionOutcome` and does not stop the others. :func:`write_summary` writes one CSV row per
identification produced (parameters and standard errors across sessions) plus one per failure.
"""

from __future__ import annotations

import csv
import inspect
import logging
import multiprocessing
import os
import time
import traceback
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from acquisition.session import SessionError, open_session

log = logging.getLogger(__name__)

__all__ = ["Run", "SessionOutcome", "plan_runs", "process_session", "reprocess", "write_summary", "summary_rows"]


@dataclass(frozen=True)
class Run:
    """One stage invocation: ``STAGES[stage](path, **settings)``."""

    stage: str
    settings: Mapping[str, Any] = field(default_factory=dict)

    def label(self) -> str:
        extra = ",".join(f"{k}={v}" for k, v in sorted(self.settings.items()))
        return f"{self.stage}({extra})"


@dataclass
class SessionOutcome:
    """What happened to one session: the result groups written and the errors met (one per failed run)."""

    path: str
    specimen: str = ""
    results: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    identifications: list[dict[str, Any]] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def ok(self) -> bool:
        return not self.errors

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "ok": self.ok}


def plan_runs(stages: Sequence[str], *, models: Sequence[str] = ("fung",), walls: Sequence[str | None] = (None,),
              identify_settings: Mapping[str, Any] | None = None,
              reconstruct_settings: Mapping[str, Any] | None = None) -> list[Run]:
    """The runs for each session: reconstruct once, then identify once per (model, wall); a wall None is the
    identification's default (thick unless the data say membrane)."""
    from vfmlab.pipeline import STAGE_ORDER, STAGES

    unknown = [s for s in stages if s not in STAGES]
    if unknown:
        raise ValueError(f"stages must be among {sorted(STAGES)}; got {unknown}")
    if not stages:
        raise ValueError("stages must name at least one stage")
    runs = []
    for stage in STAGE_ORDER:
        if stage not in stages:
            continue
        if stage == "identify":
            for model in models:
                for wall in walls:
                    extra = {k: v for k, v in (identify_settings or {}).items() if v is not None}
                    runs.append(Run("identify", {"model": model, "wall": wall, **extra}))
        elif stage == "reconstruct":
            runs.append(Run("reconstruct", dict(reconstruct_settings or {})))
        else:  # pragma: no cover - future stages
            runs.append(Run(stage, {}))
    for run in runs:  # unknown settings fail now, not once per session
        accepted = inspect.signature(STAGES[run.stage]).parameters
        unknown = sorted(set(run.settings) - set(accepted))
        if unknown:
            known = sorted(k for k, p in accepted.items() if p.kind == p.KEYWORD_ONLY and k != "invoked_by")
            raise ValueError(f"{run.stage} settings must be among {known}; got unknown {unknown}")
    return runs


def process_session(path: str, runs: Sequence[Run], invoked_by: str = "reprocess",
                    on_run: Callable[[int, str], None] | None = None) -> SessionOutcome:
    """Run ``runs`` in order on one session. Never raises: failures are recorded in the outcome.
    ``on_run(i, label)`` is called before run ``i``.

    If a reconstruct run fails, the identify runs after it are skipped (they would use stale tracks).
    """
    from vfmlab.pipeline import STAGES, StageError
    from vfmlab.results import identification_parameters, stored_verdict

    t0 = time.perf_counter()
    out = SessionOutcome(path=str(path))
    try:
        with open_session(path) as session:
            out.specimen = session.specimen.specimen_id
            status = session.status
        if status == "running":  # an interrupted session's completed steps are fine to process
            raise SessionError(f"{path}: the session is still being written; reprocess it once it has finished")
    except SessionError as exc:
        out.errors.append(str(exc))
        out.seconds = time.perf_counter() - t0
        return out
    failed_stage = None
    for i, run in enumerate(runs):
        if on_run is not None:
            on_run(i, run.label())
        if failed_stage == "reconstruct" and run.stage != "reconstruct":
            out.errors.append(f"{path}: {run.label()} skipped because reconstruct failed")
            continue
        settings = dict(run.settings)
        settings.setdefault("invoked_by", invoked_by)
        try:
            name = STAGES[run.stage](path, **settings)
        except (StageError, SessionError) as exc:
            out.errors.append(f"{exc} [{run.label()}]")
            failed_stage = failed_stage or run.stage
            continue
        except Exception as exc:  # noqa: BLE001 - one failure must not stop the batch; reported, not hidden
            log.debug("%s failed on %s:\n%s", run.label(), path, traceback.format_exc())
            out.errors.append(f"{path}: {run.label()}: {type(exc).__name__}: {exc}")
            failed_stage = failed_stage or run.stage
            continue
        out.results.append(name)
        if run.stage == "identify":
            with open_session(path) as session:
                r = session.result(name)
            out.identifications.append({
                "result": name, "model": str(r["attrs"].get("model", "")), "wall": str(r["attrs"].get("wall", "")),
                "settings": r["parameters"], "cost": float(r["attrs"].get("cost", float("nan"))),
                "converged": bool(r["attrs"].get("converged", False)),
                "flags": [str(f) for f in (r["attrs"].get("flags") or [])],
                "parameters": identification_parameters(r), "version": str(r["attrs"].get("version", "")),
                **stored_verdict(r["attrs"])})
    out.seconds = time.perf_counter() - t0
    return out


def _unique_paths(paths: Iterable[str | os.PathLike]) -> list[str]:
    seen, out = set(), []
    for p in paths:
        key = os.path.realpath(p)
        if key not in seen:  # the same file twice would have two writers at once
            seen.add(key)
            out.append(str(p))
    return out


def reprocess(paths: Iterable[str | os.PathLike], runs: Sequence[Run], *, workers: int = 1,
              scheduler: str | None = None, on_done: Callable[[SessionOutcome], None] | None = None,
              invoked_by: str = "reprocess",
              progress: Callable[[int, int, str], None] | None = None) -> list[SessionOutcome]:
    """Process every session; returns the outcomes in the order of ``paths`` (duplicates removed).
    ``progress(done, total, what)`` counts the runs (session × stage), run by run when serial.

    ``workers`` > 1 uses a local process pool (forkserver processes); ``scheduler`` (a Dask scheduler
    address such as ``tcp://host:8786``) sends one task per session to a dask.distributed cluster.
    """
    paths = _unique_paths(paths)
    if workers < 1:
        raise ValueError(f"workers must be >= 1; got {workers}")
    outcomes: dict[str, SessionOutcome] = {}
    tell = progress or (lambda done, total, what: None)
    total = len(paths) * max(len(runs), 1)

    def done(outcome: SessionOutcome) -> None:
        outcomes[outcome.path] = outcome
        tell(len(outcomes) * max(len(runs), 1), total, f"{len(outcomes)} of {len(paths)} sessions")
        if on_done is not None:
            on_done(outcome)

    if scheduler:
        _run_dask(paths, runs, scheduler, done, invoked_by)
    elif workers > 1 and len(paths) > 1:
        # forkserver: workers fork from a clean single-threaded server that has imported the
        # pipeline once (fork from this process could inherit held locks; spawn re-imports per worker).
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(["vfmlab.reprocess", "vfmlab.pipeline", "identification", "reconstruction",
                                    "acquisition.session"])
        with ProcessPoolExecutor(max_workers=min(workers, len(paths)), mp_context=ctx) as pool:
            futures = {pool.submit(process_session, p, list(runs), invoked_by): p for p in paths}
            for fut in as_completed(futures):
                try:
                    done(fut.result())
                except Exception as exc:  # noqa: BLE001 - a crashed worker process
                    done(SessionOutcome(path=futures[fut], errors=[f"{futures[fut]}: worker failed: {exc!r}"]))
    else:
        for k, p in enumerate(paths):
            def on_run(i: int, label: str, k: int = k, p: str = p) -> None:
                tell(k * len(runs) + i, total, f"{Path(p).name}: {label}")

            done(process_session(p, runs, invoked_by, on_run=on_run))
    return [outcomes[p] for p in paths]


def _run_dask(paths, runs, scheduler, done, invoked_by) -> None:
    try:
        from dask.distributed import Client, as_completed as dask_completed
    except ImportError as exc:
        raise RuntimeError("--scheduler needs dask.distributed: pip install 'vfmlab[dask]'") from exc
    client = Client(scheduler, timeout="30s")
    try:
        futures = client.map(process_session, paths, runs=list(runs), invoked_by=invoked_by, pure=False)
        by_key = {f.key: p for f, p in zip(futures, paths)}
        for fut in dask_completed(futures):
            try:
                done(fut.result())
            except Exception as exc:  # noqa: BLE001 - worker lost, unpicklable result...
                done(SessionOutcome(path=by_key[fut.key], errors=[f"{by_key[fut.key]}: dask task failed: {exc!r}"]))
    finally:
        client.close()


SUMMARY_FIXED = ["session", "specimen", "status", "result", "model", "wall", "optimizer", "ends", "cost",
                 "converged", "n_flags", "verdict", "verdict_reasons", "version", "error"]



def summary_rows(outcomes: Sequence[SessionOutcome]) -> list[dict[str, Any]]:
    """One row per identification produced and one per error.

    Parameters in SI with the unit in the column name (``beta_Pa``, ``beta_stderr_Pa``, ``phi_rad``);
    dimensionless ones without a suffix (``alpha11``, ``alpha11_stderr``).
    """
    rows = []
    for o in outcomes:
        for ident in o.identifications:
            row = {"session": o.path, "specimen": o.specimen, "status": "ok", "result": ident["result"],
                   "model": ident["model"], "wall": ident["wall"], "optimizer": ident["settings"].get("optimizer", ""),
                   "ends": ident["settings"].get("ends", ""), "cost": ident["cost"], "converged": ident["converged"],
                   "n_flags": len(ident["flags"]), "verdict": ident.get("verdict", ""),
                   "verdict_reasons": " | ".join(ident.get("verdict_reasons", [])), "version": ident["version"],
                   "error": ""}
            for name, p in ident["parameters"].items():
                suffix = f"_{p['unit']}" if p.get("unit") not in (None, "", "1") else ""  # SI unit in the header
                row[f"{name}{suffix}"] = p["value"]
                row[f"{name}_stderr{suffix}"] = p["stderr"]
                row[f"{name}_verdict"] = ident.get("parameter_verdicts", {}).get(name, "")
            rows.append(row)
        for err in o.errors:
            rows.append({"session": o.path, "specimen": o.specimen, "status": "failed", "error": err})
    return rows


def write_summary(outcomes: Sequence[SessionOutcome], path: str | os.PathLike) -> Path:
    """Write the summary CSV (see :func:`summary_rows`); parameter columns follow the fixed ones."""
    rows = summary_rows(outcomes)
    params: list[str] = []
    for row in rows:
        for key in row:
            if key not in SUMMARY_FIXED and key not in params:
                params.append(key)
    path = Path(path)
    with open(path, "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=SUMMARY_FIXED + params, restval="")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (f"{v:.10g}" if isinstance(v, float) else v) for k, v in row.items()})
    return path
