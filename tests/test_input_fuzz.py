"""Property-based tests (hypothesis) of every reader where files enter: random and mutated CSV, TOML
and HDF5 inputs give a typed error or a valid result, never another exception (issue 15).

Deterministic (``derandomize=True``) and small (``max_examples``) so that CI is fast and repeatable.
"""

from __future__ import annotations

import contextlib
import functools
import io
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from acquisition.markers_csv import CsvFormatError, read_loads_csv, read_markers_csv
from acquisition.protocol import ConfigError, parse_protocol, parse_rig, parse_specimen
from acquisition.session import SessionError, open_session
from reconstruction.calibration_io import CalibrationFileError, cameras_from_toml, cameras_to_toml
from tests.test_markers_csv import _write_inputs

FUZZ = settings(max_examples=40, derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])

_WORK = Path(tempfile.mkdtemp(prefix="vfmlab-fuzz-"))
_MARKERS, _LOADS = _write_inputs(_WORK, n_markers=10, n_steps=3)
VALID = {"markers": _MARKERS.read_text(), "loads": _LOADS.read_text()}
_CSV_ALPHABET = st.sampled_from(list("0123456789,.-+eE\n\r\t \"'nNaAiIfF_xyzmM;\x00\xff"))


def mutated(text: str) -> st.SearchStrategy[str]:
    """``text`` with a few characters deleted, replaced or inserted, or cut short."""
    edit = st.tuples(st.sampled_from(["delete", "replace", "insert", "truncate", "duplicate"]),
                     st.integers(0, max(len(text) - 1, 0)), _CSV_ALPHABET)

    def apply(edits):
        out = text
        for kind, at, char in edits:
            at = min(at, len(out))
            if kind == "delete":
                out = out[:at] + out[at + 1:]
            elif kind == "replace":
                out = out[:at] + char + out[at + 1:]
            elif kind == "insert":
                out = out[:at] + char + out[at:]
            elif kind == "truncate":
                out = out[:at]
            else:
                line_end = out.find("\n", at)
                out = out[:line_end + 1] + out[at:line_end + 1] + out[line_end + 1:] if line_end >= 0 else out
        return out

    return st.lists(edit, min_size=1, max_size=4).map(apply)


def _write(name: str, data: str | bytes) -> Path:
    path = _WORK / name
    path.write_bytes(data.encode("utf-8", "surrogatepass") if isinstance(data, str) else data)
    return path


def _check_markers(path: Path) -> None:
    try:
        table = read_markers_csv(path)
    except CsvFormatError as exc:
        assert str(path) in str(exc)
        return
    assert table.positions.shape == (len(table.steps), len(table.labels), 3)
    assert table.steps[0] == 0 and np.all(np.diff(table.steps) > 0)
    finite = table.positions[np.isfinite(table.positions)]
    assert np.all(np.abs(finite) <= 1e2)  # metres: the reader bounds coordinates at 1e5 mm


def _check_loads(path: Path) -> None:
    try:
        loads = read_loads_csv(path)
    except CsvFormatError as exc:
        assert str(path) in str(exc)
        return
    assert np.all(np.isfinite(loads["pressure"])) and np.all(loads["stretch"] > 0)
    assert loads["step"].dtype.kind == "i" and loads["step"].max() < 2**31


@FUZZ
@given(st.one_of(mutated(VALID["markers"]), st.text(_CSV_ALPHABET, max_size=300)))
def test_markers_csv_reader(text):
    _check_markers(_write("m.csv", text))


@FUZZ
@given(st.one_of(mutated(VALID["loads"]), st.text(_CSV_ALPHABET, max_size=300)))
def test_loads_csv_reader(text):
    _check_loads(_write("l.csv", text))


@FUZZ
@given(st.binary(max_size=200))
def test_csv_readers_on_random_bytes(data):
    path = _write("b.csv", data)
    _check_markers(path)
    _check_loads(path)


