"""Identification: surface mesh, membrane kinematics, constitutive models and the Virtual Fields Method.

Pure functions over arrays: no files, ports or clocks. Units SI (m, Pa, N, rad).

Typical use::

    from identification import identify
    result = identify(positions, pressure, axial_force, thickness=1.3e-3, model="fung")
    result.parameters, result.stderr, result.flags
    result.verdict, result.parameter_verdicts, result.verdict_reasons   # "trusted" | "doubtful", and why

The defaults (``DEFAULTS``: thick wall unless the data say membrane, ends decided by the data, smoothing
chosen from the data, bootstrap intervals) are ``vfmlab identify``'s: the same arrays give the same numbers.
"""

from .checks import check_setup
from . import defaults as defaults  # bound on the package even when vfmlab.stages.settings loaded it first
from .defaults import DEFAULTS, IdentifyDefaults
from .curves import StressStrainCurves, laplace_curves
from .efficient import EfficientSettings
from .design import PAPER_TABLE1, DesignResult, DesignSpecimen, Suggestion, design, suggest_steps
from .errors import DegenerateDataError, IdentificationError, MeshError
from .fit import PAPER_INITIAL_GUESS, identify_prepared
from .information import BoundResult, TubeExperiment, cramer_rao_bound
from .kinematics import Kinematics, align_steps, membrane_kinematics
from .mesh import Axis, SurfaceMesh, build_mesh, describe_dropped, fit_axis, to_cylindrical, to_trimesh
from .models import Model, available_models, cauchy_stress, get_model, pk2_stress, strain_energy
from .judged import identify
from .optimize import identify_noise_weighted
from .regional import RegionalData, RegionalResult, identify_regional, prepare_regional
from .regional_uncertainty import choose_bands, with_bootstrap
from .tube_fit import TubeFitResult, TubeObservations, fit_tube, simulate_observations
from .tube_forward import MeasurementNoise, TubeGeometry, TubeSteps, uniform_markers
from .result import IdentificationResult
from .uncertainty import Uncertainty, bootstrap
from .vfm import PrepareSettings, VFMData, internal_virtual_work, prepare
from .virtual_fields import VirtualFields, paper_fields

__all__ = [
    "DEFAULTS", "IdentifyDefaults",
    "Axis", "DegenerateDataError", "IdentificationError", "IdentificationResult", "Kinematics", "MeshError",
    "Model", "PAPER_INITIAL_GUESS", "PrepareSettings", "RegionalData", "RegionalResult", "StressStrainCurves",
    "SurfaceMesh", "Uncertainty", "VFMData", "VirtualFields", "align_steps", "available_models", "bootstrap",
    "build_mesh", "cauchy_stress", "check_setup", "choose_bands", "describe_dropped", "fit_axis", "get_model",
    "identify", "identify_noise_weighted", "identify_prepared", "identify_regional", "internal_virtual_work",
    "laplace_curves", "membrane_kinematics", "paper_fields", "pk2_stress", "prepare", "prepare_regional",
    "strain_energy", "to_cylindrical", "to_trimesh", "with_bootstrap",
    # the Cramér-Rao bound of a homogeneous tube, its maximum-likelihood fit, and test design (issue 24)
    "BoundResult", "DesignResult", "DesignSpecimen", "MeasurementNoise", "PAPER_TABLE1", "Suggestion",
    "TubeExperiment", "TubeFitResult", "TubeGeometry", "TubeObservations", "TubeSteps", "cramer_rao_bound", "design",
    "fit_tube", "simulate_observations", "suggest_steps", "uniform_markers",
    # generalised least squares over the gaps' full covariance (weighting="efficient", issue 24)
    "EfficientSettings",
]
