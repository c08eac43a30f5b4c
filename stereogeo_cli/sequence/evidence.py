"""What a sequence's reconstruction and its pairs' own readings give together: the focal lengths, one
world up and each frame's attitude.

The focal length: the bundle adjustment's, with its covariance's sigma and a floor for what the
adjustment does not model (the principal point held at the image centre, one radial term), combined in
log f with the pairs' combined reading by inverse variance. Where the motion leaves the focal length
free (a straight drive, a static rig), the adjustment's sigma is wide and the pairs' reading carries it.

Gravity never enters the adjustment: every frame's up vector (each camera's, from its fields and
vertical lines) is rotated into the reconstruction's world and the readings are combined, robustly, into
one world up; each frame's roll and pitch are then read from its pose.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stereogeo_cli.fuse.assemble import CameraEstimate, finite
from stereogeo_cli.geometry import roll_pitch_from_gravity
from stereogeo_cli.rig.combine import FocalEstimate, combine_directions
from stereogeo_cli.settings import resolve

default_conf = {
    # relative 1-sigma the adjustment's focal length keeps whatever its cost profile says: a real camera's
    # principal point lies up to ~2 % of the image off its centre, and where the adjustment holds it there
    # it moves the focal length by about as much; where it frees it, the lens model (one or two radial
    # terms) still leaves about 1 %
    "focal_floor_rel": 0.02,
    "focal_floor_rel_free_centre": 0.01,
    # the principal point's 1-sigma as a share of the image's larger side: held at the centre (a real
    # camera's lies up to ~2 % off it) or freed by the adjustment (then within ~0.5 %); it turns the rig's
    # R and T's direction by about σ / f radians, which their reported sigmas take in (for held points only
    # where no adjustment under a prior measured how far they turn them)
    "principal_point_sigma_rel": 0.02,
    "principal_point_sigma_rel_free": 0.005,
    # the motion "fixes" the focal length where the adjustment's sigma is below this share of the pairs'
    # (it then carries over 90 % of the combined weight) and the rig turned by at least this much: without
    # rotation, only the rig's own small left-right rotation ties the focal length, a thread that the
    # adjustment's unmodelled errors can pull
    "observable_ratio": 1.0 / 3.0,
    "observable_min_rotation_deg": 5.0,
    # a rig that turned less than observable_min_rotation_deg and whose camera moved less than this many
    # rig baselines stood still: its frames show what one pair shows, and the adjustment's focal length,
    # tied by the rig's own left-right rotation alone, is left out (the pairs' reading and sigma are kept)
    "still_travel_baselines": 0.5,
    # the pairs' reading is left out where it is this many combined sigmas from the adjustment's: a
    # network's read of a real lens can be far off (a car camera's 313 px for 707), and a sharp
    # adjustment is then the measurement
    "pairs_reject_sigmas": 3.0,
    # ... unless the mapping registered less than this share of the frames: its model is of a stretch of
    # them, and a broken mapping can be sharp and wrong there (renders that registered 12 of 30 frames read
    # 15-20 % high at 3-5 sigmas); its reading then does not outvote the pairs', and where the two disagree
    # the combined sigma is at least their distance
    "partial_registration_share": 0.8,
    # a frame's up reading farther than this many of its sigmas from the robust centre is left out
    "up_reject_sigmas": 3.0,
    # the combined up's sigma is at least the frames' median sigma over this: the frames of one sequence
    # share much of the network's error (one scene, one camera), which does not average away
    "up_common_factor": 3.0,
    # the vertical line segments of every registered image: a segment is taken as vertical where its
    # plane's normal is within this angle of the horizontal (first around the readings' up, then around
    # the segments' own, three times, down to the last angle)
    "vertical_within_deg": (6.0, 3.0, 2.0),
    "vertical_min_segments": 30,  # fewer vertical segments, or from fewer than 3 images: not used
    "vertical_floor_deg": 0.05,  # the segments' up keeps at least this 1-sigma
}


@dataclass(frozen=True)
class SequenceFocal:
    """One camera's focal length from the sequence: ``focal_px`` ± ``sigma_px`` combined from the
    adjustment's and the pairs'; ``observable``: the motion fixed it (the adjustment carries it and the
    rig turned);
    ``adjustment_weight``: the adjustment's share of the combined weight (0–1)."""

    focal_px: float
    sigma_px: float
    observable: bool
    adjustment_weight: float
    adjusted: FocalEstimate
    pairs: FocalEstimate
    pairs_left_out: bool = False  # the pairs' reading disagreed with a sharp adjustment's
    partial: bool = False  # the adjustment's model registered part of the frames only

    def to_report(self) -> dict:
        return {
            "focal_px": self.focal_px,
            "sigma_px": self.sigma_px,
            "observable": self.observable,
            "adjustment_weight": self.adjustment_weight,
            "pairs_left_out": self.pairs_left_out,
            "partial_registration": self.partial,
            "adjustment": {"focal_px": self.adjusted.focal_px, "sigma_px": finite(self.adjusted.sigma_px)},
            "pairs": {"focal_px": self.pairs.focal_px, "sigma_px": finite(self.pairs.sigma_px)},
        }


