"""The sequence's evidence combined: focal lengths (adjustment and pairs), one world up, each frame's
attitude, and the trajectory file, on exact synthetic inputs."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from stereogeo_cli.fuse.assemble import CameraEstimate
from stereogeo_cli.geometry import gravity_from_roll_pitch, quaternion_to_rotation, rotation_from_axis_angle
from stereogeo_cli.rig.combine import FocalEstimate
from stereogeo_cli.rig.evidence import EMPTY, PairEvidence
from stereogeo_cli.sequence.colmap import cam_from_new_world
from stereogeo_cli.sequence.evidence import (
    combine_adjusted_focal,
    frame_attitudes,
    world_up,
)
from stereogeo_cli.sequence.run import trajectory_tum


def adjusted(focal_px: float, sigma_px: float) -> CameraEstimate:
    """A camera as an adjustment gives it: its focal length and the cost profile's 1-sigma (pixels)."""
    return CameraEstimate(focal_px, 640, 480, None, {"focal_px": sigma_px})


def test_a_sharp_adjustment_carries_the_focal_length_and_is_called_observable():
    pairs = FocalEstimate(400.0, 80.0)  # 20 %: a network's read of a real camera
    sharp = combine_adjusted_focal(adjusted(500.0, 0.5), pairs, rotation_span_deg=40.0)
    assert sharp.observable
    assert sharp.adjustment_weight > 0.98
    assert sharp.focal_px == pytest.approx(500.0, rel=0.01)
    # the floor: the principal point held at the centre keeps the sigma at about 2 %
    assert sharp.sigma_px / sharp.focal_px == pytest.approx(0.02, rel=0.05)


def test_a_free_focal_length_falls_back_to_the_pairs_with_their_sigma():
    pairs = FocalEstimate(400.0, 80.0)
    free = combine_adjusted_focal(adjusted(650.0, 650.0 * 3.0), pairs, 40.0)  # the cost barely rose
    assert not free.observable
    assert free.adjustment_weight < 0.01
    assert free.focal_px == pytest.approx(400.0, rel=0.01)
    assert free.sigma_px == pytest.approx(80.0, rel=0.01)
    none = combine_adjusted_focal(adjusted(650.0, math.inf), pairs, 40.0)
    assert none.focal_px == pytest.approx(400.0) and not none.observable


def test_without_rotation_a_sharp_adjustment_is_used_but_not_called_observable():
    pairs = FocalEstimate(480.0, 96.0)
    straight = combine_adjusted_focal(adjusted(500.0, 0.5), pairs, rotation_span_deg=0.8)
    assert not straight.observable
    assert straight.focal_px == pytest.approx(500.0, rel=0.01)


def test_a_rig_standing_still_keeps_the_pairs_focal_length_and_sigma():
    """Not turned and not moved: the frames show what one pair shows, and the adjustment's sharp focal
    length (tied by the rig's own left-right rotation alone) is left out; a rig that moved is adjusted."""
    pairs = FocalEstimate(480.0, 96.0)
    still = combine_adjusted_focal(adjusted(420.0, 0.5), pairs, 0.0, travel_baselines=0.01)
    assert still.adjustment_weight == 0.0 and not still.observable
    assert still.focal_px == pytest.approx(480.0) and still.sigma_px == pytest.approx(96.0)
    assert still.adjusted.focal_px == 420.0  # still reported
    drove = combine_adjusted_focal(adjusted(420.0, 0.5), pairs, 0.0, travel_baselines=20.0)
    assert drove.adjustment_weight > 0.9


def test_a_pairs_reading_far_from_a_sharp_adjustment_is_left_out():
    # a car camera read as 313 px for 707: the adjustment's 690 ± 2 % is the measurement
    far = combine_adjusted_focal(adjusted(690.0, 1.0), FocalEstimate(313.0, 78.0), 2.0)
    assert far.pairs_left_out and far.adjustment_weight == 1.0
    assert far.focal_px == pytest.approx(690.0)
    near = combine_adjusted_focal(adjusted(690.0, 1.0), FocalEstimate(600.0, 150.0), 2.0)
    assert not near.pairs_left_out and near.focal_px < 690.0


