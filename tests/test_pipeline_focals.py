"""Two cameras' focal lengths without matches (pipeline.hold_alike_focals): held equal where the fields read
them alike, left apart otherwise."""

import math

import numpy as np
import pytest

from stereogeo_cli.fuse import RelativePose
from stereogeo_cli.pipeline import hold_alike_focals
from stereogeo_cli.refine.lm import CameraFit


def _fit(focal, rel_sigma, width=640, height=480):
    covariance = np.diag([np.radians(1.0) ** 2, np.radians(1.0) ** 2, rel_sigma**2])
    return CameraFit(width, height, focal, np.array([0.0, -1.0, 0.0]), covariance, 0.0, 1, True)


def _head_pose():
    return RelativePose(
        R=np.eye(3), t_direction=np.array([-1.0, 0, 0]), source="pose_head", notes=["too few"]
    )


def test_alike_reads_are_combined_by_their_sigmas_and_held_equal():
    left, right = _fit(500.0, 0.05), _fit(530.0, 0.10)  # 5.8 % apart, 1 combined sigma is 11.2 %
    pose = hold_alike_focals(_head_pose(), left, right, 1.0)
    assert pose.equal_focals and len(pose.notes) == 2 and pose.notes[0] == "too few"
    # inverse variance in log f: weights 1/0.05² and 1/0.10², 4 : 1
    expected = math.exp((4 * math.log(500.0) + math.log(530.0)) / 5)
    assert left.focal_px * pose.focal_scale[0] == pytest.approx(expected, rel=1e-12)
    assert right.focal_px * pose.focal_scale[1] == pytest.approx(expected, rel=1e-12)
    # with the same sigmas, the geometric mean
    same = hold_alike_focals(_head_pose(), _fit(500.0, 0.08), _fit(540.0, 0.08), 1.0)
    assert 500.0 * same.focal_scale[0] == pytest.approx(math.sqrt(500.0 * 540.0), rel=1e-12)


@pytest.mark.parametrize(
    "left, right, limit",
    [
        (_fit(500.0, 0.05), _fit(600.0, 0.05), 1.0),  # 18 % apart: more than 1 combined sigma (7.1 %)
        (_fit(500.0, 0.05), _fit(510.0, 0.05, width=800), 1.0),  # images of two sizes
        (_fit(500.0, 0.05), _fit(510.0, 0.05), 0.0),  # switched off
        (_fit(500.0, float("inf")), _fit(510.0, 0.05), 1.0),  # a read without a sigma
    ],
)
def test_reads_apart_or_not_comparable_are_left_alone(left, right, limit):
    pose = _head_pose()
    assert hold_alike_focals(pose, left, right, limit) is pose


def test_calibrate_without_matches_holds_alike_focal_lengths_equal():
    """The bundled pair with matching switched off: the pose head gives the pose, and with a limit wide enough
    for the two reads (18 % apart, about 1.1 combined sigmas) both cameras get one focal length."""
    from pathlib import Path

    from stereogeo_cli.io.images import load_image
    from stereogeo_cli.pipeline import Calibrator

    examples = Path(__file__).resolve().parent.parent / "examples"
    left, right = load_image(examples / "left.png"), load_image(examples / "right.png")
    results = {}
    for limit in (0.0, 3.0):
        calibrator = Calibrator(
            threads=2, conf={"fuse": {"min_matches": 10**9}, "equal_focal_fields_sigmas": limit}
        )
        results[limit] = calibrator.calibrate(left, right)
    apart, held = results[0.0], results[3.0]
    assert apart.pose.source == held.pose.source == "pose_head"
    assert not apart.pose.equal_focals and held.pose.equal_focals
    f_left, f_right = apart.calibration.K_left[0, 0], apart.calibration.K_right[0, 0]
    assert abs(math.log(f_left / f_right)) > 0.1
    assert held.calibration.K_left[0, 0] == pytest.approx(held.calibration.K_right[0, 0], rel=1e-9)
    assert min(f_left, f_right) < held.calibration.K_left[0, 0] < max(f_left, f_right)
    assert held.report()["pose"]["equal_focals"] is True
    assert any("held equal" in w for w in held.warnings)
