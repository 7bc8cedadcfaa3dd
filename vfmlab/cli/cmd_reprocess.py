"""``vfmlab reprocess``: re-run stages on stored sessions with new settings, in parallel if asked."""

from __future__ import annotations

from pathlib import Path

import click
from rich.table import Table

from vfmlab.cli._common import CliError, console, err_console, esc, print_json
from vfmlab.cli._outputs import check_output_path


EPILOG = """
\b
Examples:
  vfmlab reprocess a1.h5 a2.h5 a3.h5 --model fung,hgo --summary params.csv
  vfmlab reprocess data/*.h5 --stages reconstruct,identify --smooth auto --workers 2
  vfmlab reprocess data/*.h5 --scheduler tcp://10.0.0.5:8786 --json
"""


@click.command("reprocess", epilog=EPILOG)
@click.argument("sessions", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--stages", default="identify", show_default=True,
              help="Comma-separated stages to re-run, in pipeline order: reconstruct, identify.")
@click.option("--model", "models", default="fung", show_default=True,
              help="Comma-separated models to identify: fung, delfino, hgo, neohookean.")
@click.option("--wall", "walls", default=None,
              help="Wall formulation(s), comma-separated: membrane, thick. Default: thick unless the data say "
                   "membrane (as 'vfmlab identify').")
@click.option("--ends", type=click.Choice(["clamped", "free"]), default=None,
              help="clamped: tube tied on cannulae beyond the markers (pressure on the unmeasured strip counted); "
                   "free: uniform tube up to the load cell. Default: what the session records, else the data decide "
                   "(as 'vfmlab identify').")
@click.option("--optimizer", type=click.Choice(["lsq", "nelder-mead"]), default="lsq", show_default=True,
              help="Optimiser (identify).")
@click.option("--smooth", default="auto", show_default=True, metavar="auto|none|AXIAL,HARMONICS",
              help="Smooth the measured displacements before identifying (as 'vfmlab identify --smooth').")
@click.option("--weighting", type=click.Choice(["efficient", "paper", "noise"]), default="efficient",
              show_default=True,
              help="Generalised least squares over the gaps' noise covariance, the paper's cost, or gaps weighted by "
                   "their noise (as 'vfmlab identify --weighting'; Nelder-Mead always uses the paper's).")
@click.option("--set", "set_pairs", multiple=True, metavar="KEY=VALUE",
              help="Extra setting for the reconstruct stage (JSON value), repeatable.")
@click.option("--workers", type=click.IntRange(min=1), default=1, show_default=True,
              help="Sessions processed in parallel on this machine (process pool).")
@click.option("--scheduler", metavar="ADDRESS",
              help="Dask distributed scheduler (e.g. tcp://10.0.0.5:8786): one task per session on the cluster.")
@click.option("--summary", type=click.Path(dir_okay=False),
              help="Write a CSV of the identified parameters across sessions (one row per identification; SI, "
                   "the unit in each column name, e.g. beta_Pa).")
@click.option("--force", is_flag=True, help="Overwrite the --summary file if it exists.")
@click.option("--json", "as_json", is_flag=True, help="Print the outcomes as JSON.")
def command(sessions, stages, models, walls, ends, optimizer, smooth, weighting, set_pairs, workers, scheduler, summary,
            force, as_json):
    """Re-run STAGES on each SESSION with the given settings, appending new results (nothing is overwritten).

    A session that fails (corrupt file, missing markers, failed fit) is reported and the others go on;
    the exit code is 1 if any failed.
    """
    from vfmlab.pipeline import STAGES
    from vfmlab.stages.batch import plan, reprocess, split_list
    from vfmlab.cli._feedback import progress_bar
    from vfmlab.stages.feedback import no_progress
    from vfmlab.stages.identify import verdict_lines
    from vfmlab.stages.settings import ReprocessSettings

    split_list(stages, "--stages", tuple(STAGES))
    if summary:
        check_output_path(summary, force=force, inputs=sessions, option="--summary")
    settings = ReprocessSettings(stages=stages, models=models, walls=walls, ends=ends, optimizer=optimizer,
                                 smooth=smooth, weighting=weighting, set_pairs=set_pairs, workers=workers,
                                 scheduler=scheduler, summary=summary)
    runs = plan(settings)
    where = f"Dask scheduler {scheduler}" if scheduler else (f"{workers} worker processes" if workers > 1 else "serially")
    if not as_json:
        console.print(f"Reprocessing {len(sessions)} session(s) {esc(where)}: " + esc("; ".join(r.label() for r in runs)))

    def on_done(outcome):
        if not outcome.ok and not as_json:
            for err in outcome.errors:
                err_console.print(f"[red]failed:[/] {esc(err)}")

    outcomes = reprocess(sessions, settings, runs=runs, on_done=on_done, progress=no_progress if as_json else progress_bar)
    path = Path(summary) if summary else None  # as vfmlab.reprocess.write_summary names it
    if as_json:
        print_json({"outcomes": [o.to_dict() for o in outcomes], "summary": summary})
    else:
        table = Table(title="Reprocessing")
        for col in ("session", "specimen", "new results", "time (s)", "status"):
            table.add_column(col, overflow="fold")
        for o in outcomes:
            table.add_row(esc(o.path), esc(o.specimen), esc(", ".join(o.results) or "–"), f"{o.seconds:.1f}",
                          "ok" if o.ok else f"[red]{len(o.errors)} error(s)[/]")
        console.print(table)
        for path_, ident in ((o.path, i) for o in outcomes for i in o.identifications if i.get("verdict")):
            console.print(esc(f"{path_} {ident['result']} ({ident['model']}, {ident['wall']}): " + "\n".join(
                verdict_lines(ident["verdict"], ident["verdict_reasons"], ident["parameter_verdicts"],
                              ident["parameter_reasons"]))))
        n_bad = sum(not o.ok for o in outcomes)
        console.print(f"{len(outcomes) - n_bad} of {len(outcomes)} sessions processed without error."
                      + (f" Summary: {esc(path)}" if summary else ""))
    n_bad = sum(not o.ok for o in outcomes)
    if n_bad:
        raise CliError(f"{n_bad} of {len(outcomes)} session(s) failed; the others were processed (see above)")
