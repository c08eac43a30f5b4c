"""The calibration to write, from the estimates: one assembly for a single pair and for a rig's pairs.

Both ``calibrate`` (``pipeline.Calibrator``) and ``batch-calibrate --same-rig`` (``batch/same_rig.py``) end
here: each camera's focal length, size, gravity and reported sigmas, and the fused :class:`RelativePose`,
become a :class:`StereoCalibration` (K, the OpenCV distortion of the fitted lens, R, T at the baseline) with
the report's ``pose`` block rendered from the pose in one place.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from stereogeo_cli.fuse.pose import RelativePose
from stereogeo_cli.geometry import corner_radius, intrinsic_matrix, opencv_from_division, rotation_angle
from stereogeo_cli.io import StereoCalibration
from stereogeo_cli.refine.lm import vfov_sigma_deg


@dataclass(frozen=True)
class CameraEstimate:
    """One camera as it is written: its focal length (pixels), image size, up vector (None where a rig's
    pairs each have their own) and the reported 1-sigma figures (``focal_px``, ``vfov_deg``, and where there
    is a gravity ``roll_deg``, ``pitch_deg``)."""

    focal_px: float
    width: int
    height: int
    gravity_up: np.ndarray | None
    sigma: dict[str, float]

    @property
    def K(self) -> np.ndarray:
        return intrinsic_matrix(self.focal_px, self.width, self.height)


def focal_sigmas(focal_px: float, height: int, sigma_rel: float, spread_rel: float = 0.0) -> dict[str, float]:
    """The reported 1-sigma of a focal length and of its vFoV, from the relative sigma of the focal length
    (in log f) with a relative ``spread_rel`` added in quadrature (a camera's bias, two reads' distance)."""
    if spread_rel > 0 and math.isfinite(sigma_rel) and sigma_rel > 0:
        sigma_rel = math.hypot(sigma_rel, spread_rel)
    return {"focal_px": focal_px * sigma_rel, "vfov_deg": vfov_sigma_deg(focal_px, height, sigma_rel)}


def finite(value: float | None) -> float | None:
    """A number for the JSON report: None where it is not finite (JSON has no inf)."""
    return float(value) if value is not None and math.isfinite(value) else None


def pose_report(pose: RelativePose) -> dict[str, Any]:
    """The report's ``pose`` block: where the relative pose came from and what the fusion measured."""
    return {
        "source": pose.source,
        "sigma_rotation_deg": finite(pose.sigma_rotation_deg),
        "sigma_direction_deg": finite(pose.sigma_direction_deg),
        "gravity_error_deg": pose.gravity_error_deg,
        "rotation_deg": float(np.degrees(rotation_angle(pose.R))),
        # the two focal lengths held equal: the matches could not tell their ratio from 1 (or, with too few
        # matches, the fields read them alike)
        "equal_focals": pose.equal_focals,
        # a turned rig's matches refined the two focal lengths' common scale: its relative 1-sigma from the
        # matches (None: not refined, the images' read of the focal lengths stands)
        "sigma_common_focal_rel": pose.sigma_common_focal,
        # the fitted radial distortion: division-model k per camera (left, right) and its sigma
        "distortion_k": [float(k) for k in pose.distortion],
        "sigma_distortion_k": [finite(s) for s in pose.sigma_distortion],
    }


def assemble(
    cameras: tuple[CameraEstimate, CameraEstimate],
    pose: RelativePose,
    baseline_m: float,
    scale_source: str,
    model: tuple[str | None, str | None],
    warnings: list[str],
    *,
    more_pose: dict[str, Any] | None = None,
    more: dict[str, Any] | None = None,
    timing_ms: dict[str, float] | None = None,
    notes: list[str] | None = None,
) -> StereoCalibration:
    """The :class:`StereoCalibration` of two cameras and their relative pose, T at ``baseline_m``.

    ``model``: (file name, sha256); ``warnings``: the report's ``warnings``, which open its ``notes``;
    ``notes``: more notes that are not warnings; ``more_pose``: more keys of the ``pose`` block; ``more``:
    more report keys (after ``pose``, before ``warnings``).
    """
    left, right = cameras
    K_left, K_right = left.K, right.K
    # the fusion's k is in the normalised coordinates of the final K
    D_left, D_right = (
        opencv_from_division(k, corner_radius(K))
        for k, K in zip(pose.distortion, (K_left, K_right), strict=True)
    )
    return StereoCalibration(
        K_left=K_left, K_right=K_right, image_size_left=(left.width, left.height),
        image_size_right=(right.width, right.height), R=pose.R, T=pose.translation(baseline_m),
        D_left=D_left, D_right=D_right, gravity_left=left.gravity_up, gravity_right=right.gravity_up,
        sigma_left=left.sigma, sigma_right=right.sigma, scale_source=scale_source,
        matches_found=pose.matches_found, matches_inliers=pose.inliers, timing_ms=dict(timing_ms or {}),
        model_file=model[0], model_sha256=model[1], notes="; ".join([*warnings, *(notes or [])]),
        extra_report={
            "pose": {**pose_report(pose), **(more_pose or {})}, **(more or {}), "warnings": list(warnings)
        },
    )  # fmt: skip
