"""Blocks of frames left out: how far the sequence's calibration moves when one stretch of the recording is
left out (a jackknife over the sequence), and how well the calibration fitted without a stretch rectifies
that stretch's own frames.

The adjustment's cost profile measures how sharply the model it fits (one focal length per camera, the
principal point held or freed, one or two radial terms, a rigid rig, still scenes) ties the focal
lengths; where real data break that model (moving cars, a principal point off the centre, a lens the two
terms do not describe), the profile can be sharp about a biased minimum. The blocks are another reading,
from the data alone: the registered frames are cut into ``blocks`` stretches in time, the adjustment is
run again without each, and the spread of the K results, scaled as a jackknife's ((K − 1)/K · Σ of the
squared deviations from their mean), is the sampling sigma of the focal lengths' common scale, of R and of
T's direction. It is wide where different stretches of one drive disagree.

The same fits give a check users already trust: each left-out stretch's stereo correspondences (the points
of the model seen by both images of a frame) rectified with the calibration fitted without it, and the
difference of their rows in pixels, as a stereo rig's calibration is judged (under 0.25 px good, under
0.1 px excellent).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stereogeo_cli.fuse.assemble import finite
from stereogeo_cli.geometry import axis_angle_from_rotation, rectified_row_differences
from stereogeo_cli.rig.combine import chordal_mean, mean_direction

default_conf = {
    "blocks": 5,  # stretches of frames left out one at a time
    "min_block_frames": 2,  # fewer registered frames per stretch: no blocks (too short a sequence)
}


@dataclass(frozen=True)
class BlockFit:
    """The adjustment without one stretch: each camera's focal length and its [3 x 3] K and OpenCV D (in
    stereogeo's pixels), the rig's R and T (the model's scale)."""

    focal_px: tuple[float, float]
    K: tuple[np.ndarray, np.ndarray]
    D: tuple[np.ndarray, np.ndarray]
    R: np.ndarray
    T: np.ndarray


@dataclass(frozen=True)
class LeftOut:
    """What the left-out stretches tell: the jackknife 1-sigmas of the focal lengths' common scale
    (relative), of R and of T's direction (degrees), and the row differences (px) of the left-out frames'
    correspondences after rectification, as their median and 95th percentile."""

    blocks: int
    focal_sigma_rel: float
    rotation_sigma_deg: float
    direction_sigma_deg: float
    row_error_median_px: float | None
    row_error_p95_px: float | None
    row_matches: int
    focal_px: list[tuple[float, float]]  # per stretch (left, right)

    def to_report(self) -> dict:
        return {
            "blocks": self.blocks,
            "focal_sigma_rel": finite(self.focal_sigma_rel),
            "rotation_sigma_deg": finite(self.rotation_sigma_deg),
            "direction_sigma_deg": finite(self.direction_sigma_deg),
            "row_error_px": {
                "median": self.row_error_median_px,
                "p95": self.row_error_p95_px,
                "matches": self.row_matches,
            },
            "focal_px": [list(f) for f in self.focal_px],
        }


def jackknife_sigma(values: np.ndarray) -> float:
    """The jackknife 1-sigma of K leave-one-out estimates [K] (or [K x d]: the root of the summed
    variances): √((K − 1)/K · Σ |θ_k − θ̄|²)."""
    values = np.asarray(values, float)
    deviations = values - values.mean(axis=0)
    k = len(values)
    return math.sqrt((k - 1) / k * float(np.sum(deviations**2)))


def stretches(frame_names: list[str], blocks: int) -> list[list[str]]:
    """The registered frames' names in time order cut into ``blocks`` stretches of (nearly) equal length."""
    ordered = sorted(frame_names)
    return [list(part) for part in np.array_split(np.array(ordered, dtype=object), blocks) if len(part)]


def row_errors(fit: BlockFit, sizes: tuple, pairs: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """The row differences (px) of correspondences ``pairs`` ([N x 2] left, [N x 2] right, stereogeo's
    pixels) once both images are rectified with ``fit`` (OpenCV's ``stereoRectify``). ``sizes``: ((h, w)
    left, right)."""
    import cv2

    if not pairs:
        return np.zeros(0)
    (h, w), _ = sizes
    R1, R2, P1, P2, *_ = cv2.stereoRectify(
        fit.K[0], fit.D[0], fit.K[1], fit.D[1], (w, h), fit.R, fit.T.reshape(3, 1), alpha=0
    )
    left, right = (np.concatenate([p[side] for p in pairs]) for side in (0, 1))
    return rectified_row_differences(left, right, (fit.K[0], fit.D[0], fit.K[1], fit.D[1]), (R1, P1, R2, P2))


def summarise(fits: list[BlockFit], rows: np.ndarray) -> LeftOut:
    """The jackknife sigmas of the stretches' fits and the row differences' median and 95th percentile."""
    common = [0.5 * (math.log(f.focal_px[0]) + math.log(f.focal_px[1])) for f in fits]
    mean_R = chordal_mean([f.R for f in fits])
    turns = [axis_angle_from_rotation(f.R @ mean_R.T) for f in fits]  # each fit's turn from their mean
    mean_t = mean_direction([f.T for f in fits])
    across = [f.T / np.linalg.norm(f.T) - mean_t * float(f.T @ mean_t / np.linalg.norm(f.T)) for f in fits]
    return LeftOut(
        blocks=len(fits),
        focal_sigma_rel=jackknife_sigma(np.array(common)),
        rotation_sigma_deg=math.degrees(jackknife_sigma(np.array(turns))),
        direction_sigma_deg=math.degrees(jackknife_sigma(np.array(across))),
        row_error_median_px=float(np.median(rows)) if len(rows) else None,
        row_error_p95_px=float(np.percentile(rows, 95)) if len(rows) else None,
        row_matches=int(len(rows)),
        focal_px=[f.focal_px for f in fits],
    )
