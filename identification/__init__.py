"""Identification: surface mesh, membrane kinematics, constitutive models and the Virtual Fields Method.

Pure functions over arrays: no files, ports or clocks. Units SI (m, Pa, N, rad).

Typical use::

    from identification import identify
    result = identify(positions, pressure, axial_force, thickness=1.3e-3, model="fung")
    result.parameters, result.stderr, result.flags
"""

from .curves import StressStrainCurves, laplace_curves
from .errors import DegenerateDataError, IdentificationError, MeshError
from .kinematics import Kinematics, align_steps, membrane_kinematics
from .mesh import Axis, SurfaceMesh, build_mesh, fit_axis, to_cylindrical, to_trimesh
from .models import Model, available_models, cauchy_stress, get_model, pk2_stress, strain_energy
from .fit import PAPER_INITIAL_GUESS, identify_prepared
from .optimize import identify, identify_noise_weighted
from .result import IdentificationResult
from .vfm import PrepareSettings, VFMData, internal_virtual_work, prepare
from .virtual_fields import VirtualFields, paper_fields

__all__ = [
    "Axis", "DegenerateDataError", "IdentificationError", "IdentificationResult", "Kinematics", "MeshError",
    "Model", "PAPER_INITIAL_GUESS", "PrepareSettings", "StressStrainCurves", "SurfaceMesh", "VFMData", "VirtualFields",
    "align_steps", "available_models", "build_mesh", "cauchy_stress", "fit_axis", "get_model", "identify",
    "identify_noise_weighted", "identify_prepared", "internal_virtual_work", "laplace_curves", "membrane_kinematics", "paper_fields",
    "pk2_stress", "prepare", "strain_energy", "to_cylindrical", "to_trimesh",
]