def _readings_and_poses(up_world, count=30, noise_deg=1.0, seed=0):
    """Frames turning about the world's up, each camera's up read with noise, the rig R a small turn."""
    rng = np.random.default_rng(seed)
    R_rig = rotation_from_axis_angle(np.radians([0.5, -1.0, 0.3]))
    poses, readings = {}, {}
    for i in range(count):
        yaw = rotation_from_axis_angle(up_world * math.radians(3.0 * i))
        tilt = rotation_from_axis_angle(np.radians([10.0, 0.0, 5.0]))
        cam_from_world = np.eye(4)
        cam_from_world[:3, :3] = tilt @ yaw.T
        poses[i] = cam_from_world
        truth_left = cam_from_world[:3, :3] @ up_world
        gravity = []
        for g in (truth_left, R_rig @ truth_left):
            noisy = g + rng.normal(0, math.radians(noise_deg), 3)
            gravity.append(noisy / np.linalg.norm(noisy))
        cameras = tuple(
            CameraEstimate(500.0, 640, 480, g, {"focal_px": 50.0, "gravity_deg": noise_deg}) for g in gravity
        )
        readings[i] = PairEvidence(
            cameras, R_rig, np.array([-1.0, 0, 0]), "matches", 0.1, EMPTY, EMPTY, sigma_baseline_rel=0.5
        )
    return readings, poses, R_rig


def test_world_up_averages_the_frames_and_its_sigma_covers_the_error():
    up = np.array([0.2, -0.9, 0.1])
    up /= np.linalg.norm(up)
    readings, poses, R_rig = _readings_and_poses(up)
    found, sigma_deg, used = world_up(readings, poses, R_rig)
    error = math.degrees(math.acos(np.clip(found @ up, -1, 1)))
    assert used == 60
    assert error < 0.5  # 60 readings of 1° each
    assert error < 3 * sigma_deg
    # the frames share one scene's error: the sigma does not shrink below a third of one reading's
    assert sigma_deg >= 1.0 / 3.0 - 1e-9


def test_world_up_leaves_out_a_reading_far_off():
    up = np.array([0.0, -1.0, 0.0])
    readings, poses, R_rig = _readings_and_poses(up, noise_deg=0.5)
    blunder = replace(readings[3].cameras[0], gravity_up=np.array([1.0, 0.0, 0.0]))  # 90° off
    readings[3].cameras = (blunder, readings[3].cameras[1])
    found, _, used = world_up(readings, poses, R_rig)
    assert used == 59
    assert math.degrees(math.acos(np.clip(found @ up, -1, 1))) < 0.5


def test_frame_attitudes_read_roll_and_pitch_from_the_pose():
    roll, pitch = math.radians(4.0), math.radians(-7.0)
    g = gravity_from_roll_pitch(roll, pitch)
    # a camera whose rotation takes the world's z (up) to g
    axis = np.cross([0.0, 0.0, 1.0], g)
    angle = math.acos(float(np.clip(g[2], -1, 1)))
    cam_from_world = np.eye(4)
    cam_from_world[:3, :3] = rotation_from_axis_angle(axis / np.linalg.norm(axis) * angle)
    attitude = frame_attitudes({0: cam_from_world}, np.array([0.0, 0.0, 1.0]), np.eye(3))[0]
    assert attitude["left"]["roll_deg"] == pytest.approx(4.0, abs=1e-9)
    assert attitude["left"]["pitch_deg"] == pytest.approx(-7.0, abs=1e-9)
    assert attitude["right"] == attitude["left"]


def test_the_trajectory_is_tum_with_the_camera_in_the_world():
    world_from_cam = np.eye(4)
    world_from_cam[:3, :3] = rotation_from_axis_angle(np.radians([0.0, 0.0, 30.0]))
    world_from_cam[:3, 3] = [1.0, 2.0, 3.0]
    text = trajectory_tum([(0.5, world_from_cam)])
    header, line = text.strip().splitlines()
    assert header.startswith("#")
    stamp, tx, ty, tz, qx, qy, qz, qw = map(float, line.split())
    assert (stamp, tx, ty, tz) == (0.5, 1.0, 2.0, 3.0)
    R = quaternion_to_rotation(np.array([qw, qx, qy, qz]))
    np.testing.assert_allclose(R, world_from_cam[:3, :3], atol=1e-8)


