"""Data from other labs' DIC and particle-tracking software, read into vfmlab's conventions (SI, OpenCV pixels, NaN
for missing).

- :func:`read_duodic_points`: DuoDIC ``DIC3Dstereo.mat`` / MultiDIC ``DIC3DPPresults.mat`` (3-D points per step);
- :func:`read_duodic_2d_pairs`: DuoDIC ``DIC2DpairResults.mat`` (each camera's tracked pixels, to triangulate);
- :func:`read_vic3d_csv`: VIC-3D CSV exports (one file per step);
- :func:`read_point_table`: any CSV / NPZ of points with a column mapping;
- :func:`read_matlab_calibration_session`: a MATLAB stereo calibration session (cameras + board corners);
- :func:`read_myptv_cal_points`, :func:`read_myptv_target`: MyPTV's calibration dots (image <-> target pairs);
- :func:`read_myptv_blobs`, :func:`read_myptv_particles`: MyPTV's particle images (per camera) and matched particles.

Every reader raises :class:`DICImportError` (a ValueError) naming the file and what is wrong.
See ``docs/guide/other-labs-dic.md``.
"""

from .matlab import StereoPixelTracks, read_duodic_2d_pairs, read_duodic_points, read_mat_struct
from .matlab_calibration import MatlabStereoCalibration, read_matlab_calibration_session, stereo_calibration_from_matlab
from .myptv import (
    MyPTVParticles,
    parse_myptv_blobs,
    parse_myptv_cal_points,
    parse_myptv_particles,
    read_myptv_blobs,
    read_myptv_cal_points,
    read_myptv_particles,
    read_myptv_target,
)
from .result import DICImportError, DICPoints
from .tables import parse_column_map, parse_vic3d_csv, points_from_columns, read_point_table, read_vic3d_csv

__all__ = [
    "DICImportError", "DICPoints", "StereoPixelTracks", "MatlabStereoCalibration",
    "read_duodic_points", "read_duodic_2d_pairs", "read_mat_struct",
    "read_vic3d_csv", "parse_vic3d_csv", "read_point_table", "parse_column_map", "points_from_columns",
    "read_matlab_calibration_session", "stereo_calibration_from_matlab",
    "parse_myptv_cal_points", "read_myptv_cal_points", "read_myptv_target",
    "MyPTVParticles", "parse_myptv_blobs", "read_myptv_blobs", "parse_myptv_particles", "read_myptv_particles",
]