def combine_adjusted_focal(
    adjusted: CameraEstimate,
    pairs: FocalEstimate,
    rotation_span_deg: float | None,
    conf: dict | None = None,
    travel_baselines: float | None = None,
    registered_share: float = 1.0,
) -> SequenceFocal:
    """The adjustment's focal length (``adjusted.focal_px``, its ``sigma["focal_px"]`` from its cost
    profile, infinite where there is none) combined with the pairs' ``pairs`` in log f; observable where
    the adjustment carries it and the rig turned by ``rotation_span_deg`` (None: unknown) enough. Where the
    rig also moved less than the conf's ``still_travel_baselines`` (``travel_baselines``: how far its
    camera moved, in rig baselines; None: unknown), it stood still and the adjustment is left out. Where
    the adjustment's model registered less than the conf's ``partial_registration_share`` of the frames
    (``registered_share``), the pairs are never left out, and the sigma is at least the two readings'
    distance."""
    conf = resolve(default_conf, conf)
    f_a, f_p = adjusted.focal_px, pairs.focal_px
    floor = conf["focal_floor_rel_free_centre" if adjusted.principal_point_refined else "focal_floor_rel"]
    s_a = math.hypot(adjusted.sigma_focal_rel, floor)
    s_p = pairs.sigma_px / f_p if math.isfinite(pairs.sigma_px) and pairs.sigma_px > 0 else math.inf
    still = (
        rotation_span_deg is not None
        and rotation_span_deg < conf["observable_min_rotation_deg"]
        and travel_baselines is not None
        and travel_baselines < conf["still_travel_baselines"]
    )
    w_a = 0.0 if still or not math.isfinite(s_a) else 1.0 / s_a**2
    w_p = 0.0 if not math.isfinite(s_p) else 1.0 / s_p**2
    if w_a + w_p == 0:
        return SequenceFocal(f_a, math.inf, False, 0.0, FocalEstimate(f_a, f_a * s_a), pairs)
    apart = abs(math.log(f_a / f_p)) / math.hypot(s_a, s_p) if w_a and w_p else 0.0
    partial = registered_share < conf["partial_registration_share"] and w_a > 0
    pairs_left_out = apart > conf["pairs_reject_sigmas"] and not partial
    if pairs_left_out:
        w_p = 0.0
    log_f = (w_a * math.log(f_a) + w_p * math.log(f_p)) / (w_a + w_p)
    focal = math.exp(log_f)
    sigma = focal / math.sqrt(w_a + w_p)
    if partial and w_p > 0:  # a stretch's reading against the pairs': the sigma covers both
        sigma = max(sigma, focal * abs(math.log(f_a / f_p)))
    observable = (
        s_a < conf["observable_ratio"] * s_p
        and sigma / focal < conf["observable_ratio"] * s_p
        and rotation_span_deg is not None
        and rotation_span_deg >= conf["observable_min_rotation_deg"]
    )
    weight = w_a / (w_a + w_p)
    return SequenceFocal(
        focal, sigma, observable, weight, FocalEstimate(f_a, f_a * s_a), pairs, pairs_left_out, partial
    )


def rig_sigmas_deg(
    spread: tuple[float, float], cameras, sizes: tuple, conf: dict | None = None, held_measured: bool = False
) -> tuple[float, float]:
    """R's and T's direction's reported 1-sigma (degrees): the frames' own spread (``spread``, from
    :func:`~stereogeo_cli.sequence.colmap.rig_sigmas` and the adjustment's other readings) with what the
    principal points' uncertainty adds (σ_pp / f for the less certain camera) in quadrature.
    ``held_measured``: an adjustment that freed the principal points under a prior measured how far R and
    T move with them (it is in ``spread``): no bound is added for the cameras whose points were held.
    ``sizes``: ((h, w) left, right)."""
    conf = resolve(default_conf, conf)
    floor = 0.0
    for camera, (height, width) in zip(cameras, sizes, strict=True):
        if held_measured and not camera.principal_point_refined:
            continue
        share = conf[
            "principal_point_sigma_rel_free"
            if camera.principal_point_refined
            else "principal_point_sigma_rel"
        ]
        floor = max(floor, math.degrees(share * max(width, height) / camera.focal_px))
    return math.hypot(spread[0], floor), math.hypot(spread[1], floor)


def _up_readings(readings, cam_from_world: dict[int, np.ndarray], R: np.ndarray):
    """Each camera's up reading of every registered frame in world coordinates [N x 3], with its sigma
    (radians) [N]. ``readings``: per frame index its :class:`~stereogeo_cli.rig.evidence.PairEvidence`."""
    ups, sigmas = [], []
    for index, reading in readings.items():
        pose = cam_from_world.get(index)
        if pose is None:
            continue
        world_from_left = pose[:3, :3].T
        for camera, to_left in zip(reading.cameras, (np.eye(3), R.T), strict=True):
            gravity, sigma_deg = camera.gravity_up, camera.sigma.get("gravity_deg", math.inf)
            if gravity is None or not math.isfinite(sigma_deg) or sigma_deg <= 0:
                continue
            up = world_from_left @ to_left @ np.asarray(gravity, float)
            ups.append(up / np.linalg.norm(up))
            sigmas.append(math.radians(sigma_deg))
    return np.array(ups).reshape(-1, 3), np.array(sigmas)


