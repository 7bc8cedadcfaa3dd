"""One grammar and one console for all commands (issue 13, issue 16 item 10).

- docs/decisions/0004 lists every option of every command, as the CLI has them;
- every --help ends with examples and shows no printf residue;
- output that is not a terminal is the same whatever the terminal width: no line is wrapped or cut;
- text from users and files prints literally, never as rich markup.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from rig_sim.synthetic_session import make_session
from vfmlab.cli import COMMANDS, cli, main
from vfmlab.cli._options_table import HEADER, option_rows

ROOT = Path(__file__).resolve().parents[1]
DECISION = ROOT / "docs" / "decisions" / "0004-cli-and-console.md"
EVIL = "[/]evil [table] \\[bold]x"  # closes nothing, looks like tags, an escaped-looking tag


def _doc_rows() -> list[tuple[str, ...]]:
    lines = DECISION.read_text(encoding="utf-8").splitlines()
    start = lines.index(HEADER) + 2
    rows = []
    for line in lines[start:]:
        if not line.startswith("|"):
            break
        cells = re.split(r"(?<!\\)\|", line.strip())[1:-1]
        rows.append(tuple(c.strip() for c in cells))
    return rows


def test_decision_table_lists_every_option_of_every_command():
    doc = _doc_rows()
    cli_rows = option_rows()
    # command, flags, value and default must agree row by row; the meaning is the option's help text
    assert [r[:4] for r in doc] == [r[:4] for r in cli_rows], "regenerate: python -m vfmlab.cli._options_table"
    assert [r[4] for r in doc] == [r[4] for r in cli_rows]
    assert {r[0].strip("`") for r in doc} == set(COMMANDS)


@pytest.mark.parametrize("name", list(COMMANDS))
def test_every_help_has_an_example(name):
    result = CliRunner().invoke(cli, [name, "--help"], env={"COLUMNS": "80"})
    assert result.exit_code == 0, result.output
    assert "Example" in result.output and f"vfmlab {name}" in result.output.split("Example")[1]
    assert "%%" not in result.output


@pytest.fixture(scope="module")
def long_session(tmp_path_factory):
    """A session whose path is longer than any terminal, with a specimen id and notes full of brackets."""
    deep = tmp_path_factory.mktemp("w")
    for k in range(4):
        deep = deep / f"a-rather-long-folder-name-number-{k}"
    deep.mkdir(parents=True)
    return make_session(deep / "session-with-a-long-name.h5", specimen_id=EVIL)


def _commands(session: Path, tmp: Path) -> list[list[str]]:
    return [["info", str(session)], ["results", str(session)],
            ["results", str(session), "--compare", "identification_001", "identification_002"],
            ["export-markers", str(session), "-o", str(tmp / "m.csv"), "--force"],
            ["info", str(session.with_name("missing-" + session.name))]]


def test_non_terminal_output_never_wraps_or_cuts(long_session, tmp_path, monkeypatch):
    from vfmlab.cli._common import console, err_console

    outputs = {}
    for columns in ("40", "250"):
        for c in (console, err_console):  # as if the terminal had this width when vfmlab started
            monkeypatch.setattr(c, "_width", int(columns))
        runner = CliRunner()
        texts = []
        for args in _commands(long_session, tmp_path):
            result = runner.invoke(cli, args, env={"COLUMNS": columns, "TERM": "xterm-256color"})
            assert result.exception is None or isinstance(result.exception, SystemExit), result.output
            texts.append(result.output)
        outputs[columns] = texts
    assert outputs["40"] == outputs["250"]  # the terminal width does not matter when there is no terminal
    text = "\n".join(outputs["40"])
    assert "…" not in text
    lines = text.splitlines()
    path = str(long_session)
    assert any(line.startswith(path) for line in lines)  # the whole path on one line
    assert any(line.startswith(f"Wrote 160 markers × 7 steps from markers_001 to {tmp_path / 'm.csv'}")
               for line in lines)
    assert any(line.startswith("Error: ") and path.replace("session-with", "missing-session-with") in line
               for line in lines)
    assert all(line == line.rstrip() for line in lines)  # no padding to a width
    assert "beta = 5 kPa ± 0.2 kPa, alpha11 = 14.5 ± 0.58" in text  # units on the numbers


def test_user_text_prints_literally_never_as_markup(long_session, tmp_path, capsys):
    assert main(["info", str(long_session)]) == 0
    out = capsys.readouterr().out
    assert f"Specimen {EVIL}:" in out and "(synthetic test tube)" in out
    assert main(["info", str(long_session), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["specimen"]["id"] == EVIL
    # marker ids and a CSV header with markup-like text: imported, listed, exported, or refused with the text
    markers, loads = tmp_path / "markers.csv", tmp_path / "loads.csv"
    rng = np.random.default_rng(0)
    theta, z = rng.uniform(-np.pi, np.pi, 30), rng.uniform(-12, 12, 30)
    rows = [f"[/]m{i}[b],{s},{10 * (1 + 0.02 * s) * np.cos(t):.5f},{10 * (1 + 0.02 * s) * np.sin(t):.5f},{zi:.5f}"
            for s in range(3) for i, (t, zi) in enumerate(zip(theta, z))]
    markers.write_text("marker_id,step,x_mm,y_mm,z_mm\n" + "\n".join(rows) + "\n")
    loads.write_text("step,pressure_mmHg,axial_force_N,stretch\n0,0,0.1,1\n1,50,0.2,1.05\n2,100,0.3,1.05\n")
    out_h5 = tmp_path / "evil.h5"
    assert main(["import-markers", str(markers), str(loads), "--thickness-mm", "1.3", "-o", str(out_h5),
                 "--notes", EVIL, "--specimen-id", EVIL]) == 0
    assert main(["export-markers", str(out_h5), "-o", str(tmp_path / "back.csv")]) == 0
    assert "[/]m0[b]" in (tmp_path / "back.csv").read_text()
    assert main(["info", str(out_h5)]) == 0
    assert f"({EVIL})" in capsys.readouterr().out
    bad = tmp_path / "bad.csv"
    bad.write_text("marker_id,step,x_mm,y_mm,[/]z_mm\nA,0,1,2,3\n")
    assert main(["import-markers", str(bad), str(loads), "--thickness-mm", "1.3", "-o", str(tmp_path / "b.h5")]) != 0
    err = capsys.readouterr().err
    assert "[/]z_mm" in err and "Traceback" not in err


def test_table_names_survive_in_protocol_errors(tmp_path, capsys):
    protocol = tmp_path / "p.toml"
    protocol.write_text('[protocol]\nname = "no blocks"\n')
    rc = main(["run", str(protocol), "--specimen", str(ROOT / "examples" / "specimen.toml"), "-o",
               str(tmp_path / "x.h5"), "--sim", "--yes"])
    err = capsys.readouterr().err
    assert rc != 0 and "add a [test] table" in err and "[[block]]" in err


def test_run_without_a_terminal_says_to_pass_yes(tmp_path):
    result = CliRunner().invoke(cli, ["run", "p.toml", "--specimen", "s.toml", "-o", str(tmp_path / "x.h5"), "--sim"],
                                input="")
    assert result.exit_code == 1
    assert "standard input is not a terminal" in result.output and "pass --yes" in result.output
    assert not (tmp_path / "x.h5").exists()


def test_output_folders_are_never_created_and_files_need_force(long_session, tmp_path, capsys):
    missing = tmp_path / "no" / "such"
    assert main(["export-markers", str(long_session), "-o", str(missing / "m.csv")]) == 1
    assert "does not exist; create it first" in capsys.readouterr().err
    assert main(["report", str(long_session), "-o", str(missing / "r")]) == 1
    assert not (tmp_path / "no").exists()
    existing = tmp_path / "summary.csv"
    existing.write_text("keep me")
    assert main(["reprocess", str(long_session), "--summary", str(existing)]) == 1
    assert "pass --force" in capsys.readouterr().err and existing.read_text() == "keep me"
