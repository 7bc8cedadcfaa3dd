"""Reconstruction: camera calibration, marker detection, correspondence, triangulation, tracking.

Pure functions over arrays and images: no files, ports or clocks.
"""

from reconstruction.calibration import CalibrationError, CalibrationResult, calibrate_cameras, calibrate_from_detections
from reconstruction.calibration_body import calibrate_from_body, match_body_points, refine_dot_centres, select_body_model
from reconstruction.calibration_errors import CalibrationFileError, CameraError
from reconstruction.calibration_select import DistortionChoice, choose_distortion, distortion_problem
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
from reconstruction.camera_checks import fraction_in_view, validate_camera
from reconstruction.cameras import Camera, project_points, rotation_matrix
from reconstruction.refraction import Window
from reconstruction.correspondence import Correspondence, CylinderPrior, match_views
from reconstruction.detection import REJECT_REASONS, Detections, detect_markers
from reconstruction.image_quality import ImageQuality, image_quality, markers_in_views
from reconstruction.particles import detect_particles
from reconstruction.pipeline import detect_step, reconstruct_series
from reconstruction.series_tracking import SeriesResult, SeriesTracker, track_series
from reconstruction.settings import ReconstructionSettings
from reconstruction.step_points import StepPoints, points_from_detections, reconstruct_step
from reconstruction.surface import CylinderFit, fit_cylinder, marker_surface_points, specimen_frame, surface_normals
from reconstruction.targets import BoardDetection, BoardSpec, TargetError, detect_board, detect_boards
from reconstruction.tracking import StepMatch, match_step
from reconstruction.triangulation import Triangulation, triangulate
from reconstruction.volume_selfcal import body_rms, common_view_box, self_calibrate

__all__ = [
    "CalibrationError", "CalibrationResult", "calibrate_cameras", "calibrate_from_detections",
    "DistortionChoice", "choose_distortion", "distortion_problem",
    "CalibrationFileError", "cameras_from_arrays", "cameras_from_toml", "cameras_from_yaml", "cameras_to_arrays",
    "cameras_to_toml", "cameras_to_yaml", "camera_from_openptv", "camera_to_openptv", "parse_ptv_par", "Window",
    "BoardDetection", "BoardSpec", "TargetError", "detect_board", "detect_boards",
    "Camera", "CameraError", "project_points", "rotation_matrix", "validate_camera", "fraction_in_view",
    "Correspondence", "CylinderPrior", "match_views",
    "REJECT_REASONS", "Detections", "detect_markers", "detect_particles", "ImageQuality", "image_quality",
    "markers_in_views",
    "ReconstructionSettings", "SeriesResult", "SeriesTracker", "StepPoints", "detect_step", "points_from_detections",
    "reconstruct_series", "reconstruct_step", "track_series",
    "calibrate_from_body", "match_body_points", "refine_dot_centres", "select_body_model",
    "body_rms", "common_view_box", "self_calibrate",
    "CylinderFit", "fit_cylinder", "marker_surface_points", "specimen_frame", "surface_normals",
    "StepMatch", "match_step",
    "Triangulation", "triangulate",
]
