"""Stereo rigs: cameras in a world frame (x east, y north, z up; metres) and the sampler of rigs.

A camera is (width, height, focal, R_wc, center): ``X_cam = R_wc @ (X_world - center)`` in OpenCV axes;
by default fx = fy = focal and the principal point is (w/2, h/2), and a sequence may set ``aspect`` (fy / fx)
and ``principal`` (cx, cy) to render a camera whose K is not that ideal one. The rig convention is the
project's: ``X_right = R @ X_left + T``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stereogeo_cli.geometry import focal_from_vfov, intrinsic_matrix, rotation_from_axis_angle
from stereogeo_cli.synth.config import SynthConfig

WORLD_UP = np.array([0.0, 0.0, 1.0])
MAX_FOCAL_RATIO = 2.5  # largest ratio between the two focal lengths of a rig


@dataclass(frozen=True)
class Camera:
    """A pinhole camera placed in the world. Units: pixels for the image, metres for the position."""

    width: int
    height: int
    focal: float  # pixels, fx (= fy unless ``aspect`` says otherwise)
    R_wc: np.ndarray  # [3 x 3] world → camera (OpenCV axes)
    center: np.ndarray  # [3] camera centre in world coordinates, metres
    aspect: float = 1.0  # fy / fx
    principal: tuple[float, float] | None = None  # (cx, cy) in pixels; None: (w/2, h/2)

    @property
    def fy(self) -> float:
        return self.focal * self.aspect if self.aspect != 1.0 else self.focal

    @property
    def cx_cy(self) -> tuple[float, float]:
        return self.principal if self.principal is not None else (self.width / 2.0, self.height / 2.0)

    @property
    def K(self) -> np.ndarray:
        if self.aspect == 1.0 and self.principal is None:
            return intrinsic_matrix(self.focal, self.width, self.height)
        cx, cy = self.cx_cy
        return np.array([[self.focal, 0.0, cx], [0.0, self.fy, cy], [0.0, 0.0, 1.0]])

    @property
    def gravity_up(self) -> np.ndarray:
        """World up in camera coordinates [3] (the project's gravity convention)."""
        return self.R_wc @ WORLD_UP

    def project(self, X_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates [N x 2] and depths z [N] of world points [N x 3]."""
        Xc = (np.asarray(X_world, dtype=float) - self.center) @ self.R_wc.T
        z = Xc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = np.array([self.focal, self.fy]) * Xc[:, :2] / z[:, None] + np.array(self.cx_cy)
        return xy, z

    def to_calib(self) -> dict:
        """The camera object of a calib.jsonl record: K, an empty ``dist``, the size and the up vector
        (docs/synth.md, "What it writes")."""
        return {
            "K": self.K.tolist(),
            "dist": [],
            "width": int(self.width),
            "height": int(self.height),
            "gravity_up": [float(v) for v in self.gravity_up],
        }


@dataclass(frozen=True)
class Rig:
    """Two cameras and their relative pose: ``X_right = R @ X_left + T`` (T in metres)."""

    left: Camera
    right: Camera

    @property
    def R(self) -> np.ndarray:
        return self.right.R_wc @ self.left.R_wc.T

    @property
    def T(self) -> np.ndarray:
        return self.right.R_wc @ (self.left.center - self.right.center)


def _rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def camera_rotation(yaw: float, roll: float, pitch: float) -> np.ndarray:
    """R_wc [3 x 3] of a camera looking towards azimuth ``yaw`` (radians from east towards north).

    Its gravity_up equals ``gravity_from_roll_pitch(roll, pitch)`` exactly.
    """
    c, s = np.cos(yaw), np.sin(yaw)
    level = np.array([[s, -c, 0.0], [0.0, 0.0, -1.0], [c, s, 0.0]])  # rows: camera x, y, z in world
    return _rot_z(-roll) @ _rot_x(-pitch) @ level


def sample_image_size(rng: np.random.Generator, cfg: SynthConfig) -> tuple[int, int]:
    """(width, height) in pixels: short side ``cfg.short_side``, an aspect from the list, some portrait."""
    aspect = float(cfg.aspects[rng.integers(len(cfg.aspects))])
    long_side = int(2 * round(cfg.short_side * aspect / 2))
    if rng.random() < cfg.portrait_share:
        return cfg.short_side, long_side
    return long_side, cfg.short_side


def sample_vfovs(
    rng: np.random.Generator, cfg: SynthConfig, low_deg: float | None = None
) -> tuple[float, float]:
    """vFoV of the left and right cameras in radians; equal for a share of pairs."""
    lo = max(cfg.vfov_deg[0], low_deg) if low_deg is not None else cfg.vfov_deg[0]
    hi = max(lo, cfg.vfov_deg[1])
    left = rng.uniform(lo, hi)
    right = left if rng.random() < cfg.equal_fov_share else rng.uniform(lo, hi)
    # keep the focal lengths within a factor MAX_FOCAL_RATIO (e.g. a phone's wide and tele cameras)
    t_left, t_right = np.tan(np.radians(left) / 2), np.tan(np.radians(right) / 2)
    t_right = np.clip(t_right, t_left / MAX_FOCAL_RATIO, t_left * MAX_FOCAL_RATIO)
    right = float(np.clip(np.degrees(2 * np.arctan(t_right)), lo, hi))
    return float(np.radians(left)), float(np.radians(right))


def sample_attitude(rng: np.random.Generator, cfg: SynthConfig) -> tuple[float, float]:
    """(roll, pitch) of the rig in radians: a share near level, the rest uniform within ±max_angle."""
    limit = np.radians(cfg.max_angle_deg)
    if rng.random() < cfg.level_share:
        roll, pitch = rng.normal(0.0, np.radians(2.0), size=2)
    else:
        roll, pitch = rng.uniform(-limit, limit, size=2)
    return float(np.clip(roll, -limit, limit)), float(np.clip(pitch, -limit, limit))


def sample_relative_pose(rng: np.random.Generator, cfg: SynthConfig) -> tuple[np.ndarray, np.ndarray]:
    """(R, offset): the right camera's rotation relative to the left, and its centre in left coordinates.

    The baseline |offset| is log-uniform in ``cfg.baseline_m``; the offset points along the left camera's
    x axis up to a few degrees. R is the identity for a share of rigs, otherwise a toe-in (rotation mostly
    about the vertical axis) of up to ``cfg.toe_in_deg`` with smaller pitch and roll parts.
    """
    lo, hi = np.log(cfg.baseline_m[0]), np.log(cfg.baseline_m[1])
    baseline = float(np.exp(rng.uniform(lo, hi)))
    direction = np.array([1.0, *rng.normal(0.0, 0.03, size=2)])
    offset = baseline * direction / np.linalg.norm(direction)
    if rng.random() < cfg.parallel_share:
        return np.eye(3), offset
    limit = np.radians(cfg.toe_in_deg)
    rotvec = np.array(
        [rng.uniform(-limit, limit) / 3, rng.uniform(-limit, limit), rng.uniform(-limit, limit) / 3]
    )
    return rotation_from_axis_angle(rotvec), offset


@dataclass(frozen=True)
class RigSample:
    """The camera-side draws of one pair, before it is placed in a scene."""

    width: int
    height: int
    vfov_left: float  # radians
    vfov_right: float  # radians
    roll: float  # radians, of the left camera
    pitch: float  # radians, of the left camera
    R: np.ndarray  # [3 x 3] left → right
    offset: np.ndarray  # [3] right camera centre in left camera coordinates, metres

    @property
    def baseline(self) -> float:
        return float(np.linalg.norm(self.offset))

    def place(self, center_left: np.ndarray, yaw: float) -> Rig:
        """The rig with its left camera at ``center_left`` (world, metres) looking towards ``yaw``."""
        R_wl = camera_rotation(yaw, self.roll, self.pitch)
        left = Camera(
            self.width,
            self.height,
            float(focal_from_vfov(self.vfov_left, self.height)),
            R_wl,
            np.asarray(center_left, dtype=float),
        )
        R_wr = self.R @ R_wl
        center_right = left.center + R_wl.T @ self.offset
        right = Camera(
            self.width, self.height, float(focal_from_vfov(self.vfov_right, self.height)), R_wr, center_right
        )
        return Rig(left, right)


def sample_rig(rng: np.random.Generator, cfg: SynthConfig, vfov_low_deg: float | None = None) -> RigSample:
    """Image size, fields of view, attitude and relative pose of one pair."""
    width, height = sample_image_size(rng, cfg)
    vfov_left, vfov_right = sample_vfovs(rng, cfg, vfov_low_deg)
    roll, pitch = sample_attitude(rng, cfg)
    R, offset = sample_relative_pose(rng, cfg)
    return RigSample(width, height, vfov_left, vfov_right, roll, pitch, R, offset)
