"""Reconstruction: camera calibration, marker detection, correspondence, triangulation, tracking.

Pure functions over arrays and images: no files, ports or clocks.
"""

from reconstruction.calibration import CalibrationError, CalibrationResult, calibrate_cameras, calibrate_from_detections
from reconstruction.calibration_errors import CalibrationFileError
from reconstruction.calibration_io import (
    camera_from_openptv,
    camera_to_openptv,
    cameras_from_arrays,
    cameras_from_toml,
    cameras_from_yaml,
    cameras_to_arrays,
    cameras_to_toml,
    cameras_to_yaml,
    parse_ptv_par,
)
from reconstruction.cameras import Camera, project_points, rotation_matrix
from reconstruction.refraction import Window
from reconstruction.correspondence import Correspondence, CylinderPrior, match_views
from reconstruction.detection import REJECT_REASONS, Detections, detect_markers
from reconstruction.pipeline import (
    ReconstructionSettings,
    SeriesResult,
    StepPoints,
    points_from_detections,
    reconstruct_series,
    reconstruct_step,
    track_series,
)
from reconstruction.surface import CylinderFit, fit_cylinder, marker_surface_points, specimen_frame, surface_normals
from reconstruction.targets import BoardDetection, BoardSpec, TargetError, detect_board, detect_boards
from reconstruction.tracking import StepMatch, match_step
from reconstruction.triangulation import Triangulation, triangulate

__all__ = [
    "CalibrationError", "CalibrationResult", "calibrate_cameras", "calibrate_from_detections",
    "CalibrationFileError", "cameras_from_arrays", "cameras_from_toml", "cameras_from_yaml", "cameras_to_arrays",
    "cameras_to_toml", "cameras_to_yaml", "camera_from_openptv", "camera_to_openptv", "parse_ptv_par", "Window",
    "BoardDetection", "BoardSpec", "TargetError", "detect_board", "detect_boards",
    "Camera", "project_points", "rotation_matrix",
    "Correspondence", "CylinderPrior", "match_views",
    "REJECT_REASONS", "Detections", "detect_markers",
    "ReconstructionSettings", "SeriesResult", "StepPoints", "points_from_detections", "reconstruct_series",
    "reconstruct_step", "track_series",
    "CylinderFit", "fit_cylinder", "marker_surface_points", "specimen_frame", "surface_normals",
    "StepMatch", "match_step",
    "Triangulation", "triangulate",
]
