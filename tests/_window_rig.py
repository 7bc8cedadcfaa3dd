"""The 4-camera rig through glass and water shared by the self-calibration and matching-over-time tests:
two cameras on each side of a water volume, as OpenPTV's test_cavity (0.58 m away, 6 mm glass)."""

import cv2
import numpy as np

from reconstruction.cameras import Camera
from reconstruction.refraction import Window


def window_camera(name, centre, side):
    """A camera 0.58 m from the origin looking at it through 6 mm of glass into water (as OpenPTV's test_cavity)."""
    z = -np.asarray(centre, float) / np.linalg.norm(centre)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    rvec = cv2.Rodrigues(R)[0].ravel()
    K = np.array([[5800.0, 0, 640], [0, 5800.0, 512], [0, 0, 1]])
    win = Window(np.array([0.0, 0.0, side]), -0.12, (0.006,), (1.46,), 1.33)
    return Camera(name, K, np.zeros(5), rvec, -R @ np.asarray(centre, float), (1280, 1024), window=win)


def window_rig():
    """Cameras 1-2 on one side of the volume, 3-4 facing them from the other."""
    return [window_camera("cam1", [0.09, 0.0, -0.57], 1.0), window_camera("cam2", [-0.12, 0.02, -0.57], 1.0),
            window_camera("cam3", [-0.11, 0.07, 0.58], -1.0), window_camera("cam4", [0.12, 0.07, 0.57], -1.0)]
