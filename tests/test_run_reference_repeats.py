"""``[reference] repeats = N`` (issue 24): parsed and refused with named errors, captured N times by the runner as
N steps of block 0, and recognised by the stage layer from what the session records."""

import numpy as np
import pytest

from acquisition.cameras import FunctionCamera
from acquisition.protocol import MAX_REFERENCE_REPEATS, ConfigError, parse_protocol
from acquisition.runner import AutoOperator, SessionRunner
from acquisition.session import CameraSpec, SessionWriter, SpecimenInfo, open_session
from _run_fakes import FakeRig
from vfmlab.stages.reference import reference_repeats

TEST = """
[stability]
band_mmHg = 0.5
dwell_s = 0.05
timeout_s = 2
[test]
stretches = [1.1]
pressures_mmHg = [0, 60, 120]
[capture]
timeout_s = 1
"""


def test_repeats_parse_and_default():
    p = parse_protocol(TEST + "[reference]\ncapture = true\nrepeats = 4\n")
    assert p.reference_repeats == 4 and p.n_steps == 4 + 3
    assert p.steps[:5] == [(0, 1.0, 0.0)] * 4 + [(1, 1.1, 0.0)]
    one = parse_protocol(TEST + "[reference]\ncapture = true\n")
    assert one.reference_repeats == 1 and one.steps[:2] == [(0, 1.0, 0.0), (1, 1.1, 0.0)] and one.n_steps == 4
    assert parse_protocol(TEST).reference_repeats == 1 and not parse_protocol(TEST).has_reference


@pytest.mark.parametrize("value, message", [
    ("0", r"\[reference\].repeats: expected the number of captures of the reference, an integer >= 1; got 0"),
    ("-2", r"\[reference\].repeats: expected .* >= 1; got -2"),
    (str(MAX_REFERENCE_REPEATS + 1), rf"\[reference\].repeats: {MAX_REFERENCE_REPEATS + 1} captures .* at most "
                                     rf"{MAX_REFERENCE_REPEATS}"),
    ("2.5", r"\[reference\].repeats: expected an integer; got float 2.5"),
    ("true", r"\[reference\].repeats: expected an integer; got bool"),
])
def test_absurd_repeats_are_refused_with_the_key_named(value, message):
    with pytest.raises(ConfigError, match=message):
        parse_protocol(TEST + f"[reference]\ncapture = true\nrepeats = {value}\n", source="p.toml")


def test_repeats_without_a_captured_reference_are_refused():
    with pytest.raises(ConfigError, match=r"p.toml: \[reference\].repeats: repeats = 3 needs capture = true"):
        parse_protocol(TEST + "[reference]\nrepeats = 3\n", source="p.toml")
    with pytest.raises(ConfigError, match=r"unknown key|repeat"):
        parse_protocol(TEST + "[reference]\ncapture = true\nrepeat = 3\n", source="p.toml")


def _run(tmp_path, text):
    rig = FakeRig()
    cams = [FunctionCamera(f"cam{i}", lambda s: np.zeros((s["height"], s["width"]), np.uint8),
                           {"width": 16, "height": 12}).open() for i in range(2)]
    w = SessionWriter.create(tmp_path / "s.h5", SpecimenInfo("s1", 0.01, 0.035, 0.0013),
                             cameras=[CameraSpec(c.name, "sim", 16, 12) for c in cams], protocol_text=text)
    runner = SessionRunner(parse_protocol(text), w, pressure=rig, sampler=rig, cameras=cams, operator=AutoOperator(),
                           stage=lambda s: setattr(rig, "stretch", s), tick_s=0.01)
    assert runner.run() == "complete"
    with open_session(tmp_path / "s.h5") as s:
        return s.steps, s.protocol_text


def test_runner_captures_the_reference_n_times_and_the_stage_sees_them(tmp_path):
    text = TEST + "[reference]\ncapture = true\nrepeats = 3\n"
    steps, stored = _run(tmp_path, text)
    assert steps["block"].tolist() == [0, 0, 0, 1, 1, 1]
    assert steps["stretch"].tolist() == [1.0] * 3 + [1.1] * 3
    assert steps["target_pressure"][:3].tolist() == [0.0] * 3
    assert reference_repeats(stored, steps["block"]) == 3


def test_runner_without_repeats_is_unchanged(tmp_path):
    steps, stored = _run(tmp_path, TEST + "[reference]\ncapture = true\n")
    assert steps["block"].tolist() == [0, 1, 1, 1] and steps["stretch"].tolist() == [1.0] + [1.1] * 3
    assert reference_repeats(stored, steps["block"]) == 1


def test_stage_decision_needs_the_protocol_to_say_so():
    with_ref = TEST + "[reference]\ncapture = true\nrepeats = 3\n"
    assert reference_repeats(with_ref, np.array([0, 0, 0, 1, 1, 1])) == 3
    assert reference_repeats(with_ref, np.array([0, 0, 1, 1])) == 2  # a capture not in the markers result
    assert reference_repeats(TEST, np.array([0, 0, 0, 1, 1])) == 1  # block 0 is a loaded block: no reference
    assert reference_repeats("", np.array([0, 0, 0, 1, 1])) == 1  # imported session: nothing recorded
    assert reference_repeats("[test]\nstretches = 'x'\n", np.array([0, 0, 1, 1])) == 1  # unreadable protocol
    assert reference_repeats(with_ref, np.array([0, 0, 0])) == 1  # no loaded step: nothing to average for
