"""The rig sampler: camera orientation convention and the ranges the issue asks for (no rendering)."""

from __future__ import annotations

import numpy as np

from stereogeo_cli.geometry import gravity_from_roll_pitch, rotation_angle
from stereogeo_cli.synth.config import SynthConfig
from stereogeo_cli.synth.rigs import camera_rotation, sample_rig


def test_camera_rotation_matches_the_gravity_convention():
    rng = np.random.default_rng(0)
    for yaw, roll, pitch in rng.uniform(-1.2, 1.2, (20, 3)):
        R = camera_rotation(yaw, roll, pitch)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(R @ [0, 0, 1], gravity_from_roll_pitch(roll, pitch), atol=1e-12)
        forward = R.T @ [0, 0, 1]
        assert np.sign(forward[2]) == np.sign(pitch)  # pitch > 0 looks up
        np.testing.assert_allclose(np.arctan2(forward[1], forward[0]), yaw, atol=1e-9)


def test_sampler_covers_the_required_ranges():
    cfg = SynthConfig()
    rigs = [sample_rig(np.random.default_rng([0, i]), cfg) for i in range(2000)]
    baselines = np.array([r.baseline for r in rigs])
    assert baselines.min() >= 0.05 and baselines.max() <= 0.8
    # log-uniform: the median is near the geometric mean
    assert abs(np.log(np.median(baselines)) - np.log(np.sqrt(0.05 * 0.8))) < 0.15
    vfovs = np.degrees([[r.vfov_left, r.vfov_right] for r in rigs])
    assert vfovs.min() >= 20 and vfovs.max() <= 105 and vfovs.min() < 22 and vfovs.max() > 103
    equal = np.mean(vfovs[:, 0] == vfovs[:, 1])
    assert 0.4 < equal < 0.75
    angles = np.degrees([[r.roll, r.pitch] for r in rigs])
    assert np.abs(angles).max() <= 45
    assert np.mean(np.all(np.abs(angles) < 5, axis=1)) > 0.3  # a share near level
    assert np.mean(np.abs(angles[:, 0]) > 30) > 0.1
    toe_in = np.degrees([rotation_angle(r.R) for r in rigs])
    assert np.mean(toe_in == 0) > 0.2 and 1.0 < toe_in.max() < 6.0
    sizes = {(r.width, r.height) for r in rigs}
    assert {(320, 240), (240, 320), (426, 240), (240, 240), (360, 240)} <= sizes
    # the right camera is to the right of the left one
    assert all(r.offset[0] > 0 for r in rigs)
