"""Render a simulated test (``rig_sim.simulate.SimulatedTest``) step by step in the camera ring."""

from __future__ import annotations

import numpy as np

from reconstruction import Camera

from .render import RenderedFrame, render_markers
from .specimen_geometry import SurfaceOfRevolution

__all__ = ["specimen_frame", "render_simulated_steps"]


def specimen_frame(sim, step: int) -> tuple[np.ndarray, np.ndarray, SurfaceOfRevolution]:
    """Exact marker wall points ``(n_markers, 3)``, outward normals and the deformed profile of one step.

    ``sim`` is a :class:`rig_sim.simulate.SimulatedTest` (noise-free positions are used).
    """
    pts = sim.surface(step, sim.marker_theta, sim.marker_Z)
    nrm = sim.normal(step, sim.marker_theta, sim.marker_Z)
    return pts, nrm, SurfaceOfRevolution(sim.profile_z[step], sim.profile_r[step])


def render_simulated_steps(cameras: list[Camera], sim, steps=None, *, seed: int = 0, **kwargs) -> list[RenderedFrame]:
    """Render ``steps`` (default all) of a simulated test; ``kwargs`` go to :func:`render_markers`.

    Each step gets its own noise seed (``seed + step``).
    """
    steps = range(sim.n_steps) if steps is None else steps
    frames = []
    for s in steps:
        pts, nrm, prof = specimen_frame(sim, s)
        frames.append(render_markers(cameras, pts, nrm, prof, seed=seed + int(s), **kwargs))
    return frames
