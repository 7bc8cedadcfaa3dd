"""Protocol / rig / specimen files: examples load, units convert to SI, every validation error is named."""

from pathlib import Path

import pytest

from acquisition.protocol import (MMHG, ConfigError, load_protocol, load_rig, load_specimen, parse_protocol,
                                  parse_rig, parse_specimen)

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

GOOD = """
[preconditioning]
pressure_cycles = 2
pressure_max_mmHg = 80
stretch_cycles = 2
stretch_max = 1.4
[stability]
band_mmHg = 1
dwell_s = 0.5
[[block]]
stretch = 1.1
pressures_mmHg = [0, 50, 100]
"""


@pytest.fixture(scope="module")
def rig():
    return load_rig(EXAMPLES / "sim-rig.toml")


def test_examples_load_in_si(rig):
    paper = load_protocol(EXAMPLES / "paper-protocol.toml", rig)
    # block 0: the stress-free reference (L/L0 = 1, p = 0) captured 4 times; then the paper's 8 levels at L/L0 = 1.1
    assert paper.has_reference and paper.steps[:4] == [(0, 1.0, 0.0)] * 4 and paper.reference_repeats == 4
    assert paper.n_steps == 12 and [b.stretch for b in paper.blocks] == [1.0, 1.1]
    assert paper.blocks[1].pressures[-1] == pytest.approx(150 * MMHG)
    assert paper.preconditioning.pressure_cycles == 8 and paper.preconditioning.stretch_cycles == 8
    assert paper.preconditioning.pressure_max == pytest.approx(10.666e3, rel=1e-3)  # 80 mmHg = 10.7 kPa
    assert paper.preconditioning.stretch_max == 1.4
    multi = load_protocol(EXAMPLES / "multi-stretch-protocol.toml", rig)
    assert [b.stretch for b in multi.blocks] == [1.0, 1.1, 1.2] and multi.n_steps == 20
    assert multi.steps[12] == (2, 1.2, 0.0)
    spec = load_specimen(EXAMPLES / "specimen.toml")
    assert (spec.radius, spec.length, spec.thickness) == pytest.approx((0.010, 0.035, 0.0013))
    assert len(rig.cameras) >= 4 and rig.pressure.mode == "controller" and rig.load_cell.measures == "wall"
    assert paper.text.startswith("# The seed paper")
    assert paper.calibration.views == 24 and "ChArUco" in paper.calibration.board


@pytest.mark.parametrize("unit,scale", [("mmHg", MMHG), ("kPa", 1e3), ("Pa", 1.0)])
def test_units_in_key_or_unit_key(unit, scale):
    a = parse_protocol(f"[[block]]\nstretch = 1.0\npressures_{unit} = [0, 10]\n")
    b = parse_protocol(f"[[block]]\nstretch = 1.0\nunit = \"{unit}\"\npressures = [0, 10]\n")
    assert a.blocks[0].pressures == b.blocks[0].pressures == pytest.approx((0.0, 10 * scale))


def test_test_table_expands_to_blocks():
    p = parse_protocol("[test]\nstretches = [1.1, 1.2, 1.3]\npressures_kPa = [0, 5]\n")
    assert [(b.stretch, b.pressures) for b in p.blocks] == [(1.1, (0.0, 5e3)), (1.2, (0.0, 5e3)), (1.3, (0.0, 5e3))]


