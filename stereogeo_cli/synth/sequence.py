"""Rendered stereo sequences: one rig moving through one scene, with exact ground truth for every frame.

A sequence is ``frames`` pairs of one rig (fixed intrinsics, fixed left → right pose) driving straight,
turning along an arc, swept by hand, standing still in a scene of :mod:`stereogeo_cli.synth.scenes`, or
driving along a road like a car (``drive``, :mod:`stereogeo_cli.synth.traffic`). Effects of real recordings
(an off-centre principal point, fx ≠ fy, H.264, exposure changes, motion blur, moving cars and people) are
each off unless asked for (:mod:`stereogeo_cli.synth.effects`).
The folder it writes has the layout of the real sequences (``left/``, ``right/``, ``calib.json``), and
:func:`read_sequence_ground_truth` reads both (docs/synth.md, "Sequences").

Conventions (the project's): the camera frame is OpenCV's (x right, y down, z forward); pixel (0, 0) is
the centre of the top-left pixel and the principal point is exactly (w/2, h/2) unless an effect moves it;
``x_right = R · x_left + T`` in metres; ``gt_poses`` are the left camera's camera-to-world 4 × 4 matrices
in the scene's world frame (x east, y north, z up, metres), so the world's up is (0, 0, 1).

The motion is defined over the whole sequence: ``frames`` only sets how densely it is sampled (a
5-frame sequence turns as far as a 50-frame one), except for ``drive``, which is recorded at 10 Hz like a
car's rig and so lasts (frames − 1) / 10 s. The rig depends only on the seed and the config, so the four
motions of one seed share image size, focal lengths, baseline and R (a desk scene redraws a shorter
baseline; a drive, with its own config, has a car's rig).
"""

from __future__ import annotations

import json
import re
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.geometry import (
    axis_angle_from_rotation,
    roll_pitch_from_gravity,
    rotation_angle,
    rotation_from_axis_angle,
)
from stereogeo_cli.io.text import plural
from stereogeo_cli.synth.config import SynthConfig
from stereogeo_cli.synth.effects import (
    SequenceEffects,
    apply_gain,
    exposure_gains,
    mean_image,
    subframe_times,
    with_intrinsics,
)
from stereogeo_cli.synth.rigs import WORLD_UP, Camera, Rig, RigSample, sample_image_size, sample_relative_pose

MOTIONS = ("straight", "turning", "handheld", "static", "drive")
# scene kinds per motion: (indoor, outdoor); handheld indoor becomes "desk" for config.close_share
MOTION_SCENES = {
    "straight": ("corridor", "street"),
    "turning": ("room", "open"),
    "handheld": ("room", "street"),
    "static": ("room", "street"),
    "drive": ("road", "road"),
}
DURATION_S = {"straight": 5.0, "turning": 6.0, "handheld": 5.0, "static": 5.0}  # time the motion spans
DRIVE_RATE_HZ = 10.0  # a drive is recorded at this rate (its duration follows from the frames)
# a drive's rig: a car's wide stereo images (1240 × 376, as KITTI's: at half that size calibrate-sequence
# mapped a rendered drive from too few points to read its focal length), vFoV 27–33°, a horizontal baseline
# of 0.45–0.6 m, mounted within ±2° of level
DRIVE_CONFIG = {
    "short_side": 376,
    "aspects": (1240 / 376,),
    "vfov_deg": (27.0, 33.0),
    "baseline_m": (0.45, 0.6),
    "max_angle_deg": 2.0,
}
RIG_ROTATION_DEG = (0.5, 2.0)  # angle of the left → right rotation, degrees
PATH_CLEARANCE_M = 0.25  # every camera centre on the path keeps this far from every surface (desk: half)
ATTEMPTS = 60  # scene placements tried before giving up
GENERATOR = "stereogeo make-data --sequence"


def sequence_config(motion: str | None = None, **changes) -> SynthConfig:
    """The sampler settings a sequence uses by default: 640 × 480 (4:3, landscape), vFoV 45–80°, baseline
    0.1–0.5 m, rig roll and pitch within ±5°, photometric changes at half strength (the images keep
    their contrast for feature matching); for ``motion`` "drive" a car's rig (DRIVE_CONFIG); ``changes``
    override them."""
    base = SynthConfig(
        short_side=480,
        aspects=(4 / 3,),
        portrait_share=0.0,
        vfov_deg=(45.0, 80.0),
        baseline_m=(0.1, 0.5),
        max_angle_deg=5.0,
        panorama_share=0.0,
        augment=0.5,
    )
    if motion == "drive":
        base = base.replace(**DRIVE_CONFIG)
    return base.replace(**changes)


def motion_duration(motion: str, frames: int, rate_hz: float | None = None) -> float:
    """Seconds the motion spans: (frames − 1) frames at ``rate_hz`` where it is given (one frame: one
    frame's time), else fixed per motion (DURATION_S), or for a drive (frames − 1) frames at DRIVE_RATE_HZ."""
    if rate_hz is not None:
        if not rate_hz > 0:
            raise StereoGeoError(f"a sequence's frame rate must be > 0 Hz, not {rate_hz:g}")
        return max(frames - 1, 1) / float(rate_hz)
    if motion == "drive":
        return max(frames - 1, 1) / DRIVE_RATE_HZ
    return DURATION_S[motion]


# --- the rig ----------------------------------------------------------------------------------------------


def sample_sequence_rig(seed: int, cfg: SynthConfig) -> RigSample:
    """The rig of a sequence seed: one image size and vFoV (the right camera's within ±3 % of the left's),
    roll and pitch uniform within ±``cfg.max_angle_deg``, a baseline log-uniform in ``cfg.baseline_m``
    along the left camera's x axis (as :func:`sample_relative_pose`), and a left → right rotation of
    0.5–2° (mostly about the vertical axis)."""
    rng = np.random.default_rng([seed, 0x5E9])
    width, height = sample_image_size(rng, cfg.replace(portrait_share=0.0))
    vfov_left = float(np.radians(rng.uniform(*cfg.vfov_deg)))
    vfov_right = float(vfov_left * np.clip(np.exp(rng.normal(0.0, 0.01)), 0.97, 1.03))
    limit = np.radians(cfg.max_angle_deg)
    roll, pitch = (float(v) for v in rng.uniform(-limit, limit, size=2))
    R, offset = sample_relative_pose(rng, cfg.replace(parallel_share=0.0, toe_in_deg=RIG_ROTATION_DEG[1]))
    rotvec = axis_angle_from_rotation(R)
    angle = float(np.linalg.norm(rotvec))
    lo, hi = np.radians(RIG_ROTATION_DEG)
    R = rotation_from_axis_angle(rotvec * np.clip(angle, lo, hi) / max(angle, 1e-12))
    return RigSample(width, height, vfov_left, vfov_right, roll, pitch, R, offset)


