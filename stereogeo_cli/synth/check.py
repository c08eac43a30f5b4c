"""Self-checks of generated ground truth: the left depth map, moved into the right camera, must agree."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class DepthAgreement:
    """Outcome of reprojecting the left depth into the right camera."""

    agree: int  # co-visible pixels whose predicted right depth matches the right depth map
    disagree: int  # pixels the right camera should see but where it sees something farther away
    occluded: int  # pixels hidden in the right view behind something nearer (not co-visible)

    @property
    def fraction(self) -> float:
        """Share of co-visible pixels that agree (1.0 when there are none)."""
        total = self.agree + self.disagree
        return self.agree / total if total else 1.0


def reproject_depth(depth_left: np.ndarray, calib: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Left pixels with depth moved into the right camera: (x_right [N], y_right [N], z_right [N], metres)."""
    K_l, K_r = np.array(calib["left"]["K"]), np.array(calib["right"]["K"])
    R, T = np.array(calib["R"]), np.array(calib["T"])
    ys, xs = np.nonzero(depth_left > 0)
    z = depth_left[ys, xs].astype(np.float64)
    rays = np.linalg.inv(K_l) @ np.stack([xs, ys, np.ones_like(xs)]).astype(np.float64)
    X_right = R @ (rays * z) + T[:, None]
    p = K_r @ X_right
    return p[0] / p[2], p[1] / p[2], X_right[2]


def depth_agreement(
    depth_left: np.ndarray, depth_right: np.ndarray, calib: dict, rel_tol: float = 0.01, abs_tol: float = 0.01
) -> DepthAgreement:
    """Compare the reprojected left depth with the right depth map around the nearest pixel.

    The right depth is taken as the range [min, max] of its 3 x 3 neighbourhood (so depth edges and
    grazing surfaces are not punished for sampling). A pixel agrees when z_pred is within that range
    widened by abs_tol + rel_tol·z_pred; it is occluded when the right view sees something nearer
    everywhere around it; otherwise it disagrees (the right view sees something farther, or nothing),
    which a correct calibration never produces.
    """
    import cv2

    h, w = depth_right.shape
    x, y, z = reproject_depth(depth_left, calib)
    xi, yi = np.rint(x).astype(int), np.rint(y).astype(int)
    inside = (z > 0) & (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
    d = depth_right.astype(np.float32)
    kernel = np.ones((3, 3), np.uint8)
    far = np.where(d > 0, d, np.float32(np.inf))
    lo = cv2.erode(far, kernel, borderType=cv2.BORDER_REPLICATE)
    hi = cv2.dilate(d, kernel, borderType=cv2.BORDER_REPLICATE)
    z_pred = z[inside]
    lo, hi = lo[yi[inside], xi[inside]].astype(np.float64), hi[yi[inside], xi[inside]].astype(np.float64)
    tol = abs_tol + rel_tol * z_pred
    agree = (z_pred >= lo - tol) & (z_pred <= hi + tol) & np.isfinite(lo)
    occluded = ~agree & (hi < z_pred - tol) & (hi > 0)
    return DepthAgreement(int(agree.sum()), int((~agree & ~occluded).sum()), int(occluded.sum()))
