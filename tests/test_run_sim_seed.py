"""``vfmlab run --sim --sim-seed N``: the simulated rig's seed, so that a simulated test can be repeated with other
noise (coverage on rendered rigs, docs/validation/identification.md "Coverage")."""

import numpy as np
import pytest

from acquisition.protocol import MMHG, parse_protocol, parse_rig, parse_specimen
from vfmlab.cli import main
from vfmlab.operate import load_rig_config as _load_rig
from vfmlab.simrig import SimScene

PROTOCOL = """
[protocol]
name = "one step"
[test]
stretches = [1.1]
pressures_mmHg = [0, 100]
"""
SPECIMEN = "[specimen]\nid = 's'\nradius_mm = 10.0\nlength_mm = 35.0\nthickness_mm = 1.3\n"


def test_sim_seed_replaces_the_rig_seed_and_is_recorded_in_the_rig_text():
    default = _load_rig(None, True)
    rig = _load_rig(None, True, 7)
    assert default.simulation.seed == 0 and rig.simulation.seed == 7
    # the session stores rig.text; resume re-parses it and must get the same simulated rig back
    again = parse_rig(rig.text, text=rig.text)
    assert again.simulation == rig.simulation
    assert again.cameras == default.cameras and again.safety == default.safety
    assert again.load_cell == default.load_cell and again.pressure == default.pressure


def _scene(seed):
    rig = _load_rig(None, True, seed)
    return SimScene(parse_specimen(SPECIMEN), parse_protocol(PROTOCOL), ["cam0", "cam1"], (160, 120),
                    rig.simulation.n_markers, rig.simulation.seed)


def test_same_seed_same_images_other_seed_other_noise():
    a, b, c = _scene(3), _scene(3), _scene(4)
    ia, ib, ic = (s.images(100 * MMHG, 1.1) for s in (a, b, c))
    for x, y, z in zip(ia, ib, ic):
        assert np.array_equal(x, y)
        assert not np.array_equal(x, z)
    pa, pc = a.markers(100 * MMHG, 1.1)[0], c.markers(100 * MMHG, 1.1)[0]
    assert np.array_equal(pa, b.markers(100 * MMHG, 1.1)[0])
    assert np.abs(pa - pc).max() > 1e-3  # another marker layout, m
    # the mechanics do not depend on the seed: same wall force
    assert a.wall_force(100 * MMHG, 1.1) == c.wall_force(100 * MMHG, 1.1)


def test_sim_seed_without_sim_is_bad_input(tmp_path, capsys):
    (tmp_path / "p.toml").write_text(PROTOCOL)
    (tmp_path / "s.toml").write_text(SPECIMEN)
    rc = main(["run", str(tmp_path / "p.toml"), "--specimen", str(tmp_path / "s.toml"), "-o", str(tmp_path / "a.h5"),
               "--sim-seed", "3", "--yes"])
    assert rc == 2
    assert "--sim-seed" in capsys.readouterr().err
    assert not (tmp_path / "a.h5").exists()


def test_board_texture_survives_a_square_size_opencv_rejects():
    """--sim-seed 2 put the ring's magnification at 145 px per board square, which OpenCV 5's ChArUco
    generateImage rejects; the texture then uses the next size up."""
    from reconstruction.targets import BoardSpec
    from rig_sim.board import _board_texture

    spec = BoardSpec()
    tex, off, used = _board_texture(spec, 145 / spec.square_size)
    sq = round(used * spec.square_size)
    assert sq in (145, 146)
    n_cols, n_rows = (round(e / spec.square_size) for e in spec.extent)
    assert tex.shape == ((n_rows + 2) * sq, (n_cols + 2) * sq)  # one square of white margin around
    assert off == pytest.approx(-spec.square_size)
