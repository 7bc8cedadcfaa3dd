"""MATLAB stereo calibrations in (the Stereo Camera Calibrator's ``calibrationSession.mat``, as DuoDIC uses), in
vfmlab's conventions: the session's calibration arrays (``reconstruction.cameras_from_arrays`` makes the cameras)
and the detected board corners for a re-calibration.

The file is a MATLAB v5 file whose objects (``stereoParameters``, ``cameraParameters``, the board set) are MATLAB
class instances that scipy.io cannot decode; the ``mat-io`` package (import name ``matio``) can.

MATLAB -> OpenCV conventions (each checked by reprojecting the corners with MATLAB's board poses: the RMS equals
MATLAB's own, 0.572 / 0.602 px, ``tests/test_acq_dic_matlab.py``):

- ``IntrinsicMatrix`` is K transposed (``[fx 0 0; s fy 0; cx cy 1]``), and its principal point is 1-based:
  ``K = IntrinsicMatrix.T`` with 1 subtracted from cx, cy; board corners (``BoardPoints``) lose 1 too;
- distortion: ``RadialDistortion`` k1, k2 (, k3) and ``TangentialDistortion`` p1, p2 are OpenCV's coefficients;
- ``RotationVectors`` / ``TranslationVectors`` (board -> camera, one row per view) are OpenCV's rvec / tvec
  (MATLAB's rotation *matrices* are the transposes of OpenCV's, the rotation *vectors* are the same);
- ``RotationOfCamera2`` is R transposed: camera 2 is ``R = RotationOfCamera2.T``, ``t = TranslationOfCamera2``
  in camera 1's frame, which is the world frame here;
- ``ImageSize`` is [height, width]; lengths are in ``WorldUnits`` (mm), converted to metres.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .result import DICImportError, length_scale

__all__ = ["MatlabStereoCalibration", "read_matlab_calibration_session", "stereo_calibration_from_matlab"]


@dataclass(frozen=True)
class MatlabStereoCalibration:
    """A MATLAB stereo calibration in vfmlab's conventions (OpenCV pixels, world = camera 1, metres).

    Attributes
    ----------
    camera_arrays : dict
        ``camera_names``, ``K`` (2, 3, 3) px, ``dist`` (2, 5) (k1, k2, p1, p2, k3), ``rvec`` / ``tvec`` (2, 3)
        world -> camera (rad, m), ``image_size`` (2, 2) (width, height), ``rms`` (2,) MATLAB's reprojection RMS px:
        the layout of the session's calibration (``reconstruction.cameras_from_arrays``).
    board_points : ndarray, shape (2, n_views, n_corners, 2)
        Detected corners, OpenCV pixels; NaN where MATLAB did not detect a corner.
    object_points : ndarray, shape (n_corners, 3)
        The corners on the board (z = 0), m.
    board_rvecs, board_tvecs : ndarray, shape (n_views, 3)
        MATLAB's board -> camera 1 (= world) poses, rad and m.
    matlab_rms : ndarray, shape (2,)
        RMS of MATLAB's ``ReprojectionErrors`` per camera, px.
    square_size : float
        Board square, m.
    board_size : tuple (rows, cols)
        Squares of the board as MATLAB counts them (corners: (rows - 1) x (cols - 1)).
    """

    camera_arrays: dict
    board_points: np.ndarray
    object_points: np.ndarray
    board_rvecs: np.ndarray
    board_tvecs: np.ndarray
    matlab_rms: np.ndarray
    square_size: float
    board_size: tuple[int, int]


def _props(obj) -> dict:
    """Properties of a mat-io MATLAB object: the saved struct under ``any`` when the class saved one."""
    props = getattr(obj, "properties", obj)
    inner = props.get("any") if isinstance(props, dict) else None
    if isinstance(inner, np.ndarray) and inner.dtype.names:
        return {k: _one(inner[k].flat[0]) if inner[k].dtype == object else inner[k] for k in inner.dtype.names}
    return props


def _one(value):
    if isinstance(value, np.ndarray) and value.dtype == object and value.size == 1:
        return value.flat[0]
    return value


def _camera_part(params: dict, where: str) -> dict:
    """K, dist, image size (w, h), board poses, RMS and unit of one MATLAB ``cameraParameters`` (properties)."""
    try:
        K = np.asarray(params["IntrinsicMatrix"], float).T.copy()
        radial = np.asarray(params["RadialDistortion"], float).ravel()
        tangential = np.asarray(params["TangentialDistortion"], float).ravel()
        h, w = (int(v) for v in np.asarray(params["ImageSize"]).ravel())
        errors = np.asarray(params["ReprojectionErrors"], float)
        unit = str(np.asarray(params["WorldUnits"]).ravel()[0])
        rv = np.asarray(params["RotationVectors"], float)
        tv = np.asarray(params["TranslationVectors"], float)
    except (KeyError, ValueError, TypeError) as exc:
        raise DICImportError(f"{where}: cameraParameters incomplete ({exc})") from None
    K[0, 2] -= 1.0
    K[1, 2] -= 1.0
    dist = np.zeros(5)
    dist[:2] = radial[:2]
    dist[4] = radial[2] if radial.size > 2 else 0.0
    dist[2:4] = tangential[:2] if tangential.size >= 2 else 0.0
    rms = float(np.sqrt(np.nanmean(np.sum(errors**2, axis=1))))
    return dict(K=K, dist=dist, size=(w, h), rms=rms, unit=unit, rvecs=rv, tvecs=tv)


def stereo_calibration_from_matlab(stereo: dict, board: dict, where: str = "calibration") -> MatlabStereoCalibration:
    """Pure conversion: MATLAB ``stereoParameters`` properties (``CameraParameters1/2`` as property dicts,
    ``RotationOfCamera2``, ``TranslationOfCamera2``) and the board set's (``BoardPoints`` (n_corners, 2, n_views,
    2 cameras), ``WorldPoints`` (n_corners, 2), ``SquareSize``, ``BoardSize``) -> :class:`MatlabStereoCalibration`."""
    c1 = _camera_part(stereo["CameraParameters1"], f"{where}: CameraParameters1")
    c2 = _camera_part(stereo["CameraParameters2"], f"{where}: CameraParameters2")
    scale = length_scale(c1["unit"], where)
    R2 = np.asarray(stereo["RotationOfCamera2"], float).T
    t2 = np.asarray(stereo["TranslationOfCamera2"], float).ravel() * scale
    import cv2

    rvec2 = cv2.Rodrigues(R2)[0].ravel()
    arrays = {
        "camera_names": np.array(["cam1", "cam2"], dtype=object),
        "K": np.stack([c1["K"], c2["K"]]),
        "dist": np.stack([c1["dist"], c2["dist"]]),
        "rvec": np.stack([np.zeros(3), rvec2]),
        "tvec": np.stack([np.zeros(3), t2]),
        "image_size": np.array([c1["size"], c2["size"]], dtype=np.int64),
        "rms": np.array([c1["rms"], c2["rms"]]),
    }
    bp = np.asarray(board["BoardPoints"], float)
    if bp.ndim != 4 or bp.shape[1] != 2 or bp.shape[3] != 2:
        raise DICImportError(f"{where}: BoardPoints must have shape (n_corners, 2, n_views, 2); got {bp.shape}")
    corners = np.transpose(bp, (3, 2, 0, 1)) - 1.0
    wp = np.asarray(board["WorldPoints"], float)
    obj = np.c_[wp, np.zeros(len(wp))] * scale
    return MatlabStereoCalibration(
        camera_arrays=arrays, board_points=corners, object_points=obj,
        board_rvecs=np.asarray(c1["rvecs"], float), board_tvecs=np.asarray(c1["tvecs"], float) * scale,
        matlab_rms=arrays["rms"].copy(), square_size=float(np.asarray(board["SquareSize"]).ravel()[0]) * scale,
        board_size=tuple(int(v) for v in np.asarray(board["BoardSize"]).ravel()[:2]))


def read_matlab_calibration_session(path) -> MatlabStereoCalibration:
    """Read a MATLAB Stereo Camera Calibrator session (``calibrationSession.mat``, DuoDIC's calibration output).

    Needs the ``mat-io`` package; DICImportError naming the file when the file is not such a session.
    """
    path = Path(path)
    if not path.is_file():
        raise DICImportError(f"{path}: no such file")
    try:
        with warnings.catch_warnings():  # mat-io imports pandas, whose import warns about its own options
            warnings.simplefilter("ignore")
            import matio
    except ImportError:
        raise DICImportError(f"{path}: reading MATLAB calibration sessions needs the 'mat-io' package "
                             f"(pip install mat-io)") from None
    try:
        data = matio.load_from_mat(str(path))
    except Exception as exc:  # mat-io raises assorted types on foreign files
        raise DICImportError(f"{path}: not a readable MATLAB file ({type(exc).__name__}: {exc})") from None
    session = data.get("calibrationSession") if isinstance(data, dict) else None
    if session is None:
        have = sorted(data) if isinstance(data, dict) else type(data).__name__
        raise DICImportError(f"{path}: no 'calibrationSession' variable (has {have})")
    s = _props(session)
    try:
        stereo = _props(_one(s["cameraParams"]))
        board = _props(_one(s["boardSet"]))
        stereo = dict(stereo, CameraParameters1=_props(_one(stereo["CameraParameters1"])),
                      CameraParameters2=_props(_one(stereo["CameraParameters2"])))
    except (KeyError, TypeError) as exc:
        raise DICImportError(f"{path}: not a stereo calibration session (missing {exc})") from None
    return stereo_calibration_from_matlab(stereo, board, where=str(path))
