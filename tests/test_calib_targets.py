"""Board targets: object points, validation, detection of rendered chessboards, circle grids and ChArUco."""

import cv2
import numpy as np
import pytest

from reconstruction.cameras import rotation_matrix
from reconstruction.targets import BoardSpec, TargetError, detect_board
from rig_sim.board import render_board_views
from rig_sim.cameras import camera_ring


@pytest.mark.parametrize(
    "spec, tol",
    [
        (BoardSpec("chessboard", 9, 6, 3.5e-3), 0.08),  # measured 0.037 px
        (BoardSpec("circles", 7, 5, 4e-3), 0.12),  # 0.056 px (perspective bias of circle centres included)
        (BoardSpec("acircles", 4, 9, 2.5e-3), 0.08),  # 0.024 px
        (BoardSpec(), 0.08),  # ChArUco 8x6, 0.041 px
    ],
    ids=["chessboard", "circles", "acircles", "charuco"],
)
def test_detect_rendered_board(spec, tol):
    cam = camera_ring(1, image_size=(1224, 1024), seed=2)[0]
    w, h = spec.extent
    n = cam.center / np.linalg.norm(cam.center)
    R = np.stack([np.array([0, 0, 1.0]), np.cross(-n, [0, 0, 1.0]), -n], 1) @ rotation_matrix(np.array([0.3, 0.2, 0.1]))
    t = -R @ np.array([w / 2, h / 2, 0])
    views = render_board_views([cam], spec, cv2.Rodrigues(R)[0].ravel(), t, seed=1)
    assert views.seen[0, 0]
    det = detect_board(views.images[cam.name][0], spec)
    assert len(det) == spec.n_points
    err = det.points - views.points[0, 0, det.ids]
    assert np.sqrt(np.mean(np.sum(err**2, 1))) < tol


def test_no_board_gives_empty_detection():
    img = np.full((200, 300), 30, np.uint8)
    for spec in (BoardSpec(), BoardSpec("chessboard", 9, 6, 1e-3), BoardSpec("circles", 4, 3, 1e-3)):
        det = detect_board(img, spec)
        assert len(det) == 0 and det.points.shape == (0, 2)


def test_object_points_and_validation():
    ch = BoardSpec()
    obj = ch.object_points()
    assert obj.shape == (35, 3) and np.allclose(obj[1] - obj[0], [4.5e-3, 0, 0])
    cb = BoardSpec("chessboard", 9, 6, 2e-3).object_points()
    assert cb.shape == (54, 3) and np.allclose(cb[9] - cb[0], [0, 2e-3, 0])
    ac = BoardSpec("acircles", 4, 11, 1e-3).object_points()
    assert np.allclose(ac[4] - ac[0], [1e-3, 1e-3, 0])
    with pytest.raises(TargetError, match="kind"):
        BoardSpec("aruco")
    with pytest.raises(TargetError, match="marker_size"):
        BoardSpec(marker_size=5e-3)
    with pytest.raises(TargetError, match="dictionary"):
        BoardSpec(dictionary="DICT_9X9_1")
    with pytest.raises(TargetError, match=r"\(H, W\)"):
        detect_board(np.zeros((2, 3, 4, 5)), ch)


def test_charuco_object_points_match_opencv():
    spec = BoardSpec("charuco", 7, 5, 4e-3, 3e-3)
    np.testing.assert_allclose(spec.object_points(), spec.charuco_board().getChessboardCorners(), atol=1e-9)
