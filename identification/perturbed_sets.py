"""The perturbed preparations of ``efficient.GapCovariance`` as independent jobs for an injected map (issue 24).

The markers' part of the gaps' covariance needs the data prepared once per non-rigid smoothing basis function
with the loaded steps' markers moved along it, and once per function with the reference step's moved
(``gap_jacobian``). Each preparation is independent of the others, so they are cut into jobs that any
``map(fn, jobs)`` may compute: the builtin map (default; this package never forks), or one that spreads them over
the machine's cores (``vfmlab.parallel.fork_map``, what the command line passes) with the same results. A job
returns only what the covariance reads of its data sets (the right Cauchy-Green components ``c`` and the work
densities, the external work): a few hundred kB, cheap to send back from a worker.

- Loaded steps: a step's gaps depend on its own markers and the reference's only, so the moved loaded steps of
  many basis functions are prepared together as the steps of one data set (``Reprepare.stacked``: one vectorised
  pass instead of one ``prepare`` per function), at most ``STACKED_STEPS`` steps a job.
- Reference step: a moved reference brings its own re-measured mesh, so each is its own preparation,
  ``REFERENCE_SETS`` of them a job.

Units SI; shapes in the docstrings.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .gap_jacobian import Reprepare
from .resimulation import remeasured_mesh
from .vfm import VFMData

__all__ = ["PerturbedSets", "concatenate_works", "perturbed_works", "set_works"]

#: Moved loaded steps prepared in one vectorised pass (a job): at most this many (bounds the memory: a thick wall
#: of 500 triangles takes ~0.4 MB a step; 96 add ~30 MB to the peak of 300 MB, 400 added 150 MB).
STACKED_STEPS = 96

#: Moved references prepared by one job.
REFERENCE_SETS = 8

#: What a job returns: c (n, n_points, 3), work_density (n_fields, n, n_points, 3), evw (n_fields, n) and the
#: clamped ends' strip force (n,) N (``VFMData.strip_force``: the other end condition's external work), n steps.
Works = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


class PerturbedSets:
    """A job's computation: ``("loaded", moves)`` with moves
    (n_sets, n_steps - 1, n_markers, 3) m added to the loaded steps, or ``("reference", moves)`` with moves
    (n_sets, n_markers, 3) m added to the reference step (on its re-measured mesh) (moves the lean preparation does
    not stack: a tuple of n_sets arrays). Returns the ``Works`` of the moved steps of every set, set-major:
    n_sets (n_steps - 1) loaded steps, or n_sets n_steps steps."""

    def __init__(self, prep: Reprepare, aligned: np.ndarray, kept: list | None = None):
        self.prep, self.aligned, self.kept = prep, aligned, kept

    def __call__(self, job: tuple[str, np.ndarray | tuple[np.ndarray, ...]]) -> Works:
        kind, moves = job
        if kind == "loaded" and self.prep.lean:
            d = self.prep.stacked(self.aligned[1:][None] + moves)
            return d.c[1:], d.work_density[:, 1:], d.evw[:, 1:], _strip(d)[1:]
        sets, parts = [], []
        for move in moves:
            pos = self.aligned.copy()
            if kind == "loaded":
                pos[1:] += move
                mesh = self.prep.data.mesh
            else:
                pos[0] += move
                mesh = remeasured_mesh(self.prep.data.mesh, pos[0])
            d, kept = (self.prep(pos, m=mesh), None) if self.prep.lean else self.prep.prepared(
                pos, self.prep.data.pressure, self.prep.data.axial_force, mesh)
            sets.append(set_works(d, kind))
            parts.append(kept)
        if self.kept is not None:
            self.kept.append((kind, parts))
        return concatenate_works(sets)


def set_works(d: VFMData, kind: str) -> Works:
    """What the gaps read of a moved set ``d`` (``Works``): its loaded steps (``kind`` "loaded") or every step."""
    first = 1 if kind == "loaded" else 0
    return d.c[first:], d.work_density[:, first:], d.evw[:, first:], _strip(d)[first:]


def _strip(d: VFMData) -> np.ndarray:
    return np.zeros(d.evw.shape[1]) if d.strip_force is None else d.strip_force


def concatenate_works(sets: list[Works]) -> Works:
    c, wd, evw, strip = zip(*sets)
    return np.concatenate(c), np.concatenate(wd, axis=1), np.concatenate(evw, axis=1), np.concatenate(strip)


def perturbed_works(prep: Reprepare, aligned: np.ndarray, loaded: list[np.ndarray],
                    reference: list[np.ndarray], kept: list | None = None) -> tuple[list[VFMData], list[VFMData]]:
    """The data sets of the loaded steps moved by each of ``loaded`` ((n_steps - 1, n_markers, 3) m each) and of
    the reference moved by each of ``reference`` ((n_markers, 3) m each), one ``prep.data``-like data set per
    job, whose steps are the moved steps of its sets, set-major (n_sets (n_steps - 1) loaded, n_sets n_steps
    reference steps; only ``c``, ``work_density``, ``evw`` and ``strip_force`` are theirs: what the gaps read), in
    the order of the moves. ``kept``: a list to which every job appends (its kind, its sets' ``vfm.DenseParts``:
    a dense cloud's smoothed states, None on the lean or full path), in the order of the jobs."""
    per = max(1, STACKED_STEPS // max(len(aligned) - 1, 1))
    # only the lean preparation takes a job's sets as one array; the others prepare them one by one (not stacked:
    # a dense cloud's copy is ~0.35 s at 50,000 points)
    together = np.stack if prep.lean else tuple
    jobs = [("loaded", together(loaded[i:i + per])) for i in range(0, len(loaded), per)]
    n_loaded_jobs = len(jobs)
    jobs += [("reference", together(reference[i:i + REFERENCE_SETS]))
             for i in range(0, len(reference), REFERENCE_SETS)]
    works = [dataclasses.replace(prep.data, c=c, work_density=wd, evw=evw, strip_force=strip)
             for c, wd, evw, strip in map(PerturbedSets(prep, aligned, kept), jobs)]
    return works[:n_loaded_jobs], works[n_loaded_jobs:]