def world_up(readings, cam_from_world: dict[int, np.ndarray], R: np.ndarray, conf: dict | None = None):
    """One up vector [3] of the reconstruction's world from every registered frame's readings (per frame
    index its :class:`~stereogeo_cli.rig.evidence.PairEvidence`), its 1-sigma (degrees) and how many readings
    it used: :func:`stereogeo_cli.rig.combine.combine_directions`, readings farther than
    ``up_reject_sigmas`` left out, the sigma at least the median sigma over ``up_common_factor``."""
    conf = resolve(default_conf, conf)
    ups, sigmas = _up_readings(readings, cam_from_world, R)
    if len(ups) == 0:
        return None, None, 0
    mean, sigma, used = combine_directions(ups, sigmas, conf["up_reject_sigmas"], conf["up_common_factor"])
    return mean, math.degrees(sigma), int(used.sum())


def up_from_segments(normals: np.ndarray, owners: np.ndarray, start: np.ndarray, conf: dict | None = None):
    """The world's up from the planes of vertical line segments seen from many poses: the direction most
    nearly perpendicular to their normals (the smallest eigenvector of Σ n nᵀ), the segments taken as
    vertical around ``start`` and then around the estimate itself.

    Its information [3 x 3] (inverse covariance, radians⁻², rank 2 across the up) is the normals' spread
    across the up over their scatter about it, as if each image gave one independent reading (segments of
    one image share its pose's error): a drive straight ahead, whose vertical segments are all seen from
    one side, fixes the up's roll well and its pitch barely, and the information says so. Returns (up [3],
    information, segments used), or (None, None, 0) where too few images show vertical segments."""
    conf = resolve(default_conf, conf)
    up = np.asarray(start, float) / np.linalg.norm(start)
    used = np.zeros(len(normals), bool)
    for within in conf["vertical_within_deg"]:
        used = np.abs(normals @ up) < math.sin(math.radians(within))
        if used.sum() < conf["vertical_min_segments"] or len(set(owners[used].tolist())) < 3:
            return None, None, 0
        n = normals[used]
        candidate = np.linalg.eigh(n.T @ n)[1][:, 0]
        up = candidate if candidate @ up > 0 else -candidate
    n = normals[used]
    residual = n @ up
    tangent = n - np.outer(residual, up)
    per_image = len(n) / len(set(owners[used].tolist()))
    variance = max(float(np.mean(residual**2)) * per_image, math.radians(conf["vertical_floor_deg"]) ** 2)
    return up, tangent.T @ tangent / variance, int(used.sum())


def combine_ups(up: np.ndarray, sigma_deg: float, found: np.ndarray, information: np.ndarray):
    """The readings' up (isotropic ``sigma_deg``) and the segments' (``information``: see
    :func:`up_from_segments`) combined in the plane across the readings' up. Returns (up, its 1-sigma in
    degrees as the root mean of the two directions' variances, the Mahalanobis distance of the two in
    sigmas)."""
    basis = np.linalg.svd(up.reshape(1, 3))[2][1:].T  # [3 x 2], across up
    offset = basis.T @ found  # the segments' up in that plane (small angles, radians)
    from_readings = np.eye(2) / math.radians(sigma_deg) ** 2
    from_segments = basis.T @ information @ basis
    covariance = np.linalg.inv(from_readings + from_segments)
    shift = covariance @ from_segments @ offset
    combined = up + basis @ shift
    apart = float(
        offset @ np.linalg.solve(np.linalg.inv(from_readings) + np.linalg.pinv(from_segments), offset)
    )
    sigma = math.degrees(math.sqrt(float(np.trace(covariance)) / 2))
    return combined / np.linalg.norm(combined), sigma, math.sqrt(max(apart, 0.0) / 2)


def attitude(gravity: np.ndarray) -> dict:
    """A camera's up vector [3] with its roll and pitch (degrees), as a frame of the report holds them."""
    roll, pitch = roll_pitch_from_gravity(gravity)
    return {
        "gravity_up": np.asarray(gravity, float).tolist(),
        "roll_deg": math.degrees(float(roll)),
        "pitch_deg": math.degrees(float(pitch)),
    }


def frame_attitudes(cam_from_world: dict[int, np.ndarray], up: np.ndarray, R: np.ndarray) -> dict[int, dict]:
    """Each frame's up vector in its left and right camera and their roll and pitch (degrees)."""
    out = {}
    for index, pose in cam_from_world.items():
        left = pose[:3, :3] @ up
        out[index] = {"left": attitude(left), "right": attitude(R @ left)}
    return out
