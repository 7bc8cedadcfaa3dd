"""``vfmlab.parallel.fork_map``: the builtin ``map``'s results and exceptions, computed on several processes;
and the bootstrap of ``vfmlab identify`` run through it gives the very same uncertainty."""

import os

import numpy as np
import pytest

from vfmlab.parallel import fork_map


def _square_and_pid(x):
    return x * x, os.getpid()


def test_fork_map_returns_map_in_order(tmp_path):
    """Results, not scheduling: which process computes which item depends on the machine's load."""
    out = fork_map(_square_and_pid, range(7), workers=2)
    assert [v for v, _ in out] == [x * x for x in range(7)]
    offset = np.arange(3.0)  # a closure over data: not pickled, the forked workers inherit it
    np.testing.assert_array_equal(np.array(fork_map(lambda x: offset * x, range(5), workers=2)),
                                  np.arange(5.0)[:, None] * offset)
    assert fork_map(_square_and_pid, [], workers=2) == []
    assert fork_map(lambda x: fork_map(abs, [-x, x], workers=2), [1, 2], workers=2) == [[1, 1], [2, 2]]  # nested


def _fails_on_three(x):
    if x == 3:
        raise ValueError("item 3 is bad")
    return x


def test_an_exception_in_a_childs_share_surfaces_as_in_map():
    with pytest.raises(ValueError, match="item 3 is bad"):  # whichever process took item 3
        fork_map(_fails_on_three, range(6), workers=2)
    assert fork_map(_fails_on_three, [0, 1, 2], workers=2) == [0, 1, 2]


def _killed_in_child(x, parent=os.getpid()):
    if os.getpid() != parent:
        os._exit(9)  # the worker dies (killed, out of memory): its share is recomputed here
    return -x


def test_a_worker_that_dies_has_its_share_recomputed():
    assert fork_map(_killed_in_child, range(5), workers=2) == [0, -1, -2, -3, -4]


def test_bootstrap_through_fork_map_is_identical():
    from identification.optimize import identify
    from identification.uncertainty import bootstrap
    from rig_sim.homogeneous_tube import PAPER, homogeneous

    pos, p, f = homogeneous("fung", PAPER["fung"], [1.0, 1.1, 1.2, 1.3], [1.0, 1.1, 1.1, 1.1], n=120, seed=0)
    noisy = pos + np.random.default_rng(1).normal(0.0, 0.02e-3, pos.shape)
    result = identify(noisy, p, f, thickness=1.3e-3, model="fung", ends="free", smoothing="auto", wall="membrane")
    serial = bootstrap(result.data, result, noisy[list(result.steps)] if result.steps else noisy, n_replicates=6)
    forked = bootstrap(result.data, result, noisy[list(result.steps)] if result.steps else noisy, n_replicates=6,
                       map_replicates=lambda fn, items: fork_map(fn, items, workers=2))
    np.testing.assert_array_equal(forked.replicates, serial.replicates)
    assert forked.stderr == serial.stderr and forked.interval == serial.interval
