"""The metric baseline from exact feature matches and the network's per-cell depth.

The matches, with the fused rotation and translation direction, triangulate each point's depth for a
baseline of 1 (Z₁). The depth head predicts q = log(Z / f_n) per stride-8 cell of the left view (Z in
metres; f_n the focal length in units of half the network input's short side; see
:class:`stereogeo_cli.network.model.DepthHead`). So each match gives a baseline

    log B = q + log f_n − log Z₁

and the focal length cancels to first order: Z₁ grows with the focal length assumed as f_n does. Only
points whose rays meet at an angle the match noise cannot hide count, each weighted by how well its
parallax and its cell's predicted spread fix it; the estimate is their weighted median.

The scene's scale is one unknown for the whole image: the cells' errors are not independent, so the
1-sigma is not the spread of the votes but a figure measured on validation renders (the model records it,
``depth_sigma_scale_rel``). The route and its measurements: docs/network.md, "A depth head for the baseline".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stereogeo_cli.fuse.matches import Matches
from stereogeo_cli.fuse.pose import _normalise, ray_angles
from stereogeo_cli.geometry import ResizeCrop, undistort_division
from stereogeo_cli.refine.lm import weighted_median
from stereogeo_cli.settings import resolve

default_conf = {
    "enabled": True,  # calibrate takes the baseline this way when the model has a depth head
    # a match counts when its rays meet at this many times the angle a pixel of noise spans (or more)
    "min_parallax_noise": 3.0,
    "noise_px": 0.5,  # the matches' noise when weighing a vote (pixels of the original image)
    "max_epipolar_px": 2.0,  # matches farther than this from the fused epipolar geometry are left out
    "min_votes": 8,  # fewer usable matches: no estimate
}


@dataclass(frozen=True)
class DepthField:
    """The depth head's output for one view: ``q`` and ``log_spread`` [h x w] at stride ``stride`` of the
    network input, and how the original image maps to that input (a ResizeCrop)."""

    q: np.ndarray
    log_spread: np.ndarray
    stride: int
    resize_crop: ResizeCrop

    @property
    def focal_scale(self) -> float:
        """Network-input pixels per f_n unit: half the input's short side."""
        width, height = self.resize_crop.out_size
        return min(width, height) / 2.0

    def sample(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(q, log spread) [N] at original-image pixels [N x 2], bilinear between cell centres."""
        xy = self.resize_crop.points_to_output(np.asarray(points, dtype=float))
        h, w = self.q.shape
        # cell (i, j) covers input pixels stride·j … stride·(j+1) − 1: its centre is stride·j + (stride − 1)/2
        u = np.clip((xy[:, 0] - (self.stride - 1) / 2) / self.stride, 0, w - 1)
        v = np.clip((xy[:, 1] - (self.stride - 1) / 2) / self.stride, 0, h - 1)
        j0, i0 = (
            np.minimum(np.floor(u).astype(int), w - 2).clip(0),
            np.minimum(np.floor(v).astype(int), h - 2).clip(0),
        )
        j1, i1 = np.minimum(j0 + 1, w - 1), np.minimum(i0 + 1, h - 1)
        a, b = u - j0, v - i0

        def bilinear(grid):
            return (
                grid[i0, j0] * (1 - a) * (1 - b) + grid[i0, j1] * a * (1 - b)
                + grid[i1, j0] * (1 - a) * b + grid[i1, j1] * a * b
            )  # fmt: skip

        return bilinear(self.q), bilinear(self.log_spread)


@dataclass(frozen=True)
class DepthBaseline:
    baseline_m: float
    votes: int  # matches that voted
    spread: float  # the votes' weighted median absolute deviation of log B (a diagnosis, not the sigma)


def triangulate_unit(
    left: np.ndarray, right: np.ndarray, K_left, K_right, R, t_direction, distortion=(0.0, 0.0)
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Depths in the left camera [N] of matches for |T| = 1 (midpoint method), the angle between each
    match's two rays [N] (radians) and the distance of each match to the epipolar plane (radians)."""
    nl = _normalise(undistort_division(left, K_left, distortion[0]), K_left)
    nr = _normalise(undistort_division(right, K_right, distortion[1]), K_right)
    x_l, x_r = (np.column_stack([n, np.ones(len(n))]) for n in (nl, nr))
    t = np.asarray(t_direction, dtype=float) / np.linalg.norm(t_direction)
    a = x_l @ np.asarray(R, dtype=float).T  # the left ray in the right camera's frame
    b = x_r
    # Z_l·a + t ≈ Z_r·b: least squares over (Z_l, Z_r)
    aa, bb, ab = np.sum(a * a, 1), np.sum(b * b, 1), np.sum(a * b, 1)
    at, bt = a @ t, b @ t
    det = aa * bb - ab * ab
    with np.errstate(divide="ignore", invalid="ignore"):
        z_left = (ab * bt - bb * at) / det
    unit_a = a / np.linalg.norm(a, axis=1, keepdims=True)
    unit_b = b / np.linalg.norm(b, axis=1, keepdims=True)
    angle = ray_angles(nl, nr, R)
    normal = np.cross(unit_a, t)
    with np.errstate(divide="ignore", invalid="ignore"):
        off_plane = np.abs(np.sum(normal * unit_b, 1)) / np.linalg.norm(normal, axis=1)
    return z_left, angle, np.arcsin(np.clip(off_plane, 0.0, 1.0))


def baseline_from_depth(
    matches: Matches,
    depth: DepthField,
    K_left: np.ndarray,
    K_right: np.ndarray,
    R: np.ndarray,
    t_direction: np.ndarray,
    distortion: tuple[float, float] = (0.0, 0.0),
    conf: dict | None = None,
) -> DepthBaseline | None:
    """The metric |T| the matches and the left view's depth field agree on, or None (too few usable
    matches). ``K_*``, ``R``, ``t_direction`` and ``distortion`` are the fused calibration (original
    pixels)."""
    conf = resolve(default_conf, conf)
    if len(matches) < conf["min_votes"]:
        return None
    z_unit, angle, off_plane = triangulate_unit(
        matches.left, matches.right, K_left, K_right, R, t_direction, distortion
    )
    noise = conf["noise_px"] / (0.5 * (K_left[0, 0] + K_right[0, 0]))  # radians per pixel of noise
    usable = (
        np.isfinite(z_unit) & (z_unit > 0) & (angle >= conf["min_parallax_noise"] * noise)
        & (off_plane * K_right[0, 0] <= conf["max_epipolar_px"])
    )  # fmt: skip
    if usable.sum() < conf["min_votes"]:
        return None
    q, log_spread = depth.sample(matches.left[usable])
    focal_n = K_left[0, 0] * depth.resize_crop.scale / depth.focal_scale  # f_n of the fused focal
    log_b = q + np.log(focal_n) - np.log(z_unit[usable])
    # each vote's 1-sigma in log: the cell's predicted spread (Laplace scale → sigma) and the triangulation's
    sigma = np.hypot(np.sqrt(2.0) * np.exp(log_spread), noise / angle[usable])
    weight = 1.0 / sigma**2
    centre = weighted_median(log_b, weight)
    return DepthBaseline(
        baseline_m=float(np.exp(centre)),
        votes=int(usable.sum()),
        spread=weighted_median(np.abs(log_b - centre), weight),
    )
