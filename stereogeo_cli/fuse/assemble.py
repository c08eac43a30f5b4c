"""The calibration to write, from the estimates: one assembly for a single pair and for a rig's pairs.

``calibrate`` (``pipeline.Calibrator``), ``batch-calibrate --same-rig`` (``batch/same_rig.py``) and
``calibrate-sequence`` (``sequence/run.py``) end here: each camera's focal length, size, gravity and
reported sigmas, and the rig's pose, become a :class:`StereoCalibration` (:func:`calibration`) with the
report's ``pose`` block of the same keys for all: a fused :class:`RelativePose` (:func:`assemble`,
:func:`pose_report`), or a pose measured otherwise, e.g. by a bundle adjustment
(:func:`measured_pose_report`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from stereogeo_cli.fuse.pose import RelativePose
from stereogeo_cli.geometry import (
    axis_angle_from_rotation,
    corner_radius,
    intrinsic_matrix,
    opencv_from_division,
    rotation_angle,
)
from stereogeo_cli.io import StereoCalibration
from stereogeo_cli.refine.lm import vfov_sigma_deg


@dataclass(frozen=True)
class CameraEstimate:
    """One camera as estimated, by a pair, an adjustment or a rig: its focal length (pixels), image size,
    up vector (None where a rig's pairs each have their own) and 1-sigma figures (``focal_px``; as it is
    written also ``vfov_deg``, and where there is a gravity ``roll_deg``, ``pitch_deg``; a pair's reading of
    its rig ``gravity_deg``)."""

    focal_px: float
    width: int
    height: int
    gravity_up: np.ndarray | None
    sigma: dict[str, float]
    principal_point: tuple[float, float] | None = None  # (cx, cy) in pixels; None: the image's centre
    principal_point_refined: bool = False  # the principal point was fitted (else held at the centre)
    radial: tuple[float, float] = (0.0, 0.0)  # OpenCV's k1, k2, where the camera's own fit has them
    division_k: float = 0.0  # a pair's fitted lens: the division model's k (normalised coordinates)
    # the EXIF (or given) prior (focal, sigma) in pixels that a pair's reading took in, kept apart
    focal_prior: tuple[float, float] | None = None

    @property
    def sigma_focal_rel(self) -> float:
        """The focal length's relative 1-sigma (inf where it is not known)."""
        return self.sigma.get("focal_px", math.inf) / self.focal_px

    @property
    def K(self) -> np.ndarray:
        K = intrinsic_matrix(self.focal_px, self.width, self.height)
        if self.principal_point is not None:
            K[0, 2], K[1, 2] = self.principal_point
        return K


def focal_sigmas(focal_px: float, height: int, sigma_rel: float, spread_rel: float = 0.0) -> dict[str, float]:
    """The reported 1-sigma of a focal length and of its vFoV, from the relative sigma of the focal length
    (in log f) with a relative ``spread_rel`` added in quadrature (a camera's bias, two reads' distance)."""
    if spread_rel > 0 and math.isfinite(sigma_rel) and sigma_rel > 0:
        sigma_rel = math.hypot(sigma_rel, spread_rel)
    return {"focal_px": focal_px * sigma_rel, "vfov_deg": vfov_sigma_deg(focal_px, height, sigma_rel)}


def finite(value: float | None) -> float | None:
    """A number for the JSON report: None where it is not finite (JSON has no inf)."""
    return float(value) if value is not None and math.isfinite(value) else None


def rotation_sigma_deg(pose: RelativePose, cameras: tuple[CameraEstimate, CameraEstimate]) -> float:
    """The reported 1-sigma of R (degrees): the fusion's, which holds the focal lengths at the values
    written, with their own uncertainty taken in.

    R is read through the focal lengths: the part of the rotation that turns the optical axis, ω⊥ (the
    axis-angle vector's x and y), shows in the images as pixel shifts of about f·ω⊥, so with both focal
    lengths e^δ times the truth it reads about δ·ω⊥ off, while a turn about the optical axis does not depend
    on f. On the car-mounted pairs, whose cameras turn 48–72°, R moved 6–15° with both true focal lengths
    scaled by e^±0.22, where δ·|ω⊥| gives 11–13°. So R's variance takes in (|ω⊥|·σ)², σ the two cameras'
    mean relative focal sigma as reported (a given focal length has none), less what the fusion's sigma
    holds of it already: the fields' own sigma of the common scale (``sigma_focal_considered``), narrower
    than the reported one, which has the camera bias and the photographs' scale (on a turned rig, the images'
    read with the camera bias: ``fuse.pose._with_common_scale_as_read``)."""
    relative = [(c.sigma.get("focal_px") or 0.0) / c.focal_px for c in cameras]
    common = float(np.mean([r for r in relative if math.isfinite(r)] or [0.0]))
    turn = math.degrees(float(np.hypot(*axis_angle_from_rotation(pose.R)[:2])))
    beyond = max(common**2 - pose.sigma_focal_considered**2, 0.0)
    return math.sqrt(pose.sigma_rotation_deg**2 + turn**2 * beyond)