def rectified(sample: RigSample) -> RigSample:
    """The rig as a car's stereo camera delivers its images, rectified: both cameras one vFoV, no rotation
    between them (R = I) and the baseline along the left camera's x axis. The images of such a rig alone
    do not fix the focal length (only motion does), as on a real drive."""
    baseline = float(np.linalg.norm(sample.offset))
    return replace(sample, vfov_right=sample.vfov_left, R=np.eye(3), offset=np.array([baseline, 0.0, 0.0]))


def _rig_sample_of(rig: Rig, template: RigSample) -> tuple[RigSample, float]:
    """The RigSample (and the yaw) that places ``rig`` exactly: a scene builder may have changed the
    template's pitch or baseline, so they are read back from the placed cameras."""
    R_wl = rig.left.R_wc
    roll, pitch = roll_pitch_from_gravity(rig.left.gravity_up)
    forward = R_wl[2]  # the optical axis in world coordinates: (cos p cos yaw, cos p sin yaw, sin p)
    yaw = float(np.arctan2(forward[1], forward[0]))
    offset = R_wl @ (rig.right.center - rig.left.center)
    return replace(template, roll=float(roll), pitch=float(pitch), R=rig.R, offset=offset), yaw


# --- motions ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Motion:
    """A left-camera path relative to its start (the anchor, where the scene placed the rig).

    Positions are in the anchor's heading frame (x right, y forward, z up; horizontal axes; metres);
    yaw, roll and pitch are added to the anchor's (radians; yaw > 0 turns left). ``extent`` ∈ (0, 1]
    keeps the first part of a straight or turning path (the rest is the same path cut short).
    ``duration`` (seconds, None: the motion's DURATION_S) is the time a hand-held sweep's sinusoids span
    (the other motions are shaped over u, or, a drive, carry their duration in ``params``).
    """

    kind: str
    params: dict
    extent: float = 1.0
    duration: float | None = None

    def at(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(xyz [N x 3] metres, yaw [N], roll [N], pitch [N] radians) at sequence times ``u`` ∈ [0, 1] [N]."""
        u = np.asarray(u, dtype=float)
        p = self.params
        zero = np.zeros_like(u)
        if self.kind == "straight":
            s = u * self.extent * p["length_m"]  # distance driven, metres
            sway = np.sin(2 * np.pi * s / p["sway_wavelength_m"] + p["phase"]) - np.sin(p["phase"])
            x = p["sway_m"] * sway
            z = p["bob_m"] * np.sin(2 * np.pi * s / p["bob_wavelength_m"])
            yaw = p["yaw_drift_rad"] * np.sin(np.pi * s / p["length_m"])
            pitch = p["pitch_bump_rad"] * np.sin(2 * np.pi * s / p["bob_wavelength_m"])
            return np.stack([x, s, z], 1), yaw, zero, pitch
        if self.kind == "turning":
            theta = u * self.extent * p["span_rad"]  # heading change, > 0 turning left
            r = p["radius_m"]
            x = -np.sign(p["span_rad"]) * r * (1.0 - np.cos(theta))
            y = r * np.sin(np.abs(theta))
            z = p["bob_m"] * np.sin(2 * np.pi * np.abs(theta) * r / p["bob_wavelength_m"])
            return np.stack([x, y, z], 1), theta, zero, zero
        if self.kind == "handheld":
            t = u * (DURATION_S["handheld"] if self.duration is None else self.duration)
            dofs = [_smooth(t, p[name]) for name in ("x", "y", "z", "yaw", "roll", "pitch")]
            return np.stack(dofs[:3], 1), dofs[3], dofs[4], dofs[5]
        if self.kind == "drive":
            return _drive_at(p, u)
        return np.zeros((len(u), 3)), zero, zero, zero


def _drive_heading(p: dict, s: np.ndarray) -> np.ndarray:
    """A drive's heading (radians, > 0 left) after ``s`` metres: straight, then the curve (a smoothstep of
    ``turn_rad`` over its stretch of the drive), then straight again."""
    start, length = p["curve_start"] * p["length_m"], p["curve_length"] * p["length_m"]
    x = np.clip((s - start) / max(length, 1e-9), 0.0, 1.0)
    return p["turn_rad"] * x * x * (3.0 - 2.0 * x)


def _drive_at(p: dict, u: np.ndarray):
    """:meth:`Motion.at` of a drive: constant speed along the road, its heading integrated into the path
    (on a 5 cm grid, times outside the drive included, for motion blur), and the suspension's heave, pitch
    and roll as sinusoids."""
    t = u * p["duration_s"]
    s = p["speed_mps"] * t
    lo, hi = min(0.0, float(s.min())) - 1.0, max(p["length_m"], float(s.max())) + 1.0
    grid = np.linspace(lo, hi, int(np.ceil((hi - lo) / 0.05)) + 1)
    heading = _drive_heading(p, grid)
    step = np.diff(grid)
    x = np.concatenate([[0.0], np.cumsum(-(np.sin(heading[1:]) + np.sin(heading[:-1])) / 2 * step)])
    y = np.concatenate([[0.0], np.cumsum((np.cos(heading[1:]) + np.cos(heading[:-1])) / 2 * step)])
    x, y = np.interp(s, grid, x) - np.interp(0.0, grid, x), np.interp(s, grid, y) - np.interp(0.0, grid, y)

    def wave(name: str) -> np.ndarray:
        return p[f"{name}_amplitude"] * np.sin(2 * np.pi * p[f"{name}_hz"] * t + p[f"{name}_phase"])

    return np.stack([x, y, wave("heave")], 1), _drive_heading(p, s), wave("roll"), wave("pitch")


def _smooth(t: np.ndarray, spec: dict) -> np.ndarray:
    """A sum of sinusoids scaled to the peak ``spec["amplitude"]`` over the sequence's time [N] (seconds)."""
    total = np.zeros_like(t)
    for f, phase, weight in zip(spec["freq_hz"], spec["phase"], spec["weight"], strict=True):
        total += weight * np.sin(2 * np.pi * f * t + phase)
    return total * spec["amplitude"] / spec["peak"]


