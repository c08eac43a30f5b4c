"""ROS ``left.yaml`` / ``right.yaml``: the camera_info files ``camera_calibration_parsers`` reads.

Unrectified K and D of each camera; R = R1 / R2 and P = P1 / P2 of the rectification, so the right P has
``P[0, 3] = -fx' · baseline`` (in metres, from ``cv2.stereoRectify``).
"""

from __future__ import annotations

import numpy as np

from stereogeo_cli.io.calibration import Rectification, StereoCalibration
from stereogeo_cli.io.text import flow_list


def camera_info_yaml(
    name: str, size: tuple[int, int], K: np.ndarray, D: np.ndarray, R: np.ndarray, P: np.ndarray
) -> str:
    """One camera_info YAML: size (width, height) in pixels, K [3 x 3], D [5 or 8], R [3 x 3], P [3 x 4]."""
    model = "plumb_bob" if D.size == 5 else "rational_polynomial"

    def matrix(key: str, M: np.ndarray, rows: int, cols: int) -> str:
        return f"{key}:\n  rows: {rows}\n  cols: {cols}\n  data: {flow_list(np.ravel(M))}\n"

    return (
        f"image_width: {size[0]}\n"
        f"image_height: {size[1]}\n"
        f"camera_name: {name}\n"
        + matrix("camera_matrix", K, 3, 3)
        + f"distortion_model: {model}\n"
        + matrix("distortion_coefficients", D, 1, D.size)
        + matrix("rectification_matrix", R, 3, 3)
        + matrix("projection_matrix", P, 3, 4)
    )


def render_ros(calibration: StereoCalibration, rect: Rectification) -> dict[str, str]:
    """``{"left.yaml": text, "right.yaml": text}``."""
    c = calibration
    left = camera_info_yaml("left", c.image_size_left, c.K_left, c.dist_left, rect.R1, rect.P1)
    right = camera_info_yaml("right", c.image_size_right, c.K_right, c.dist_right, rect.R2, rect.P2)
    return {"left.yaml": left, "right.yaml": right}
