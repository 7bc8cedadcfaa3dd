"""Simulated rig: exact artery mechanics, instrument simulators over pseudo-terminals, rendered cameras.

Implements the interfaces of the stage packages; the stage packages never import it.
"""

from rig_sim.instruments import SimulatedRig