def _handheld_dof(rng: np.random.Generator, amplitude: float, duration: float) -> dict:
    """One degree of freedom of a hand-held sweep: two or three sinusoids of 0.12–0.5 Hz, scaled to the
    peak ``amplitude`` over ``duration`` seconds."""
    k = int(rng.integers(2, 4))
    spec = {
        "freq_hz": [float(v) for v in rng.uniform(0.12, 0.5, k)],
        "phase": [float(v) for v in rng.uniform(0, 2 * np.pi, k)],
        "weight": [float(v) for v in rng.uniform(0.4, 1.0, k)],
        "amplitude": 1.0,
        "peak": 1.0,
    }
    grid = np.linspace(0.0, duration, max(2001, int(np.ceil(duration * 400)) + 1))
    return {**spec, "amplitude": float(amplitude), "peak": float(np.max(np.abs(_smooth(grid, spec))))}


def _drive_params(rng: np.random.Generator, duration: float) -> dict:
    """A drive: 8–12 m/s, a curve of 6–12° to the left or right over 30–50 % of the drive, and the
    suspension's heave (0.5–1.5 cm at 1–2 Hz), pitch (0.15–0.4° at 0.8–1.6 Hz) and roll (0.1–0.3° at
    0.5–1.2 Hz)."""
    speed = float(rng.uniform(8.0, 12.0))
    params = {
        "duration_s": float(duration),
        "speed_mps": speed,
        "length_m": speed * float(duration),
        "turn_rad": float(np.radians(rng.uniform(6.0, 12.0)) * rng.choice([-1.0, 1.0])),
        "curve_start": float(rng.uniform(0.1, 0.5)),
        "curve_length": float(rng.uniform(0.3, 0.5)),
    }
    for name, amplitude, hz in (("heave", (0.005, 0.015), (1.0, 2.0)),
                                ("pitch", np.radians([0.15, 0.4]), (0.8, 1.6)),
                                ("roll", np.radians([0.1, 0.3]), (0.5, 1.2))):  # fmt: skip
        params[f"{name}_amplitude"] = float(rng.uniform(*amplitude))
        params[f"{name}_hz"] = float(rng.uniform(*hz))
        params[f"{name}_phase"] = float(rng.uniform(0, 2 * np.pi))
    return params


def sample_motion(
    rng: np.random.Generator, kind: str, outdoor: bool, duration: float | None = None
) -> Motion:
    """The motion's parameters (metres, radians; see :class:`Motion`); ``duration`` (seconds) for a drive
    (default one of 50 frames) and a hand-held sweep (default its DURATION_S); the other motions are shaped
    over the sequence whatever its time."""
    if kind == "straight":
        return Motion(
            kind,
            {
                "length_m": float(rng.uniform(15.0, 25.0) if outdoor else rng.uniform(4.0, 8.0)),
                "sway_m": float(rng.uniform(0.01, 0.05)),
                "sway_wavelength_m": float(rng.uniform(6.0, 15.0)),
                "phase": float(rng.uniform(0, 2 * np.pi)),
                "bob_m": float(rng.uniform(0.003, 0.01)),
                "bob_wavelength_m": float(rng.uniform(1.5, 4.0)),
                "yaw_drift_rad": float(np.radians(rng.uniform(-0.6, 0.6))),
                "pitch_bump_rad": float(np.radians(rng.uniform(0.02, 0.1))),
            },
        )
    if kind == "turning":
        return Motion(
            kind,
            {
                "radius_m": float(rng.uniform(4.0, 12.0) if outdoor else rng.uniform(1.0, 2.5)),
                "span_rad": float(np.radians(rng.uniform(65.0, 100.0)) * rng.choice([-1.0, 1.0])),
                "bob_m": float(rng.uniform(0.003, 0.01)),
                "bob_wavelength_m": float(rng.uniform(1.5, 4.0)),
            },
        )
    if kind == "handheld":
        amplitudes = {
            "x": rng.uniform(0.12, 0.25),  # the sweep, metres (peak to peak up to twice this)
            "y": rng.uniform(0.03, 0.1),
            "z": rng.uniform(0.03, 0.1),
            "yaw": np.radians(rng.uniform(10.0, 20.0)),
            "roll": np.radians(rng.uniform(8.0, 15.0)),
            "pitch": np.radians(rng.uniform(8.0, 15.0)),
        }
        span = DURATION_S["handheld"] if duration is None else float(duration)
        return Motion(
            kind, {name: _handheld_dof(rng, a, span) for name, a in amplitudes.items()}, duration=span
        )
    if kind == "static":
        return Motion(kind, {})
    if kind == "drive":
        return Motion(
            kind, _drive_params(rng, motion_duration("drive", 50) if duration is None else duration)
        )
    raise StereoGeoError(f"unknown sequence motion {kind!r}; choose from {', '.join(MOTIONS)}")


def long_enough(motion: Motion) -> bool:
    """Whether a path cut short (``motion.extent`` < 1) still shows its motion: ≥ 60 % of a straight
    drive, ≥ 60° of a turn; hand-held sweeps and static rigs are never cut."""
    if motion.kind == "straight":
        return motion.extent >= 0.6
    if motion.kind == "turning":
        return abs(motion.extent * motion.params["span_rad"]) >= np.radians(60.0)
    return motion.extent >= 1.0


def frame_rigs(motion: Motion, rig_sample: RigSample, anchor: Rig, u: np.ndarray) -> list[Rig]:
    """The rig at sequence times ``u`` [N]: the motion applied to the anchor, each placed by
    :meth:`RigSample.place` (so gravity, R and T follow the project's conventions exactly)."""
    base, yaw0 = _rig_sample_of(anchor, rig_sample)
    xyz, yaw, roll, pitch = motion.at(u)
    forward = np.array([np.cos(yaw0), np.sin(yaw0), 0.0])
    right = np.array([np.sin(yaw0), -np.cos(yaw0), 0.0])
    heading = np.stack([right, forward, WORLD_UP], 1)  # [3 x 3] columns: local x, y, z in the world
    centers = anchor.left.center + xyz @ heading.T
    return [
        replace(base, roll=base.roll + float(r), pitch=base.pitch + float(p)).place(c, yaw0 + float(y))
        for c, y, r, p in zip(centers, yaw, roll, pitch, strict=True)
    ]


