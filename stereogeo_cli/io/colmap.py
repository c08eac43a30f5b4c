"""COLMAP ``cameras.txt``: camera 1 is the left camera, camera 2 the right.

COLMAP puts the centre of the top-left pixel at (0.5, 0.5), OpenCV at (0, 0): ``c_colmap = c_opencv + 0.5``.
The model is PINHOLE (fx fy cx cy) without distortion, OPENCV (+ k1 k2 p1 p2) when only those are set,
FULL_OPENCV (+ k1 k2 p1 p2 k3 k4 k5 k6) otherwise.
"""

from __future__ import annotations

import numpy as np

from stereogeo_cli.io.calibration import Rectification, StereoCalibration
from stereogeo_cli.io.text import yaml_float


def _camera_line(camera_id: int, K: np.ndarray, D: np.ndarray, size: tuple[int, int]) -> str:
    params = [K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5]
    if not np.any(D):
        model = "PINHOLE"
    elif not np.any(D[4:]):
        model, params = "OPENCV", params + list(D[:4])
    else:
        model, params = "FULL_OPENCV", params + list(D) + [0.0] * (8 - D.size)
    return f"{camera_id} {model} {size[0]} {size[1]} " + " ".join(yaml_float(p) for p in params) + "\n"


def render_colmap(calibration: StereoCalibration, rect: Rectification | None = None) -> dict[str, str]:
    """``{"cameras.txt": text}`` with COLMAP's header comment."""
    c = calibration
    return {
        "cameras.txt": "# Camera list with one line of data per camera:\n"
        "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
        "# Number of cameras: 2\n"
        + _camera_line(1, c.K_left, c.dist_left, c.image_size_left)
        + _camera_line(2, c.K_right, c.dist_right, c.image_size_right)
    }
