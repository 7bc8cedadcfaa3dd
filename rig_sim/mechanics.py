"""Public face of the simulator's exact artery mechanics (ground truth for tests and the demo).

    from rig_sim.mechanics import simulate_test, PAPER_PARAMETERS, PAPER_PRESSURES
    sim = simulate_test("fung", PAPER_PARAMETERS["fung"], stretches=(1.1, 1.2), clamped=True)
    sim.positions      # (n_steps, n_markers, 3) m, world frame of the rig
    sim.pressure, sim.axial_force, sim.stretch

See docs/validation/mechanics.md for equations and conventions.
"""

from .clamped import ClampedSolution, solve_clamped
from .markers import min_marker_spacing, place_markers
from .materials import (
    MODELS,
    PAPER_PARAMETERS,
    MembraneLaw,
    ModelError,
    check_params,
    get_law,
    membrane_cauchy,
    membrane_pk2,
    strain_energy,
)
from .simulate import MMHG, PAPER_PRESSURES, SimulatedTest, simulate_test
from .tube import (
    MechanicsError,
    MembraneState,
    ThickState,
    inflate_membrane,
    inflate_thick,
    membrane_pressure,
    membrane_wall_force,
    midwall_membrane_state,
    thick_tube_state,
    transducer_force,
    wall_force_from_transducer,
)

__all__ = [
    "ClampedSolution", "solve_clamped", "MMHG", "MODELS", "PAPER_PARAMETERS", "PAPER_PRESSURES", "MechanicsError", "MembraneLaw", "MembraneState",
    "ModelError", "SimulatedTest", "ThickState", "check_params", "get_law", "inflate_membrane", "inflate_thick",
    "membrane_cauchy", "membrane_pk2", "membrane_pressure", "membrane_wall_force", "midwall_membrane_state",
    "min_marker_spacing", "place_markers", "simulate_test", "strain_energy", "thick_tube_state", "transducer_force",
    "wall_force_from_transducer",
]