# --- clearance of the path ----------------------------------------------------------------------------


def _triangles(scene) -> np.ndarray:
    """All triangles of a scene [T x 3 x 3] (surfaces and windows), metres, float64."""
    parts = [scene.surfaces[:, :3].reshape(-1, 3, 3), scene.windows.reshape(-1, 3, 3)]
    return np.concatenate(parts).astype(np.float64)


def distance_to_triangles(
    points: np.ndarray, triangles: np.ndarray, max_distance: float = np.inf, chunk: int = 32
) -> np.ndarray:
    """Euclidean distance [P] of points [P x 3] to the nearest of the triangles [T x 3 x 3], metres,
    capped at ``max_distance`` (triangles whose bounding box is farther than that from a chunk of points
    are skipped, which makes the check of a path cheap)."""
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    n = np.cross(b - a, c - a)
    area = np.linalg.norm(n, axis=1)
    keep = area > 1e-12
    a, b, c, n = a[keep], b[keep], c[keep], n[keep] / area[keep, None]
    lo, hi = np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)

    def segment(p, s0, s1):  # [P x T] distances of points [P x 1 x 3] to segments [T x 3]
        d = s1 - s0
        t = np.einsum("ptk,tk->pt", p - s0, d) / np.maximum(np.einsum("tk,tk->t", d, d), 1e-24)
        return np.linalg.norm(p - s0 - np.clip(t, 0, 1)[..., None] * d, axis=-1)

    out = np.full(len(points), float(max_distance))
    for i in range(0, len(points), chunk):
        p = np.asarray(points[i : i + chunk], dtype=np.float64)
        near = np.all((lo <= p.max(axis=0) + max_distance) & (hi >= p.min(axis=0) - max_distance), axis=1)
        if not near.any():
            continue
        ta, tb, tc, tn = a[near], b[near], c[near], n[near]
        p = p[:, None, :]
        height = np.einsum("ptk,tk->pt", p - ta, tn)  # signed distance to each plane
        q = p - height[..., None] * tn  # the projection onto the plane
        inside = np.ones(height.shape, bool)
        for s0, s1 in ((ta, tb), (tb, tc), (tc, ta)):
            inside &= np.einsum("ptk,tk->pt", np.cross(s1 - s0, q - s0), tn) >= 0
        edges = np.minimum(np.minimum(segment(p, ta, tb), segment(p, tb, tc)), segment(p, tc, ta))
        d = np.where(inside, np.abs(height), edges).min(axis=1)
        out[i : i + chunk] = np.minimum(d, max_distance)
    return out


def free_extent(motion: Motion, rig_sample: RigSample, anchor: Rig, triangles: np.ndarray, clearance: float):
    """How much of the motion's path (a fraction in [0, 1]) both cameras travel at least ``clearance``
    metres from every surface. The path is sampled at 401 points less than 2·clearance apart, so it cannot
    pass through a surface between two samples unnoticed (the crossing would be nearer than clearance to
    one of them). A long drive is sampled more densely, as finely as that needs."""
    u = np.linspace(0.0, 1.0, 401)
    rigs = frame_rigs(motion, rig_sample, anchor, u)
    centers = np.array([[r.left.center, r.right.center] for r in rigs])  # [N x 2 x 3]
    step = np.linalg.norm(np.diff(centers, axis=0), axis=-1).max() if len(u) > 1 else 0.0
    if step > clearance:
        u = np.linspace(0.0, 1.0, int(np.ceil(400 * step / clearance)) + 1)
        rigs = frame_rigs(motion, rig_sample, anchor, u)
        centers = np.array([[r.left.center, r.right.center] for r in rigs])
        step = np.linalg.norm(np.diff(centers, axis=0), axis=-1).max()
    if step > 2 * clearance:  # pragma: no cover - the motions move far less per sample
        raise StereoGeoError("internal: the path sampling is too coarse for its clearance check")
    distance = distance_to_triangles(centers.reshape(-1, 3), triangles, 2 * clearance)
    near = distance.reshape(-1, 2).min(axis=1) < clearance
    return 1.0 if not near.any() else float(u[max(int(np.argmax(near)) - 1, 0)])


# --- planning and rendering -------------------------------------------------------------------------------


@dataclass
class SequencePlan:
    """Everything a sequence's frames are rendered from: the scene, the rig per frame, the calib.json."""

    motion: Motion
    scene: object  # scenes.Scene (its movers included)
    rigs: list[Rig]
    timestamps: np.ndarray  # [N] seconds
    sky_index: int
    sky_yaw: float
    calib: dict
    seed: int
    config: SynthConfig
    renderer: object  # render.Renderer
    vaos: list
    rig_sample: RigSample | None = None  # the rig's template (to place it at times between frames)
    effects: SequenceEffects = field(default_factory=SequenceEffects)
    duration: float = 5.0  # seconds the motion spans
    gains: np.ndarray | None = None  # [N x 2] per-frame exposure gains (left, right), or None

    def rigs_at(self, times: np.ndarray) -> list[Rig]:
        """The rig at any times [N] (seconds; between frames or a little outside the sequence)."""
        u = np.asarray(times, dtype=float) / self.duration
        rigs = frame_rigs(self.motion, self.rig_sample, self.scene.rig, u)
        return [with_intrinsics(r, self.effects, self.seed) for r in rigs]

    def release(self) -> None:
        self.renderer.release(self.vaos)
        self.vaos = []


def _is_planar(depth: np.ndarray, focal: float, tolerance: float = 0.05, share: float = 0.15) -> bool:
    """Whether a view is one plane (a wall filling it): fewer than ``share`` of its points [H x W z-depth,
    metres; 0 = nothing] lie farther than ``tolerance`` × their median depth from their best-fit plane."""
    h, w = depth.shape
    ys, xs = np.nonzero(depth > 0)
    z = depth[ys, xs].astype(np.float64)
    X = np.stack([(xs - w / 2) * z / focal, (ys - h / 2) * z / focal, z], 1)
    centered = X - X.mean(axis=0)
    normal = np.linalg.svd(centered, full_matrices=False)[2][-1]
    return float(np.mean(np.abs(centered @ normal) > tolerance * np.median(z))) < share


