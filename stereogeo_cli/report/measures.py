"""Numbers the report's figures show that the JSON report does not hold, each measured on the calibration
as written: the matches' row differences once rectified, and how far one R is from another."""

from __future__ import annotations

import math

import numpy as np

from stereogeo_cli.geometry import axis_angle_from_rotation, rectified_row_differences, rotation_angle
from stereogeo_cli.io.calibration import StereoCalibration, rectify


def row_errors(calibration: StereoCalibration, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """|row difference| (px) of matches ``left``, ``right`` [N x 2] once both images are rectified with the
    calibration (its ``cv2.stereoRectify``, as the written files rectify them)."""
    if len(left) == 0:
        return np.zeros(0)
    rect, c = rectify(calibration), calibration
    cameras = (c.K_left, c.dist_left, c.K_right, c.dist_right)
    return rectified_row_differences(left, right, cameras, (rect.R1, rect.P1, rect.R2, rect.P2))


def rotation_apart_deg(R_a, R_b) -> float:
    """The angle (degrees) of the rotation between two rotations [3 x 3]."""
    return math.degrees(rotation_angle(np.asarray(R_a, float) @ np.asarray(R_b, float).T))


def rotation_vector_deg(R) -> np.ndarray:
    """A rotation [3 x 3] as its axis-angle vector in degrees [3] (the axis times the angle)."""
    return np.degrees(axis_angle_from_rotation(np.asarray(R, float)))