BAD = [
    # (toml text, fragments the message must contain)
    (GOOD + "colour = 'red'\n", ["[[block]] #1", "unknown key", "colour"]),
    (GOOD.replace("dwell_s", "dwel_s"), ["[stability]", "unknown key", "dwel_s"]),
    (GOOD + "[extras]\na = 1\n", ["unknown key", "extras"]),
    (GOOD.replace("pressures_mmHg = [0, 50, 100]", "pressures_mmHg = []"), ["pressures_mmHg", "empty"]),
    ("[test]\nstretches = []\npressures_mmHg = [0]\n", ["[test].stretches", "empty"]),
    ("[protocol]\nname = 'x'\n", ["no test blocks"]),
    (GOOD.replace("stretch = 1.1", "stretch = 0"), ["[[block]] #1 .stretch", "impossible", "> 0"]),
    (GOOD.replace("stretch = 1.1", "stretch = -1.2"), ["[[block]] #1 .stretch", "impossible"]),
    (GOOD.replace("stretch = 1.1", "stretch = 0.9"), ["[[block]] #1 .stretch", "< 1"]),
    (GOOD.replace("stretch = 1.1", "stretch = 4.0"), ["[[block]] #1 .stretch", "<= 3"]),
    (GOOD.replace("stretch = 1.1", "stretch = '1.1'"), ["[[block]] #1 .stretch", "expected", "str"]),
    (GOOD.replace("pressure_cycles = 2", "pressure_cycles = 2.5"), ["[preconditioning].pressure_cycles",
                                                                    "integer", "2.5"]),
    (GOOD.replace("pressure_cycles = 2", "pressure_cycles = true"), ["pressure_cycles", "integer"]),
    (GOOD.replace("[0, 50, 100]", "[0, 'fifty', 100]"), ["pressures_mmHg[1]", "expected a number"]),
    (GOOD.replace("[0, 50, 100]", "[0, -5, 100]"), ["pressures_mmHg[1]", ">= 0"]),
    (GOOD.replace("band_mmHg = 1", "band_mmHg = 1\nband_kPa = 0.1"), ["band", "given twice"]),
    (GOOD.replace("band_mmHg = 1", "band = 1"), ["[stability].band", "no unit"]),
    (GOOD.replace("band_mmHg = 1", "band = 1\nunit = 'psi'"), ["[stability].unit", "psi"]),
    (GOOD.replace("stretch_max = 1.4", "stretch_max = 1.0"), ["[preconditioning].stretch_max", "> 1"]),
    (GOOD.replace("dwell_s = 0.5", "dwell_s = -1"), ["[stability].dwell_s", ">= 0"]),
    (GOOD + "[capture]\ncameras = []\n", ["[capture].cameras", "empty"]),
    (GOOD + "[calibration]\nviews = -2\n", ["[calibration].views", ">= 0"]),
    (GOOD + "[calibration]\nviews = 4\npattern = 'x'\n", ["[calibration]", "unknown key", "pattern"]),
    ("[[block]]\nstretch = 1.1\n", ["[[block]] #1 .pressures_mmHg", "missing"]),
    ("[[block\nstretch = 1\n", ["not valid TOML"]),
]


@pytest.mark.parametrize("text,fragments", BAD, ids=[f"bad{i}" for i in range(len(BAD))])
def test_protocol_validation_errors_name_file_and_key(text, fragments):
    with pytest.raises(ConfigError) as info:
        parse_protocol(text, source="p.toml")
    msg = str(info.value)
    assert msg.startswith("p.toml: "), msg
    for frag in fragments:
        assert frag in msg, (frag, msg)


def test_pressure_above_rig_safety_limit(rig, tmp_path):
    path = tmp_path / "hot.toml"
    path.write_text(GOOD.replace("[0, 50, 100]", "[0, 50, 250]"))
    with pytest.raises(ConfigError, match=r"hot.toml: block #1 .pressures: 250.0 mmHg is above the rig's safety "
                                          r"limit 200.0 mmHg \(sim-rig.toml: \[safety\]\)"):
        load_protocol(path, rig)
    path.write_text(GOOD.replace("pressure_max_mmHg = 80", "pressure_max_mmHg = 300"))
    with pytest.raises(ConfigError, match=r"\[preconditioning\].pressure_max: 300.0 mmHg is above"):
        load_protocol(path, rig)


def test_reference_capture_is_block_zero_and_limits_name_the_test_blocks(rig):
    p = parse_protocol(GOOD + "[reference]\ncapture = true\n")
    assert p.has_reference and p.steps[:2] == [(0, 1.0, 0.0), (1, 1.1, 0.0)] and p.n_steps == 4
    assert not parse_protocol(GOOD + "[reference]\ncapture = false\n").has_reference
    with pytest.raises(ConfigError, match=r"block #1 .pressures: 250.0 mmHg"):
        parse_protocol(GOOD.replace("100]", "250]") + "[reference]\ncapture = true\n", source="p.toml", rig=rig)
    with pytest.raises(ConfigError, match=r"\[reference\].capture: expected true/false"):
        parse_protocol(GOOD + "[reference]\ncapture = 1\n", source="p.toml")


