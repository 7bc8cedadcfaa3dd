"""``vfmlab results``: list the derived results of a session and compare two of them."""

from __future__ import annotations

import click
from vfmlab.cli._common import console, esc, print_json
from vfmlab.display import settings_text
from vfmlab.cli._sessions import cli_session


#: The settings a listing shows per kind (--json or --compare show every setting).
KEY_SETTINGS = {"identification": ("optimizer", "ends", "markers_result")}


EPILOG = """
\b
Examples:
  vfmlab results a1.h5
  vfmlab results a1.h5 --kind identification --json
  vfmlab results a1.h5 --compare identification_001 identification_002
"""


@click.command("results", epilog=EPILOG)
@click.argument("session", type=click.Path(dir_okay=False))
@click.option("--kind", help="Only results of this kind (calibration, markers, identification, ...).")
@click.option("--compare", nargs=2, metavar="A B", help="Compare two results by name, e.g. identification_001 identification_002.")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable JSON on stdout (SI; each parameter has its unit).")
def command(session, kind, compare, as_json):
    """List the results stored in SESSION (name, kind, date, version, settings; identified parameters) and the
    identified models side by side (parameters with units, cost, verdict), or compare two results (settings diff
    and differences of their parameters)."""
    from vfmlab.display import side_by_side_table
    from vfmlab.results import compare_results, list_results, side_by_side
    from vfmlab.stages.reachable import with_reachable
    from vfmlab.views.results import comparison_lines, result_lines

    with cli_session(session) as s:
        data = compare_results(s, *compare) if compare else with_reachable(s, list_results(s, kind))
    if as_json:
        print_json(data)
        return
    if compare:
        for item in comparison_lines(data):
            console.print(item)
        return
    if not data:
        console.print(f"{esc(session)}: no results{' of kind ' + esc(kind) if kind else ''} yet.")
        return
    console.print(f"[bold]{esc(session)}[/]: {len(data)} result(s), oldest first")
    for row in data:
        for line in result_lines(row, settings_text(row["settings"], KEY_SETTINGS.get(row["kind"]))):
            console.print(line)
    table = side_by_side(data)
    if table["rows"]:
        console.print(side_by_side_table(table))
