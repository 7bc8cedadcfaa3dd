"""Calibration targets: board specifications, their object points and detection in images.

Board frame: origin at the board's top-left corner (as printed), x along the columns, y along
the rows, z into the board (OpenCV's convention), metres.

Supported kinds and how ``columns`` x ``rows`` count:

- ``"charuco"``: squares of a ChArUco board (inner corners ``(columns-1) x (rows-1)``, identified by
  their ArUco markers, so partial views are usable);
- ``"chessboard"``: inner corners of a plain chessboard (OpenCV's ``patternSize``), the whole board
  must be seen;
- ``"circles"`` / ``"acircles"``: symmetric / asymmetric circle grid (OpenCV's ``patternSize``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["TargetError", "BoardSpec", "BoardDetection", "detect_board", "detect_boards"]

log = logging.getLogger(__name__)

_KINDS = ("charuco", "chessboard", "circles", "acircles")


class TargetError(ValueError):
    """A board specification or detection input is invalid."""


@dataclass(frozen=True)
class BoardSpec:
    """A calibration target.

    Attributes
    ----------
    kind : {"charuco", "chessboard", "circles", "acircles"}
    columns, rows : int
        Squares (charuco) or inner corners / circles (others), see the module docstring.
    square_size : float
        Square side or circle spacing, m.
    marker_size : float
        ArUco marker side (charuco only), m.
    dictionary : str
        Name of an OpenCV predefined ArUco dictionary, e.g. ``"DICT_4X4_50"`` (charuco only).
    subpix_half_window : int
        Half-size of ``cornerSubPix``'s search window, px, for chessboards (5 -> 11x11 window is too
        large for small squares; keep it below a quarter of a square's size in pixels).
    """

    kind: str = "charuco"
    columns: int = 8
    rows: int = 6
    square_size: float = 4.5e-3
    marker_size: float = 3.4e-3
    dictionary: str = "DICT_4X4_50"
    subpix_half_window: int = 5

    def __post_init__(self) -> None:
        if self.kind not in _KINDS:
            raise TargetError(f"BoardSpec.kind must be one of {_KINDS}; got {self.kind!r}")
        if self.columns < 2 or self.rows < 2:
            raise TargetError(f"BoardSpec: columns and rows must be >= 2; got {self.columns} x {self.rows}")
        if not self.square_size > 0:
            raise TargetError(f"BoardSpec.square_size must be > 0 (m); got {self.square_size}")
        if self.kind == "charuco":
            if not 0 < self.marker_size < self.square_size:
                raise TargetError(
                    f"BoardSpec.marker_size must be in (0, square_size={self.square_size}) m for charuco; got {self.marker_size}"
                )
            if not hasattr(cv2.aruco, self.dictionary):
                raise TargetError(f"BoardSpec.dictionary must name an OpenCV ArUco dictionary; got {self.dictionary!r}")

    def charuco_board(self) -> "cv2.aruco.CharucoBoard":
        """The OpenCV ChArUco board object (charuco only)."""
        if self.kind != "charuco":
            raise TargetError(f"charuco_board() needs kind 'charuco'; this board is {self.kind!r}")
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.columns, self.rows), self.square_size, self.marker_size, dictionary)

    @property
    def n_points(self) -> int:
        if self.kind == "charuco":
            return (self.columns - 1) * (self.rows - 1)
        return self.columns * self.rows

    @property
    def extent(self) -> tuple[float, float]:
        """Printed size (width, height) of the pattern, m (squares for charuco, else corner span + 1 square)."""
        if self.kind == "charuco":
            return self.columns * self.square_size, self.rows * self.square_size
        if self.kind == "acircles":
            return (2 * self.columns + 1) * self.square_size, (self.rows + 1) * self.square_size
        return (self.columns + 1) * self.square_size, (self.rows + 1) * self.square_size

    def object_points(self) -> np.ndarray:
        """Board points ``(n_points, 3)`` in the board frame, m; row index = point id."""
        if self.kind == "charuco":
            # as CharucoBoard.getChessboardCorners() (id = row * (columns - 1) + column), in float64
            j, i = np.meshgrid(np.arange(1, self.columns), np.arange(1, self.rows))
            return np.stack([j.ravel() * self.square_size, i.ravel() * self.square_size, np.zeros(j.size)], -1)
        j, i = np.meshgrid(np.arange(self.columns), np.arange(self.rows))
        if self.kind == "acircles":
            x = (2 * j + i % 2) * self.square_size
            y = i * self.square_size
        else:
            x = j * self.square_size
            y = i * self.square_size
        # offset so the pattern sits inside extent like a printed sheet with a one-square margin
        pts = np.stack([x.ravel() + self.square_size, y.ravel() + self.square_size, np.zeros(x.size)], -1)
        return pts


@dataclass(frozen=True)
class BoardDetection:
    """Board points found in one image.

    Attributes
    ----------
    ids : ndarray, shape (n,), int
        Indices into ``BoardSpec.object_points()``.
    points : ndarray, shape (n, 2)
        Pixel coordinates (OpenCV convention).
    """

    ids: np.ndarray
    points: np.ndarray

    @classmethod
    def empty(cls) -> "BoardDetection":
        return cls(np.zeros(0, int), np.zeros((0, 2)))

    def __len__(self) -> int:
        return int(self.ids.size)


def _gray(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.ndim != 2:
        raise TargetError(f"image must be (H, W) or (H, W, 3); got shape {np.shape(image)}")
    if img.dtype != np.uint8:
        scale = 255.0 / max(float(img.max()), 1.0)
        img = np.clip(img.astype(np.float32) * scale, 0, 255).astype(np.uint8)
    return img


def detect_board(image: np.ndarray, spec: BoardSpec, *, min_points: int = 6) -> BoardDetection:
    """Find the board's points in one image.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, 3)
    spec : BoardSpec
    min_points : int
        Fewer points than this count as "not seen" (empty detection).

    Returns
    -------
    BoardDetection
        Empty when the board is not found.
    """
    gray = _gray(image)
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
    if spec.kind == "charuco":
        board = spec.charuco_board()
        cparams = cv2.aruco.CharucoParameters()
        dparams = cv2.aruco.DetectorParameters()
        dparams.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        detector = cv2.aruco.CharucoDetector(board, cparams, dparams)
        corners, ids, _, _ = detector.detectBoard(gray)
        if ids is None or len(ids) < min_points:
            return BoardDetection.empty()
        pts = np.asarray(corners, np.float32).reshape(-1, 1, 2)
        # refine on a window limited by the square size in pixels
        hw = _subpix_window(pts.reshape(-1, 2), np.asarray(ids).ravel(), spec, spec.subpix_half_window)
        pts = cv2.cornerSubPix(gray, pts, (hw, hw), (-1, -1), crit)
        return BoardDetection(np.asarray(ids, int).ravel(), pts.reshape(-1, 2).astype(float))
    size = (spec.columns, spec.rows)
    if spec.kind == "chessboard":
        found, pts = cv2.findChessboardCorners(gray, size, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
        if not found:
            return BoardDetection.empty()
        hw = spec.subpix_half_window
        pts = cv2.cornerSubPix(gray, pts.astype(np.float32), (hw, hw), (-1, -1), crit)
    else:
        flag = cv2.CALIB_CB_SYMMETRIC_GRID if spec.kind == "circles" else cv2.CALIB_CB_ASYMMETRIC_GRID
        found, pts = cv2.findCirclesGrid(gray, size, flags=flag)
        if not found:
            return BoardDetection.empty()
    pts = np.asarray(pts, float).reshape(-1, 2)
    if len(pts) < min_points:
        return BoardDetection.empty()
    return BoardDetection(np.arange(len(pts)), pts)


def _subpix_window(points: np.ndarray, ids: np.ndarray, spec: BoardSpec, cap: int) -> int:
    """Half-window for cornerSubPix: at most a quarter of the smallest square side in pixels."""
    obj = spec.object_points()[ids, :2]
    if len(points) < 2:
        return cap
    d_img = np.linalg.norm(points[:, None] - points[None], axis=-1)
    d_obj = np.linalg.norm(obj[:, None] - obj[None], axis=-1)
    np.fill_diagonal(d_obj, np.inf)
    near = np.isclose(d_obj, spec.square_size)
    if not near.any():
        return cap
    side = float(np.min(d_img[near]))
    return int(max(2, min(cap, side // 4)))


def detect_boards(images: dict[str, list[np.ndarray]] | dict[str, np.ndarray], spec: BoardSpec, **kw) -> dict[str, list[BoardDetection]]:
    """Detect the board in synchronised views: ``{camera: [image per view]}`` -> ``{camera: [BoardDetection per view]}``."""
    out = {}
    for cam, imgs in images.items():
        out[cam] = [detect_board(img, spec, **kw) for img in imgs]
        log.info("camera %s: board found in %d of %d views", cam, sum(len(d) > 0 for d in out[cam]), len(out[cam]))
    return out