def test_stretch_above_rig_limit_and_unknown_camera(rig):
    with pytest.raises(ConfigError, match=r"block #1 .stretch: 1.6 is above the rig's stretch limit 1.5"):
        parse_protocol(GOOD.replace("stretch = 1.1", "stretch = 1.6"), source="p.toml", rig=rig)
    with pytest.raises(ConfigError, match=r"\[capture\].cameras: camera 'camX' is not in the rig"):
        parse_protocol(GOOD + "[capture]\ncameras = ['camX']\n", source="p.toml", rig=rig)


def test_missing_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="nope.toml: cannot read file"):
        load_protocol(tmp_path / "nope.toml")


RIG = (EXAMPLES / "sim-rig.toml").read_text()


@pytest.mark.parametrize("text,fragments", [
    (RIG.replace('measures = "wall"', 'measures = "both"'), ["[load_cell].measures", "'wall' or 'total'", "both"]),
    (RIG.replace('mode = "controller"', 'mode = "auto"'), ["[pressure].mode", "auto"]),
    (RIG.replace('backend = "sim"', 'backend = "gopro"', 1), ["[[camera]] #1 .backend", "gopro"]),
    (RIG.replace('name = "cam1"', 'name = "cam0"'), ["[[camera]] #2 .name", "duplicate"]),
    (RIG.replace("max_stretch = 1.5", "max_stretch = 1.5\nmax_temp = 3"), ["[safety]", "unknown key", "max_temp"]),
    (RIG.replace('port = "sim"\nmeasures', 'measures'), ["[load_cell].port", "missing"]),
    (RIG + '\n[simulation]\nmaterial = "rubber"\n', ["[simulation].material", "'fung'", "rubber"]),
    (RIG + '\n[simulation]\nn_markers = 3\n', ["[simulation].n_markers"]),
    (RIG + '\n[simulation]\nclamped = "yes"\n', ["[simulation].clamped"]),
])
def test_rig_validation_errors(text, fragments):
    with pytest.raises(ConfigError) as info:
        parse_rig(text, source="r.toml")
    for frag in fragments:
        assert frag in str(info.value), (frag, str(info.value))


@pytest.mark.parametrize("text,fragment", [
    ("[specimen]\nid = 'a'\nradius_mm = 10\nlength_mm = 35\n", "[specimen].thickness_mm: missing"),
    ("[specimen]\nid = 'a'\nradius_mm = 0\nlength_mm = 35\nthickness_mm = 1\n", "[specimen].radius_mm: expected a number > 0"),
    ("[specimen]\nid = 'a'\nradius_mm = 1\nlength_mm = 35\nthickness_mm = 2\n", "[specimen].thickness_mm: wall thickness"),
    ("[specimen]\nid = ''\nradius_mm = 1\nlength_mm = 35\nthickness_mm = 0.2\n", "[specimen].id"),
    ("[specimen]\nid = 'a'\nradius = 1\nradius_mm = 1\nlength_mm = 35\nthickness_mm = 0.2\n", "unknown key"),
])
def test_specimen_validation_errors(text, fragment):
    with pytest.raises(ConfigError, match="^s.toml: ") as info:
        parse_specimen(text, source="s.toml")
    assert fragment in str(info.value)


def test_simulation_table_defaults_and_values():
    assert parse_rig(RIG, source="r.toml").simulation.n_markers == 300
    sim = parse_rig(RIG + '\n[simulation]\nmaterial = "hgo"\nn_markers = 120\nclamped = true\nseed = 4\n',
                    source="r.toml").simulation
    assert (sim.material, sim.n_markers, sim.clamped, sim.seed) == ("hgo", 120, True, 4)


def test_built_in_sim_rig_is_the_example_file():
    """``vfmlab run --sim`` without --rig uses the packaged copy of examples/sim-rig.toml."""
    from vfmlab.operate import DEFAULT_SIM_RIG

    assert DEFAULT_SIM_RIG == RIG
    assert parse_rig(DEFAULT_SIM_RIG, source="<built-in>").simulated