# -- TOML -------------------------------------------------------------------------------------------

_TOML_ALPHABET = st.sampled_from(list("[]{}=\"'.,#\n 0123456789abcdefghijklmnopqrstuvwxyz_-+eE"))


def _calibration_toml() -> str:
    from reconstruction.cameras import Camera

    cams = [Camera(f"cam{i}", np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]]), np.zeros(5),
                   np.array([0.0, 0.1 * i, 0]), np.array([0.0, 0, 300]), (640, 480)) for i in range(2)]
    return cameras_to_toml(cams, units="mm")


_PROTOCOL = "[preconditioning]\ncycles = 3\n\n[[block]]\nstretch = 1.05\npressures_mmHg = [0, 30, 80, 150]\n"


@FUZZ
@given(st.one_of(mutated(_calibration_toml()), st.text(_TOML_ALPHABET, max_size=300)))
def test_calibration_toml_reader(text):
    try:
        cams, _ = cameras_from_toml(text)
    except (CalibrationFileError, ValueError) as exc:  # TOML syntax errors are ValueErrors with line/column
        assert str(exc)
        return
    for cam in cams:
        assert np.all(np.isfinite(cam.K)) and len(cam.image_size) == 2


@FUZZ
@given(st.one_of(mutated(_PROTOCOL), st.text(_TOML_ALPHABET, max_size=200)))
def test_protocol_and_specimen_toml_readers(text):
    for parse in (parse_protocol, parse_specimen, parse_rig):
        try:
            parse(text)
        except ConfigError as exc:
            assert str(exc)


# -- HDF5 sessions -------------------------------------------------------------------------------

@functools.cache
def _small_session() -> bytes:
    """A small imported session (10 markers x 3 steps), built once."""
    from vfmlab.cli import main

    out = _WORK / "small.h5"
    if not out.exists():
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            assert main(["import-markers", str(_MARKERS), str(_LOADS), "--thickness-mm", "1.3", "-o", str(out)]) == 0
    return out.read_bytes()


def _read_everything(path: Path) -> None:
    """Every reader of the Session class, as the commands use them."""
    from vfmlab.cli.cmd_info import summarise

    with open_session(path) as s:
        info = summarise(s)  # per-part damage is collected, not raised
        assert isinstance(info["damaged"], list)
        for name in s.results():
            result = s.result(name)
            if result["kind"] == "markers":
                assert np.ndim(result["arrays"]["positions"]) == 3
        _ = (s.steps, s.specimen, s.events(), s.log("force"), s.image_cameras, s.protocol_text)


@FUZZ
@given(st.lists(st.tuples(st.floats(0, 1, exclude_max=True), st.integers(0, 7)), min_size=1, max_size=4))
def test_session_bit_flips(flips):
    data = bytearray(_small_session())
    for where, bit in flips:
        data[int(where * len(data))] ^= 1 << bit
    path = _write("flipped.h5", bytes(data))
    try:
        _read_everything(path)
    except SessionError as exc:
        assert str(path) in str(exc)


@FUZZ
@given(st.floats(0, 1), st.binary(max_size=64))
def test_session_truncated_or_overwritten(cut, junk):
    data = _small_session()
    path = _write("cut.h5", data[:int(cut * len(data))] + junk)
    try:
        _read_everything(path)
    except SessionError as exc:
        assert str(path) in str(exc)


def test_the_fuzzed_inputs_start_valid():
    """The mutation base is valid: the properties above are not vacuous."""
    _check_markers(_MARKERS)
    assert read_markers_csv(_MARKERS).positions.shape == (3, 10, 3)
    assert len(cameras_from_toml(_calibration_toml())[0]) == 2
    _read_everything(_write("valid.h5", _small_session()))
    assert not math.isnan(read_loads_csv(_LOADS)["pressure"][1])
    with pytest.raises(SessionError):
        _read_everything(_write("empty.h5", b""))
