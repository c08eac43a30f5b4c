"""Two-view geometry for the rig convention ``X_right = R @ X_left + T``."""

from __future__ import annotations

import numpy as np

from stereogeo_cli.geometry.rotation import skew


def essential_matrix(R: np.ndarray, T: np.ndarray) -> np.ndarray:
    """E = [T]ₓ R, so that x̂_rightᵀ E x̂_left = 0 for normalised homogeneous points."""
    return skew(np.asarray(T, dtype=float).reshape(3)) @ np.asarray(R, dtype=float)


def fundamental_matrix(K_left: np.ndarray, K_right: np.ndarray, R: np.ndarray, T: np.ndarray) -> np.ndarray:
    """F = K_right⁻ᵀ E K_left⁻¹, so that x_rightᵀ F x_left = 0 for pixel homogeneous points."""
    E = essential_matrix(R, T)
    return np.linalg.inv(K_right).T @ E @ np.linalg.inv(K_left)


def symmetric_epipolar_distance(F: np.ndarray, x_left: np.ndarray, x_right: np.ndarray) -> np.ndarray:
    """Mean of point-to-epipolar-line distances in both images, pixels [N], for points [N x 2]."""
    ones = np.ones((len(x_left), 1))
    pl = np.hstack([x_left, ones])
    pr = np.hstack([x_right, ones])
    lines_right = pl @ F.T  # F x_left
    lines_left = pr @ F  # Fᵀ x_right
    num = np.abs(np.sum(pr * lines_right, axis=1))
    d_right = num / np.linalg.norm(lines_right[:, :2], axis=1)
    d_left = num / np.linalg.norm(lines_left[:, :2], axis=1)
    return 0.5 * (d_right + d_left)


def rectified_row_differences(
    left: np.ndarray, right: np.ndarray, cameras: tuple, rectification: tuple
) -> np.ndarray:
    """|row difference| (px) of matches ``left``, ``right`` [N x 2] once both images are rectified:
    ``cameras`` = (K_left, D_left, K_right, D_right) in OpenCV's model, ``rectification`` = (R1, P1, R2, P2)
    as ``cv2.stereoRectify`` gives them. 0 for every match of a calibration the matches agree with."""
    import cv2

    if len(left) == 0:
        return np.zeros(0)
    K_left, D_left, K_right, D_right = cameras
    R1, P1, R2, P2 = rectification
    y_left = cv2.undistortPoints(np.asarray(left, float).reshape(-1, 1, 2), K_left, D_left, R=R1, P=P1)
    y_right = cv2.undistortPoints(np.asarray(right, float).reshape(-1, 1, 2), K_right, D_right, R=R2, P=P2)
    return np.abs(y_left.reshape(-1, 2)[:, 1] - y_right.reshape(-1, 2)[:, 1])
