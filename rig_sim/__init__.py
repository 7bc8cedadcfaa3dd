"""Simulated rig: exact artery mechanics, instrument simulators over pseudo-terminals, rendered cameras.

Implements the interfaces of the stage packages; the stage packages never import it.
"""

from .cameras import camera_ring, look_at
from .imaging import render_simulated_steps, specimen_frame
from .instruments import SimulatedRig
from .render import MarkerTruth, RenderedFrame, SceneStyle, render_markers
from .sensor import SensorModel, expose
from .specimen_geometry import MarkerLayout, SurfaceOfRevolution, deform_cylinder, random_marker_layout

__all__ = [
    "SimulatedRig",
    "camera_ring",
    "look_at",
    "MarkerTruth",
    "RenderedFrame",
    "SceneStyle",
    "render_markers",
    "render_simulated_steps",
    "specimen_frame",
    "SensorModel",
    "expose",
    "MarkerLayout",
    "SurfaceOfRevolution",
    "deform_cylinder",
    "random_marker_layout",
]