def pose_report(pose: RelativePose, cameras: tuple[CameraEstimate, CameraEstimate]) -> dict[str, Any]:
    """The report's ``pose`` block: where the relative pose came from and what the fusion measured."""
    return {
        "source": pose.source,
        # the fusion's, with the focal lengths' uncertainty (rotation_sigma_deg)
        "sigma_rotation_deg": finite(rotation_sigma_deg(pose, cameras)),
        "sigma_direction_deg": finite(pose.sigma_direction_deg),
        # what decided which way T points: "matches" (points in front of both cameras, with parallax) or
        # "pose_head" (a far scene: the head's sign, which takes the files' names as given)
        "sign_source": pose.sign_source,
        "gravity_error_deg": pose.gravity_error_deg,
        "rotation_deg": float(np.degrees(rotation_angle(pose.R))),
        # the two focal lengths held equal: the matches could not tell their ratio from 1 (or, with too few
        # matches, the fields read them alike)
        "equal_focals": pose.equal_focals,
        # a turned rig's matches refined the two focal lengths' common scale: its relative 1-sigma from the
        # matches (None: not refined, the images' read of the focal lengths stands)
        "sigma_common_focal_rel": pose.sigma_common_focal,
        # two views from one centre (source "rotation"): each focal length's relative 1-sigma as the rotation
        # alone reads it, before it is combined with the images' (None: held, or the turn tells nothing)
        "rotation_focal_sigma_rel": list(pose.focal_read_sigma_rel or (None, None)),
        # the fitted radial distortion: division-model k per camera (left, right) and its sigma
        "distortion_k": [float(k) for k in pose.distortion],
        "sigma_distortion_k": [finite(s) for s in pose.sigma_distortion],
    }


def measured_pose_report(
    source: str, R: np.ndarray, sigma_rotation_deg: float, sigma_direction_deg: float
) -> dict[str, Any]:
    """The report's ``pose`` block, with :func:`pose_report`'s keys, for a pose that no fusion of one set of
    matches made (``source``: e.g. "sequence", a bundle adjustment): its R's angle and the two sigmas
    (degrees); the fusion's own measurements are None and its lens terms absent (the lens is in K and D)."""
    return {
        "source": source,
        "sigma_rotation_deg": finite(sigma_rotation_deg),
        "sigma_direction_deg": finite(sigma_direction_deg),
        "sign_source": source,
        "gravity_error_deg": None,
        "rotation_deg": math.degrees(rotation_angle(R)),
        "equal_focals": False,
        "sigma_common_focal_rel": None,
        "rotation_focal_sigma_rel": [None, None],
        "distortion_k": [None, None],
        "sigma_distortion_k": [None, None],
    }


def calibration(
    cameras: tuple[CameraEstimate, CameraEstimate],
    pose: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]],
    scale_source: str,
    model: tuple[str | None, str | None],
    warnings: list[str],
    *,
    matches: tuple[int, int] = (0, 0),
    more: dict[str, Any] | None = None,
    timing_ms: dict[str, float] | None = None,
    notes: list[str] | None = None,
) -> StereoCalibration:
    """The :class:`StereoCalibration` of two cameras and their pose: ``pose`` is (R, T in metres, the OpenCV
    distortion D of each camera, the report's ``pose`` block). ``matches``: (found, inliers); ``model``:
    (file name, sha256); ``warnings``: the report's ``warnings``, which open its ``notes``; ``notes``: more
    notes that are not warnings; ``more``: more report keys (after ``pose``, before ``warnings``)."""
    left, right = cameras
    R, T, (D_left, D_right), block = pose[0], pose[1], pose[2], pose[3]
    return StereoCalibration(
        K_left=left.K, K_right=right.K, image_size_left=(left.width, left.height),
        image_size_right=(right.width, right.height), R=R, T=T, D_left=D_left, D_right=D_right,
        gravity_left=left.gravity_up, gravity_right=right.gravity_up, sigma_left=left.sigma,
        sigma_right=right.sigma, scale_source=scale_source, matches_found=matches[0],
        matches_inliers=matches[1], timing_ms=dict(timing_ms or {}), model_file=model[0],
        model_sha256=model[1], notes="; ".join([*warnings, *(notes or [])]),
        extra_report={"pose": block, **(more or {}), "warnings": list(warnings)},
    )  # fmt: skip


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
    # the fusion's k is in the normalised coordinates of the final K
    D = tuple(
        opencv_from_division(k, corner_radius(camera.K))
        for k, camera in zip(pose.distortion, cameras, strict=True)
    )
    block = {**pose_report(pose, cameras), **(more_pose or {})}
    return calibration(
        cameras, (pose.R, pose.translation(baseline_m), D, block), scale_source, model, warnings,
        matches=(pose.matches_found, pose.inliers), more=more, timing_ms=timing_ms, notes=notes,
    )  # fmt: skip
