"""The preview image: the rectified pair side by side, rows every 32 px, and each camera's horizon."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from stereogeo_cli.io.atomic import write_files_atomically
from stereogeo_cli.io.calibration import StereoCalibration, rectify

ROW_SPACING = 32  # pixels between the horizontal guide lines
ROW_COLOUR = (0, 255, 0)  # RGB
HORIZON_COLOUR = (255, 0, 255)


def horizon_line(P: np.ndarray, R_rect: np.ndarray, gravity: np.ndarray) -> np.ndarray:
    """The horizon in a rectified image as a line l [3] (lᵀ·(x, y, 1) = 0).

    Rays r of the rectified camera are on the horizon when (R_rect·g)·r = 0, with r = K⁻¹ (x, y, 1).
    """
    K = P[:, :3]
    return np.linalg.inv(K).T @ (R_rect @ gravity)


def _draw_line(image: np.ndarray, line: np.ndarray, colour) -> None:
    a, b, c = line
    w = image.shape[1]
    if abs(b) < 1e-12:
        return
    y0, y1 = -c / b, -(a * (w - 1) + c) / b
    limit = 1e6
    if abs(y0) < limit and abs(y1) < limit:
        cv2.line(image, (0, round(y0)), (w - 1, round(y1)), colour, 2, cv2.LINE_AA)


def render_preview(left: np.ndarray, right: np.ndarray, calibration: StereoCalibration) -> np.ndarray:
    """The preview as an RGB image [H x 2W x 3]: rectified left | rectified right."""
    rect = rectify(calibration)
    views = []
    for image, K, D, R_rect, P, g in (
        (left, calibration.K_left, calibration.dist_left, rect.R1, rect.P1, calibration.gravity_left),
        (right, calibration.K_right, calibration.dist_right, rect.R2, rect.P2, calibration.gravity_right),
    ):
        map_x, map_y = cv2.initUndistortRectifyMap(K, D, R_rect, P, rect.size, cv2.CV_32FC1)
        view = cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR)
        for y in range(ROW_SPACING, view.shape[0], ROW_SPACING):
            cv2.line(view, (0, y), (view.shape[1] - 1, y), ROW_COLOUR, 1)
        if g is not None:
            _draw_line(view, horizon_line(P, R_rect, g), HORIZON_COLOUR)
        views.append(view)
    return np.hstack(views)


def write_preview(
    path: str | Path, left: np.ndarray, right: np.ndarray, calibration: StereoCalibration
) -> Path:
    """Write the preview PNG atomically."""
    path = Path(path)
    image = render_preview(left, right, calibration)
    ok, data = cv2.imencode(".png", cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    if not ok:
        raise RuntimeError("PNG encoding of the preview failed")
    write_files_atomically(path.parent, {path.name: data.tobytes()})
    return path
