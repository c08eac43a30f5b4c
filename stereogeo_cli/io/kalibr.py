"""Kalibr ``camchain.yaml``: two pinhole-radtan cameras, cam1 carrying ``T_cn_cnm1`` = [R | T; 0 0 0 1].

Kalibr's radtan model has four coefficients (k1 k2 p1 p2): a k3 is folded into k1 k2 over the image
(``geometry.fold_k3``, said in a comment); the rational terms k4–k6 cannot be written and are named in a
comment when they are not zero.
"""

from __future__ import annotations

import numpy as np

from stereogeo_cli.geometry import fold_k3
from stereogeo_cli.io.calibration import Rectification, StereoCalibration
from stereogeo_cli.io.text import flow_list


def _camera(K: np.ndarray, D: np.ndarray, size: tuple[int, int], overlaps: int, topic: str) -> str:
    text = ""
    if np.any(D[5:] != 0):
        text += f"  # radtan keeps k1 k2 p1 p2; dropped: {flow_list(D[5:])}\n"
    if D[4] != 0:
        text += (
            f"  # k3 = {flow_list([D[4]])[1:-1]} folded into k1 k2 over the image (radtan has four terms)\n"
        )
        D = fold_k3(D[:5], K)
    return text + (
        f"  cam_overlaps: [{overlaps}]\n"
        f"  camera_model: pinhole\n"
        f"  distortion_coeffs: {flow_list(D[:4])}\n"
        f"  distortion_model: radtan\n"
        f"  intrinsics: {flow_list([K[0, 0], K[1, 1], K[0, 2], K[1, 2]])}\n"
        f"  resolution: [{size[0]}, {size[1]}]\n"
        f"  rostopic: {topic}\n"
    )


def render_kalibr(calibration: StereoCalibration, rect: Rectification | None = None) -> dict[str, str]:
    """``{"camchain.yaml": text}``; cam0 is the left camera, ``X_cam1 = T_cn_cnm1 @ X_cam0`` (metres)."""
    c = calibration
    T_cn_cnm1 = np.eye(4)
    T_cn_cnm1[:3, :3], T_cn_cnm1[:3, 3] = c.R, c.T
    rows = "".join(f"  - {flow_list(row)}\n" for row in T_cn_cnm1)
    text = (
        "cam0:\n"
        + _camera(c.K_left, c.dist_left, c.image_size_left, 1, "/cam0/image_raw")
        + "cam1:\n"
        + "  T_cn_cnm1:\n"
        + rows
        + _camera(c.K_right, c.dist_right, c.image_size_right, 0, "/cam1/image_raw")
    )
    return {"camchain.yaml": text}
