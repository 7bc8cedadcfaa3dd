"""Issue 26, items 7-11: inputs judged by physics as well as by syntax, and text from files that cannot act on
the terminal. One test per item, each asserting the message and the exit code (decision 0007: 0 complete,
1 failed, 2 bad input, 130 interrupted).
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.test_markers_csv import _write_inputs
from vfmlab.cli import main

ESC = "\x1b"


def run(capsys, *argv) -> tuple[int, str, str]:
    """``vfmlab argv`` in-process: (exit code, stdout, stderr as one line); never a traceback."""
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert "Traceback" not in err and "internal error" not in err, err
    return rc, out, " ".join(err.split())


# -- item 8: terminal escape sequences -----------------------------------------------------------------------

def test_escape_sequences_from_a_session_are_shown_escaped(tmp_path, capsys):
    markers, loads = _write_inputs(tmp_path, n_markers=12, n_steps=3)
    evil = tmp_path / f"m{ESC}]0;owned{chr(7)}.csv"  # a file name is text from outside too
    evil.write_bytes(markers.read_bytes())
    out = tmp_path / "s.h5"
    rc, _, _ = run(capsys, "import-markers", evil, loads, "--thickness-mm", "1.3", "-o", out,
                   "--specimen-id", f"A1{ESC}[2J{ESC}]0;pwned{chr(7)}", "--notes", f"note\r{ESC}[31mred\u202eevil")
    assert rc == 0
    for argv in (["info", out], ["results", out], ["info", "--json", out], ["results", "--json", out]):
        rc, text, err = run(capsys, *argv)
        assert rc == 0 and ESC not in text + err and "\r" not in text and chr(7) not in text, argv
        assert "\u202e" not in text
    rc, text, _ = run(capsys, "info", out)
    # (rich itself drops BEL and CR; the rest is shown escaped)
    assert "A1\\x1b[2J\\x1b]0;pwned" in text and "note\\x1b[31mred\\u202eevil" in text
    rc, text, _ = run(capsys, "results", out)
    assert "m\\x1b]0;owned" in text
    rc, _, err = run(capsys, "info", tmp_path / f"no{ESC}[2Jsuch.h5")
    assert rc == 2 and ESC not in err and "no\\x1b[2Jsuch.h5" in err


def test_log_lines_show_control_characters_escaped(capsys):
    import logging

    from vfmlab.cli._common import _EchoHandler

    _EchoHandler().emit(logging.LogRecord("vfmlab", logging.WARNING, __file__, 1, f"x{ESC}[2Jy", None, None))
    err = capsys.readouterr().err
    assert ESC not in err and "x\\x1b[2Jy" in err


# -- item 9: an HDF5 session with a user block -------------------------------------------------------------------

@pytest.mark.parametrize("userblock", [512, 1024, 4096])
def test_export_markers_never_overwrites_an_hdf5_file_with_a_user_block(tmp_path, capsys, userblock):
    import h5py

    markers, loads = _write_inputs(tmp_path, n_markers=12, n_steps=3)
    session = tmp_path / "s.h5"
    assert run(capsys, "import-markers", markers, loads, "--thickness-mm", "1.3", "-o", session)[0] == 0
    other = tmp_path / "U.h5"
    with h5py.File(other, "w", userblock_size=userblock) as f:
        f["entry/data"] = np.arange(10.0)
    before = other.read_bytes()
    assert before[:8] != b"\x89HDF\r\n\x1a\n" and before[userblock:userblock + 8] == b"\x89HDF\r\n\x1a\n"
    rc, _, err = run(capsys, "export-markers", session, "-o", other, "--force")
    assert rc == 1 and "is an HDF5 session file; vfmlab never overwrites a session, even with --force" in err
    assert other.read_bytes() == before
    text = tmp_path / "t.csv"  # 8 bytes that look like the signature, but not at an offset the spec allows
    text.write_bytes(b"x" * 100 + b"\x89HDF\r\n\x1a\n")
    assert run(capsys, "export-markers", session, "-o", text, "--force")[0] == 0