def _views_are_usable(renderer, scene, vaos, rigs: list[Rig], sky_index: int, sky_yaw: float) -> bool:
    """Six frames spread over the sequence: each left view sees surfaces over ≥ half of it, mostly ≥ 1.2 m
    away (0.3 m at a desk), not one plane alone, with corners to match (sample.py's MIN_CORNER_DENSITY)."""
    from stereogeo_cli.synth.sample import MIN_CORNER_DENSITY, corner_density

    near = 0.3 if scene.kind == "desk" else 1.2
    for k in np.unique(np.linspace(0, len(rigs) - 1, 6).round().astype(int)):
        cam = rigs[k].left
        small = Camera(max(cam.width // 4, 8), max(cam.height // 4, 6), cam.focal / 4, cam.R_wc, cam.center)
        depth = renderer.render_depth(small, scene, vaos)
        seen = depth[depth > 0]
        if seen.size < 0.5 * depth.size or np.median(seen) < near or _is_planar(depth, small.focal):
            return False
        if corner_density(renderer.render_color(cam, sky_index, sky_yaw, scene, vaos)) < MIN_CORNER_DENSITY:
            return False
    return True


def _draw_scene(motion, seed, rng, cfg, renderer, rig_sample, u, duration, intrinsics):
    """Scenes and paths drawn until one fits (see :func:`plan_sequence`): (motion, scene, rigs, sky index,
    sky yaw, vertex arrays, attempts). ``intrinsics`` maps a placed rig to the rig the frames render."""
    from stereogeo_cli.synth.scenes import build_scene
    from stereogeo_cli.synth.traffic import build_road

    for attempt in range(ATTEMPTS):
        outdoor = bool(rng.random() < cfg.outdoor_share) or motion == "drive"
        kind = MOTION_SCENES[motion][int(outdoor)]
        if kind == "room" and motion == "handheld" and rng.random() < cfg.close_share:
            kind = "desk"
        choices = renderer.sky_choices["outdoor" if outdoor else "window"]
        sky_index = choices[min(int(rng.random() * len(choices)), len(choices) - 1)]
        sky_yaw = float(rng.random())
        plan_motion = sample_motion(rng, motion, outdoor, duration)
        if kind == "road":  # the road is built along the drive's own path
            track = plan_motion.at(np.linspace(0.0, 1.0, 401))[0][:, :2]
            scene = build_road(rng, rig_sample, renderer.materials, track)
        else:
            scene = build_scene(rng, rig_sample, renderer.materials, kind, baseline_m=cfg.baseline_m)
        clearance = PATH_CLEARANCE_M / 2 if kind == "desk" else PATH_CLEARANCE_M
        extent = free_extent(plan_motion, rig_sample, scene.rig, _triangles(scene), clearance)
        if extent < 1.0:
            plan_motion = replace(plan_motion, extent=0.95 * extent)
            if not long_enough(plan_motion):
                continue
        rigs = frame_rigs(plan_motion, rig_sample, scene.rig, u)
        vaos = renderer.upload(scene)
        if attempt < ATTEMPTS - 1 and not _views_are_usable(renderer, scene, vaos, rigs, sky_index, sky_yaw):
            renderer.release(vaos)
            continue
        # the views are judged with the ideal intrinsics, so an effect on K never changes the scene drawn
        return plan_motion, scene, [intrinsics(r) for r in rigs], sky_index, sky_yaw, vaos, attempt + 1
    raise StereoGeoError(f"no {motion} path fits a scene after {ATTEMPTS} tries (seed {seed})")


def _with_movers(scene, count: int, stream: list, materials, plan_motion, rig_sample, timestamps, duration):
    """The scene with ``count`` cars and people moving on their own (traffic.place_movers; its own random
    stream, so the scene and the path stay those of the same seed without them)."""
    from stereogeo_cli.synth.traffic import place_movers

    rng = np.random.default_rng([*stream, 0xEFF, 3])
    triangles = _triangles(scene)

    def rigs_at(times):
        return frame_rigs(plan_motion, rig_sample, scene.rig, np.asarray(times, dtype=float) / duration)

    def distance(points):
        return distance_to_triangles(points, triangles, 2.0)

    return replace(scene, movers=place_movers(rng, scene, materials, count, timestamps, rigs_at, distance))


def plan_sequence(
    motion: str,
    frames: int,
    seed: int,
    config: SynthConfig | None = None,
    effects: SequenceEffects | None = None,
    rate_hz: float | None = None,
) -> SequencePlan:
    """Build the scene and the per-frame rigs of sequence (motion, seed) and its calib.json record.

    Scenes are drawn until the whole path keeps clear of every surface (a straight or turning path may be
    cut short where it meets an obstacle, see ``long_enough``) and the views are usable
    (``_views_are_usable``). ``effects`` (default: none) add the effects of real recordings.
    ``rate_hz``: the frame rate; the motion then spans (frames − 1) / rate_hz seconds (default: the
    motion's own time, see :func:`motion_duration`). Call ``release()`` on the plan when its frames are
    rendered.
    """
    from stereogeo_cli.synth.sample import get_renderer

    if motion not in MOTIONS:
        raise StereoGeoError(f"unknown sequence motion {motion!r}; choose from {', '.join(MOTIONS)}")
    if frames < 1:
        raise StereoGeoError("a sequence needs at least one frame (-n ≥ 1)")
    cfg = config or sequence_config(motion)
    effects = effects or SequenceEffects()
    renderer = get_renderer(seed, cfg)
    rig_sample = sample_sequence_rig(seed, cfg)
    if motion == "drive":
        rig_sample = rectified(rig_sample)
    stream = [seed, 0x5E9, MOTIONS.index(motion) + 1]
    rng = np.random.default_rng(stream)
    u = np.linspace(0.0, 1.0, frames) if frames > 1 else np.zeros(1)
    duration = motion_duration(motion, frames, rate_hz)

    def intrinsics(rig: Rig) -> Rig:
        return with_intrinsics(rig, effects, seed)

    plan_motion, scene, rigs, sky_index, sky_yaw, vaos, attempts = _draw_scene(
        motion, seed, rng, cfg, renderer, rig_sample, u, duration, intrinsics
    )
    timestamps = u * duration if rate_hz is None else np.arange(frames) / float(rate_hz)
    if effects.moving_objects:
        args = (renderer.materials, plan_motion, rig_sample, timestamps, duration)
        scene = _with_movers(scene, effects.moving_objects, stream, *args)
    calib = _calib(motion, seed, cfg, plan_motion, rig_sample, scene, rigs, timestamps, attempts, duration)
    if rate_hz is not None:
        calib["extra"]["rate_hz"] = float(rate_hz)
    calib["extra"]["sky"] = renderer.sky_name(sky_index)
    gains = exposure_gains(seed, MOTIONS.index(motion) + 1, timestamps, effects.exposure_stops)
    if effects.active:
        _record_effects(calib, effects, seed, scene, gains)
    return SequencePlan(
        plan_motion, scene, rigs, timestamps, sky_index, sky_yaw, calib, seed, cfg, renderer, vaos,
        rig_sample, effects, duration, gains,
    )  # fmt: skip


def _pose(camera: Camera) -> np.ndarray:
    """Camera-to-world [4 x 4] of a camera (OpenCV axes)."""
    P = np.eye(4)
    P[:3, :3] = camera.R_wc.T
    P[:3, 3] = camera.center
    return P


def _intrinsics_note(cam: Camera) -> str:
    if cam.principal is None and cam.aspect == 1.0:
        return "principal point exactly (w/2, h/2)"
    (cx, cy), (mx, my) = cam.cx_cy, (cam.width / 2, cam.height / 2)
    return (
        f"principal point ({cx:g}, {cy:g}) where the image centre is ({mx:g}, {my:g}), fy/fx {cam.aspect:g}"
    )


def _calib(motion, seed, cfg, plan_motion, rig_sample, scene, rigs, timestamps, attempts, duration) -> dict:
    first = rigs[0]

    def camera(cam: Camera) -> dict:
        return {"K": cam.K.tolist(), "dist": [], "width": int(cam.width), "height": int(cam.height)}

    poses = np.array([_pose(r.left) for r in rigs])
    centers = poses[:, :3, 3]
    spans = [rotation_angle(poses[0, :3, :3].T @ P[:3, :3]) for P in poses]
    roll, pitch = np.degrees(roll_pitch_from_gravity(np.array([r.left.gravity_up for r in rigs])))
    settings = {
        k: (str(v) if isinstance(v, Path) else list(v) if isinstance(v, tuple) else v)
        for k, v in asdict(cfg).items()
    }
    rate = (len(rigs) - 1) / duration if len(rigs) > 1 else 0.0
    return {
        "left": camera(first.left),
        "right": camera(first.right),
        "R": first.R.tolist(),
        "T": [float(v) for v in first.T],
        "timestamps": [float(t) for t in timestamps],
        "gt_poses": poses.tolist(),
        "gravity_up_world": [float(v) for v in WORLD_UP],
        "motion": motion,
        "seed": int(seed),
        "scene": scene.kind,
        "extra": {
            "generator": GENERATOR,
            "world": "the scene's frame: x east, y north, z up, metres",
            "frames": len(rigs),
            "rate_hz": float(rate),
            "duration_s": duration,
            "vfov_deg": [float(np.degrees(rig_sample.vfov_left)), float(np.degrees(rig_sample.vfov_right))],
            "baseline_m": float(np.linalg.norm(first.T)),
            "rig_rotation_deg": float(np.degrees(rotation_angle(first.R))),
            "roll_deg": [float(v) for v in roll],
            "pitch_deg": [float(v) for v in pitch],
            "path_length_m": float(np.linalg.norm(np.diff(centers, axis=0), axis=1).sum()),
            "translation_span_m": float(np.linalg.norm(centers[:, None] - centers[None], axis=-1).max()),
            "rotation_span_deg": float(np.degrees(max(spans))),
            "motion_params": {**plan_motion.params, "extent": plan_motion.extent},
            "scene_attempts": int(attempts),
            "depth": "depth/left|right/<frame>.npy: float32 z-depth, metres (0 = sky)" if cfg.depth else None,
            "config": settings,
        },
        "notes": (
            f"{GENERATOR} {motion}, seed {seed}, scene {scene.kind}: rendered, undistorted pinhole, "
            f"{_intrinsics_note(first.left)} with pixel (0, 0) the centre of the top-left pixel"
        ),
    }


def _record_effects(calib: dict, effects: SequenceEffects, seed: int, scene, gains) -> None:
    """calib.json's record of the effects that are on: ``extra.effects`` (the options, a random principal
    point offset as drawn), ``extra.moving_objects``, ``extra.exposure_gain`` [N x 2], ``extra.h264``, and
    a line in the notes."""
    from stereogeo_cli.synth.effects import BLUR_SUBFRAMES
    from stereogeo_cli.synth.video import PRESET

    extra = calib["extra"]
    extra["effects"] = effects.to_json(seed)
    said = []
    if effects.changes_intrinsics():
        said.append("an off-ideal K (principal point, fy/fx)")
    if effects.h264_kbps is not None:
        video = ["left.mp4", "right.mp4"] if effects.keep_video else None
        extra["h264"] = {"kbps": effects.h264_kbps, "encoder": "libx264 (PyAV)", "preset": PRESET,
                         "pix_fmt": "yuv420p", "video": video}  # fmt: skip
        said.append(f"frames through H.264 at {effects.h264_kbps:g} kbit/s")
    if gains is not None:
        extra["exposure_gain"] = gains.tolist()
        said.append(f"exposure drifting by up to ±{effects.exposure_stops:g} stops")
    if effects.motion_blur_ms > 0:
        extra["motion_blur_subframes"] = BLUR_SUBFRAMES
        said.append(f"motion blur over {effects.motion_blur_ms:g} ms (poses at mid-exposure)")
    if effects.moving_objects:
        extra["moving_objects"] = [
            {"kind": m.kind, "size_m": [float(v) for v in m.size], "speed_mps": float(m.speed)}
            for m in scene.movers
        ]
        said.append(f"{len(scene.movers)} objects moving on their own")
    calib["notes"] += "; effects: " + ", ".join(said)


def _mover_vaos(plan: SequencePlan, t: float) -> list:
    """Vertex arrays of the scene's moving objects at time ``t`` (none without them); release after use."""
    if not plan.scene.movers:
        return []
    surfaces = np.concatenate([m.surfaces(t) for m in plan.scene.movers])
    alone = replace(plan.scene, surfaces=surfaces, windows=np.zeros((0, 3), np.float32), movers=())
    return plan.renderer.upload(alone)


def _render_views(plan: SequencePlan, index: int) -> list[np.ndarray]:
    """The two colour images of frame ``index`` before photometry: one render at the frame's time, or the
    mean of sub-frame renders over the exposure with motion blur."""
    r, t = plan.renderer, float(plan.timestamps[index])
    still = plan.motion.kind == "static" and not plan.scene.movers
    if plan.effects.motion_blur_ms > 0 and not still:
        times = subframe_times(t, plan.effects.motion_blur_ms)
        rigs = plan.rigs_at(times)
    else:
        times, rigs = [t], [plan.rigs[index]]
    views: list[list[np.ndarray]] = [[], []]
    for time, rig in zip(times, rigs, strict=True):
        extra = _mover_vaos(plan, time)
        for side, camera in enumerate((rig.left, rig.right)):
            views[side].append(
                r.render_color(camera, plan.sky_index, plan.sky_yaw, plan.scene, plan.vaos + extra)
            )
        r.release(extra)
    return [v[0] if len(v) == 1 else mean_image(v) for v in views]


def render_frame(plan: SequencePlan, index: int, stream: int = 0):
    """Frame ``index``: (left, right [H x W x 3] uint8 RGB, depth_left, depth_right [H x W] float32 or None).

    Photometric changes (``config.augment``) are one draw per camera for the whole sequence (exposure,
    gamma, white balance; no blur) and new sensor noise per frame (``stream``: the frame whose noise is
    used; a static sequence uses frame 0's for every frame). The effects' exposure drift scales each
    frame before that, and motion blur and moving objects are rendered in (depth at the frame's time).
    """
    from stereogeo_cli.synth.sample import Exposure, augment

    cfg, rig, r = plan.config, plan.rigs[index], plan.renderer
    base = [plan.seed, 0x5E9, MOTIONS.index(plan.motion.kind) + 1]
    exposure = Exposure.sample(np.random.default_rng([*base, 2]), cfg.augment)
    images = []
    for side, image in enumerate(_render_views(plan, index)):
        if plan.gains is not None:
            image = apply_gain(image, float(plan.gains[index, side]))
        camera_rng = np.random.default_rng([*base, 3, side])
        noise_rng = np.random.default_rng([*base, 4, side, stream])
        images.append(augment(camera_rng, image, cfg.augment, exposure, noise_rng=noise_rng, blur_share=0.0))
    depths = [None, None]
    if cfg.depth:
        extra = _mover_vaos(plan, float(plan.timestamps[index]))
        depths = [r.render_depth(c, plan.scene, plan.vaos + extra) for c in (rig.left, rig.right)]
        r.release(extra)
    return images[0], images[1], depths[0], depths[1]


# --- writing ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SequenceSummary:
    folder: Path
    frames: int
    motion: str
    scene: str


_FRAME_FILE = re.compile(r"^\d{6}\.(png|npy)$")
_VIDEO_FILES = ("left.mp4", "right.mp4")  # written with --h264 --keep-video


def _holds_only_frames(folder: Path) -> bool:
    """Whether ``folder`` holds nothing but left/, right/ and depth/ with frame files, and videos (an
    interrupted run)."""
    for entry in folder.iterdir():
        if entry.is_file() and (entry.name in _VIDEO_FILES or entry.name.startswith(".tmp-")):
            continue
        if entry.name not in ("left", "right", "depth") or not entry.is_dir():
            return False
        for path in entry.rglob("*"):
            if path.is_file() and not (_FRAME_FILE.match(path.name) or path.name.startswith(".tmp-")):
                return False
    return True


def _prepare_folder(folder: Path) -> None:
    """Make the folder; refuse one that holds something other than a sequence this command wrote (or
    began to write), and remove the frames and videos of an earlier sequence there (a new one may have
    fewer)."""
    calib = folder / "calib.json"
    if folder.is_dir() and any(folder.iterdir()):
        try:
            ours = json.loads(calib.read_text())["extra"]["generator"] == GENERATOR
        except (OSError, ValueError, KeyError, TypeError):
            ours = not calib.exists() and _holds_only_frames(folder)
        if not ours:
            raise StereoGeoError(
                f"{folder} is not empty and holds no sequence made by make-data --sequence; "
                "use another folder"
            )
        for sub in ("left", "right", "depth/left", "depth/right"):
            if (folder / sub).is_dir():
                for old in (folder / sub).iterdir():
                    if _FRAME_FILE.match(old.name) or old.name.startswith(".tmp-"):
                        old.unlink()
        for old in folder.iterdir():
            if old.is_file() and (old.name in _VIDEO_FILES or old.name.startswith(".tmp-")):
                old.unlink()
        calib.unlink(missing_ok=True)
    try:
        for sub in ("left", "right"):
            (folder / sub).mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise StereoGeoError(f"cannot create the output folder {folder}: {error.strerror}") from error


def _open_videos(folder: Path, plan: SequencePlan) -> list:
    """The two H.264 writers of an ``h264_kbps`` sequence (temporary files in the folder)."""
    from stereogeo_cli.synth.video import H264Writer

    cam, rate = plan.rigs[0].left, plan.calib["extra"]["rate_hz"] or DRIVE_RATE_HZ
    kbps = plan.effects.h264_kbps
    return [H264Writer(folder / f".tmp-{side}.mp4", cam.width, cam.height, rate, kbps) for side in _SIDES]


def _finish_videos(folder: Path, plan: SequencePlan, writers: list, frames: int) -> None:
    """Close the videos, write their decoded frames as the sequence's PNGs, and keep the videos as
    left.mp4 and right.mp4 (``keep_video``) or remove them."""
    from stereogeo_cli.synth.dataset import _atomic_write, _png
    from stereogeo_cli.synth.sample import sample_id
    from stereogeo_cli.synth.video import read_h264

    cam = plan.rigs[0].left
    for side, writer in zip(_SIDES, writers, strict=True):
        writer.close()
        video = folder / f".tmp-{side}.mp4"
        count = 0
        for k, image in enumerate(read_h264(video, cam.width, cam.height)):
            _atomic_write(folder / side / f"{sample_id(k)}.png", _png(image))
            count += 1
        if count != frames:  # pragma: no cover - the encoder flushes every frame
            raise StereoGeoError(f"internal: the {side} video decoded to {count} frames of {frames}")
        if plan.effects.keep_video:
            video.replace(folder / f"{side}.mp4")
        else:
            video.unlink()


_SIDES = ("left", "right")


def make_sequence(
    folder: Path,
    motion: str,
    frames: int = 50,
    seed: int = 0,
    config: SynthConfig | None = None,
    progress: bool = True,
    effects: SequenceEffects | None = None,
    rate_hz: float | None = None,
) -> SequenceSummary:
    """Render sequence (motion, seed) of ``frames`` pairs into ``folder``: left/<frame>.png,
    right/<frame>.png (frames 000000, 000001, … in time order), depth/ with ``config.depth``, left.mp4 and
    right.mp4 with ``effects.keep_video``, and calib.json last; ``rate_hz``: the frame rate (see
    :func:`plan_sequence`). The same arguments give the same bytes; a folder holding an earlier (or
    interrupted) sequence is overwritten, any other non-empty folder is refused."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    from stereogeo_cli.synth.dataset import _atomic_write, _npy, _png
    from stereogeo_cli.synth.sample import sample_id

    folder = Path(folder)
    cfg = config or sequence_config(motion)
    if rate_hz is not None:
        motion_duration(motion, frames, rate_hz)  # a bad rate is refused before the folder is touched
    _prepare_folder(folder)
    plan = plan_sequence(motion, frames, seed, cfg, effects, rate_hz)
    try:
        if cfg.depth:
            for side in _SIDES:
                (folder / "depth" / side).mkdir(parents=True, exist_ok=True)
        writers = _open_videos(folder, plan) if plan.effects.h264_kbps is not None else None
        columns = (
            TextColumn(f"rendering {motion}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeRemainingColumn(),
        )
        with Progress(*columns, disable=not progress, transient=False) as bar:
            task = bar.add_task("render", total=frames)
            still = None
            same_every_frame = motion == "static" and plan.gains is None and not plan.scene.movers
            for k in range(frames):
                if same_every_frame:  # one pair, the same bytes in every frame
                    still = still or render_frame(plan, 0)
                    views = still
                else:
                    views = render_frame(plan, k, stream=0 if motion == "static" else k)
                name = sample_id(k)
                for side, image, writer in zip(_SIDES, views[:2], writers or [None, None], strict=True):
                    if writer is not None:
                        writer.add(image)
                    else:
                        _atomic_write(folder / side / f"{name}.png", _png(image))
                for side, depth in zip(_SIDES, views[2:], strict=True):
                    if depth is not None:
                        _atomic_write(folder / "depth" / side / f"{name}.npy", _npy(depth))
                bar.advance(task)
        if writers is not None:
            _finish_videos(folder, plan, writers, frames)
    finally:
        plan.release()
    _atomic_write(folder / "calib.json", (json.dumps(plan.calib, indent=1) + "\n").encode())
    return SequenceSummary(folder, frames, motion, plan.scene.kind)


# --- reading ------------------------------------------------------------------------------------------------


_IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm"}


def _images(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in _IMAGE_SUFFIXES and p.is_file())


def read_sequence_ground_truth(folder: Path | str) -> dict:
    """A sequence folder's calib.json and frame files as numpy arrays (synthetic and real sequences).

    Frames are ``left/`` (or ``cam0/``) and ``right/`` (or ``cam1/``), sorted by name. Returns a dict:
    ``left_images``, ``right_images`` (lists of Paths; right None for a mono sequence); ``K_left``,
    ``K_right`` [3 x 3]; ``dist_left``, ``dist_right`` [k] (OpenCV order, empty: none); ``size_left``,
    ``size_right`` (width, height); ``R`` [3 x 3], ``T`` [3] metres (``x_right = R x_left + T``);
    ``timestamps`` [N] seconds; ``gt_poses`` [N x 4 x 4] left camera-to-world; ``gravity_up_world`` [3];
    ``gravity_left``, ``gravity_right`` [N x 3] (the world's up in each camera per frame, the project's
    gravity convention; from the poses and gravity_up_world); ``motion``, ``seed``, ``scene``, ``extra``
    and ``calib`` (the whole record). Anything the folder does not give is None.
    Raises StereoGeoError when calib.json is missing or the frame counts disagree.
    """
    folder = Path(folder)
    try:
        calib = json.loads((folder / "calib.json").read_text())
    except (OSError, ValueError) as error:
        raise StereoGeoError(f"cannot read {folder / 'calib.json'}: {error}") from error

    def array(key, shape=None):
        value = calib.get(key)
        return None if value is None else np.asarray(value, dtype=float).reshape(shape or -1)

    def camera(side):
        c = calib.get(side)
        if c is None:
            return None, None, None
        return np.asarray(c["K"], float), np.asarray(c.get("dist") or [], float), (c["width"], c["height"])

    def frames(*names):
        for name in names:
            if (folder / name).is_dir():
                return _images(folder / name)
        return None

    left, right = frames("left", "cam0"), frames("right", "cam1")
    if left is None:
        raise StereoGeoError(f"{folder} has no left/ or cam0/ folder of frames")
    K_l, dist_l, size_l = camera("left")
    K_r, dist_r, size_r = camera("right")
    poses = None if calib.get("gt_poses") is None else np.asarray(calib["gt_poses"], float).reshape(-1, 4, 4)
    timestamps = array("timestamps")
    for what, whats, n in (
        ("right frame", "right frames", right), ("timestamp", "timestamps", timestamps),
        ("pose in gt_poses", "poses in gt_poses", poses),
    ):  # fmt: skip
        if n is not None and len(n) != len(left):
            counts = f"{plural(len(left), 'left frame')} but {plural(len(n), what, whats)}"
            raise StereoGeoError(f"{folder}: {counts}")
    up = array("gravity_up_world", 3)
    R = array("R", (3, 3))
    gravity_left = gravity_right = None
    if poses is not None and up is not None:
        gravity_left = np.einsum("nji,j->ni", poses[:, :3, :3], up)  # R_cw^T · up
        gravity_right = gravity_left @ R.T if R is not None else None
    return {
        "folder": folder,
        "left_images": left,
        "right_images": right,
        "K_left": K_l,
        "K_right": K_r,
        "dist_left": dist_l,
        "dist_right": dist_r,
        "size_left": size_l,
        "size_right": size_r,
        "R": R,
        "T": array("T", 3),
        "timestamps": timestamps,
        "gt_poses": poses,
        "gravity_up_world": up,
        "gravity_left": gravity_left,
        "gravity_right": gravity_right,
        "motion": calib.get("motion"),
        "seed": calib.get("seed"),
        "scene": calib.get("scene"),
        "extra": calib.get("extra"),
        "calib": calib,
    }
