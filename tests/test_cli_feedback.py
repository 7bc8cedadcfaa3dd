"""Progress on the command line: a bar with the time left on a terminal, one line per stage otherwise."""

from __future__ import annotations

import io
import re

from rich.console import Console

from vfmlab.cli._feedback import progress_bar
from vfmlab.report import build_report


class _Clock:
    """A clock the test moves (no sleeping)."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_not_a_terminal_prints_one_line_per_stage():
    out = io.StringIO()
    console = Console(file=out, force_terminal=False, width=120)
    with progress_bar("report", None, console=console) as update:
        for stage in ("report: surface fields", "report: Strain maps", "report: Stress maps"):
            for k in range(5):  # ticks within a stage print nothing more
                update(k, 5, stage)
        update()
    lines = out.getvalue().splitlines()
    assert lines == ["report ...", "report: surface fields ...", "report: Strain maps ...", "report: Stress maps ..."]


def test_terminal_shows_a_bar_with_time_left():
    out = io.StringIO()
    console = Console(file=out, force_terminal=True, width=120, color_system=None)
    clock = _Clock()
    with progress_bar("identify fung", None, console=console, clock=clock) as update:
        update(0, 16, "identify fung: bootstrap")
        for k in range(1, 9):
            clock.t += 2.0  # two seconds a replicate: eight left, 16 s
            update(k, 16)
    text = out.getvalue()  # the bar's last frame, drawn when it stops (then erased: the bar is transient)
    shown = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", text)
    assert "identify fung: bootstrap" in shown
    assert "8/16" in shown
    assert re.search(r"left\s+0:00:1[5-7]", shown), shown[-400:]


def test_report_tells_each_section(tmp_path):
    from rig_sim.synthetic_session import make_session

    session = make_session(tmp_path / "bare.h5", with_results=False)
    told = []
    build_report(session, tmp_path / "out", progress=lambda done, total, what: told.append((done, total, what)))
    assert told[0] == (0, told[0][1], "surface fields") and told[-1] == (told[0][1], told[0][1], "done")
    assert [d for d, _, _ in told] == list(range(len(told)))