def test_vertical_segments_seen_from_many_poses_give_the_world_up():
    from stereogeo_cli.sequence.evidence import combine_ups, up_from_segments

    rng = np.random.default_rng(3)
    up = np.array([0.05, 0.02, 1.0])
    up /= np.linalg.norm(up)
    # vertical segments: planes through the up; the rest: planes at any angle
    horizontal = rng.normal(size=(300, 3))
    vertical = np.cross(horizontal, up)
    vertical /= np.linalg.norm(vertical, axis=1, keepdims=True)
    vertical += rng.normal(0, math.radians(0.2), vertical.shape)
    others = rng.normal(size=(300, 3))
    normals = np.concatenate([vertical, others])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    owners = np.arange(len(normals)) % 30
    start = up + np.array([0.03, -0.02, 0.0])  # the readings' up, about 2° off
    found, information, used = up_from_segments(normals, owners, start)
    assert math.degrees(math.acos(min(1.0, found @ up))) < 0.1
    assert 300 <= used < 340  # the verticals, and the few others that happen to lie near the horizontal
    combined, sigma, apart = combine_ups(start / np.linalg.norm(start), 2.0, found, information)
    assert math.degrees(math.acos(min(1.0, combined @ up))) < 0.1 and sigma < 0.2 and apart < 3
    assert up_from_segments(others[:20], owners[:20], start)[0] is None  # too few: not used


def test_a_camera_in_the_scaled_world_stays_a_rotation_and_a_metric_translation():
    """The reconstruction moved by a similarity (scale 2.5: COLMAP's units to metres): each camera's new
    world→camera transform is rigid, and maps a moved point to the camera coordinates scaled likewise."""
    rng = np.random.default_rng(3)
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rotation_from_axis_angle(rng.normal(size=3)), rng.normal(size=3)
    moved = np.eye(4)
    moved[:3, :3], moved[:3, 3] = 2.5 * rotation_from_axis_angle(rng.normal(size=3)), rng.normal(size=3)
    new = cam_from_new_world(pose, moved)
    np.testing.assert_allclose(new[:3, :3] @ new[:3, :3].T, np.eye(3), atol=1e-12)
    point = np.append(rng.normal(size=3), 1.0)
    np.testing.assert_allclose(new @ (moved @ point), np.append(2.5 * (pose @ point)[:3], 1.0), atol=1e-12)


def test_an_adjustment_of_part_of_the_frames_does_not_outvote_the_pairs():
    """A sharp adjustment over 3 sigmas from the pairs leaves them out where it registered every frame;
    where it registered 40 % of them (a broken mapping), the pairs stay, and the sigma covers both
    readings."""
    pairs = FocalEstimate(400.0, 26.0)  # 6.5 %: the 2 % adjustment is 3.3 sigmas off, and fixes f
    whole = combine_adjusted_focal(adjusted(500.0, 0.5), pairs, rotation_span_deg=40.0)
    assert whole.pairs_left_out and whole.observable and not whole.partial
    assert whole.focal_px == pytest.approx(500.0, rel=1e-3)
    part = combine_adjusted_focal(adjusted(500.0, 0.5), pairs, rotation_span_deg=40.0, registered_share=0.4)
    assert part.partial and not part.pairs_left_out and not part.observable
    assert 400.0 < part.focal_px < 500.0
    low, high = part.focal_px - part.sigma_px, part.focal_px + part.sigma_px
    assert low <= 400.0 * 1.02 and high >= 500.0  # both readings within about 1 sigma
    near = FocalEstimate(490.0, 49.0)
    agreed = combine_adjusted_focal(adjusted(500.0, 0.5), near, 40.0, registered_share=0.4)
    assert agreed.partial and agreed.observable and agreed.sigma_px < 0.03 * 500.0  # agreeing: no widening
