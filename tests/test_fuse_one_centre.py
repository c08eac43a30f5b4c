"""Two views from one centre (fuse/one_centre.py): recognised against an essential matrix by GRIC, fitted as
a rotation, and read for the focal lengths only as far as the turn and the principal points allow."""

import json
from pathlib import Path

import numpy as np

from stereogeo_cli.fuse import Matches, fuse_relative_pose
from stereogeo_cli.fuse.one_centre import gric
from stereogeo_cli.geometry import intrinsic_matrix, rotation_error, rotation_from_axis_angle

ROOT = Path(__file__).resolve().parents[1]
SIZE = (640, 480)
COMMON = 0.27  # the fields' relative sigma with the camera bias, as the pipeline passes it


def _turned(rng, K_left, K_right, R, count=400, noise_px=0.3, outliers=0.1, depth=(2.0, 30.0), T=None):
    """Matches of points in front of the left camera seen by a camera turned by R (and moved by T)."""
    X = np.column_stack([rng.uniform(-1, 1, count), rng.uniform(-0.75, 0.75, count), np.ones(count)])
    X *= rng.uniform(*depth, count)[:, None]
    T = np.zeros(3) if T is None else T
    xl, xr = X @ K_left.T, (X @ R.T + T) @ K_right.T
    xl, xr = xl[:, :2] / xl[:, 2:], xr[:, :2] / xr[:, 2:]
    inside = (xr[:, 0] > 0) & (xr[:, 0] < SIZE[0]) & (xr[:, 1] > 0) & (xr[:, 1] < SIZE[1])
    xl, xr = (
        xl[inside] + rng.normal(0, noise_px, (inside.sum(), 2)),
        xr[inside] + rng.normal(0, noise_px, (inside.sum(), 2)),
    )
    bad = rng.random(len(xl)) < outliers
    xr[bad] = rng.uniform(0, SIZE[0], (bad.sum(), 2))
    return Matches(xl, xr)


def test_gric_prefers_the_smaller_model_where_both_fit_and_the_better_fit_where_not():
    rng = np.random.default_rng(0)
    noise = rng.chisquare(2, 500)  # squared distances of matches on a 2-dimensional variety, noise units
    on_both = gric(noise, 2, 5, 2.0) < gric(rng.chisquare(1, 500), 3, 5, 2.0)
    assert on_both  # λ₁·n favours the variety of lower dimension where both explain the matches
    off = gric(noise + 25.0, 2, 5, 2.0)  # every match 5 sigmas off the rotation: capped at 4 each
    assert off > gric(rng.chisquare(1, 500), 3, 5, 2.0)


def test_a_turned_camera_is_recognised_and_tells_its_focal_length():
    """A camera turned 15° on a tripod, read 20 % too long by the fields: its focal length comes out within
    2 %, its sigma covering it, and R within a tenth of a degree or so."""
    rng = np.random.default_rng(1)
    K = intrinsic_matrix(500, *SIZE)
    given = intrinsic_matrix(600, *SIZE)
    errors, focal = [], []
    for _ in range(5):
        R = rotation_from_axis_angle(np.radians([3.0, 15.0, 1.0]) * rng.uniform(0.8, 1.2, 3))
        pose = fuse_relative_pose(
            _turned(rng, K, K, R), given, given, prior_R=R, prior_t=np.array([-0.1, 0, 0]),
            focal_sigma_rel=(0.1, 0.1), common_focal_sigma_rel=COMMON,
        )  # fmt: skip
        assert pose.source == "rotation" and "rotation alone" in pose.notes[0]
        errors.append(np.degrees(rotation_error(pose.R, R)))
        for side in (0, 1):
            relative = 600 * pose.focal_scale[side] / 500 - 1
            assert abs(np.log1p(relative)) < 3 * pose.focal_read_sigma_rel[side]
            focal.append(abs(relative))
        assert pose.focal_read_sigma_rel[0] < 0.08  # the turn told far more than the fields' 27 %
    # the focal lengths about 0.8 % off (the fields' read still weighs in, as far as the principal points'
    # uncertainty lets it), and R by that share of the 15° turn
    assert np.median(focal) < 0.02, focal
    assert np.median(errors) < 0.2, errors


def test_a_rig_with_parallax_keeps_its_essential_matrix():
    rng = np.random.default_rng(2)
    K = intrinsic_matrix(500, *SIZE)
    for _ in range(5):
        R = rotation_from_axis_angle(rng.normal(0, np.radians(1.0), 3))
        T = R @ np.array([-0.3, 0.0, 0.0])
        matches = _turned(rng, K, K, R, T=T, depth=(1.5, 12.0))
        pose = fuse_relative_pose(matches, K, K, prior_R=R, prior_t=T, focal_sigma_rel=(0.1, 0.1))
        assert pose.source == "matches"
        assert pose.focal_read_sigma_rel is None


def test_a_photo_and_its_crop_say_nothing_of_the_focal_length():
    """The evaluation's pair of a photo and the photo less its 8 leftmost columns: one centre and no turn,
    the principal point of the crop 4 px off its centre. Neither model may read a focal length into it."""
    rng = np.random.default_rng(3)
    width, height = SIZE
    left = np.column_stack([rng.uniform(10, width - 10, 500), rng.uniform(10, height - 10, 500)])
    left += rng.normal(0, 0.01, left.shape)
    matches = Matches(left, left - np.array([8.0, 0.0]))
    K_left, K_right = intrinsic_matrix(450, width, height), intrinsic_matrix(450, width - 8, height)
    pose = fuse_relative_pose(
        matches, K_left, K_right, prior_R=np.eye(3), prior_t=np.array([-0.1, 0, 0]),
        focal_sigma_rel=(0.1, 0.1), common_focal_sigma_rel=COMMON,
    )  # fmt: skip
    assert abs(np.log(pose.focal_scale[0])) < 0.02 and abs(np.log(pose.focal_scale[1])) < 0.02
    assert pose.focal_read_sigma_rel is None or all(s is None for s in pose.focal_read_sigma_rel)
    assert np.degrees(rotation_error(pose.R, np.eye(3))) < 1.0


def test_a_turn_about_the_optical_axis_leaves_the_fields_read_and_its_sigma():
    rng = np.random.default_rng(4)
    K = intrinsic_matrix(500, *SIZE)
    given = intrinsic_matrix(560, *SIZE)
    R = rotation_from_axis_angle(np.radians([0.0, 0.0, 10.0]))
    pose = fuse_relative_pose(
        _turned(rng, K, K, R), given, given, prior_R=R, prior_t=np.array([-0.1, 0, 0]),
        focal_sigma_rel=(0.1, 0.1), common_focal_sigma_rel=COMMON,
    )  # fmt: skip
    assert pose.source == "rotation"
    assert np.degrees(rotation_error(pose.R, R)) < 0.05
    # a roll maps pixels through both focal lengths alike: the fields' read (their ratio aside) stands
    assert abs(np.log(pose.focal_scale[0] * pose.focal_scale[1]) / 2) < 0.03
    assert all(s is None or s > 0.2 for s in pose.focal_read_sigma_rel)


def test_a_given_focal_length_is_held_and_the_other_is_read():
    rng = np.random.default_rng(5)
    K = intrinsic_matrix(500, *SIZE)
    R = rotation_from_axis_angle(np.radians([2.0, 18.0, 0.0]))
    pose = fuse_relative_pose(
        _turned(rng, K, K, R), K, intrinsic_matrix(620, *SIZE), prior_R=R, prior_t=np.array([-0.1, 0, 0]),
        focal_sigma_rel=(None, 0.1),
    )  # fmt: skip
    assert pose.source == "rotation"
    assert pose.focal_scale[0] == 1.0 and pose.focal_read_sigma_rel[0] is None
    assert abs(620 * pose.focal_scale[1] / 500 - 1) < 0.05


def test_crops_of_a_real_panorama_calibrate_as_one_centre(shared_data, tmp_path):
    """Two perspective crops of real panoramas no model has seen: calibrate fits them as a rotation (the
    report says so, T is the pose head's) and reads R to about a tenth of a degree."""
    from stereogeo_cli import calibrate
    from stereogeo_cli.synth.config import SynthConfig
    from stereogeo_cli.synth.dataset import make_dataset

    held_out = ROOT / "benchmarks" / "panoramas" / "held_out.txt"
    panoramas = tmp_path / "panoramas"
    panoramas.mkdir()
    for name in held_out.read_text().split():
        if not name.startswith("#") and name.endswith(".jpg"):
            (panoramas / name).symlink_to(shared_data / "panoramas" / name)
    folder = tmp_path / "crops"
    config = SynthConfig(panoramas=panoramas, panorama_share=1.0)
    make_dataset(folder, 8, 990001, config, workers=1, progress=False)
    errors, sources = [], []
    for line in (folder / "calib.jsonl").read_text().splitlines():
        truth = json.loads(line)
        result = calibrate(folder / "left" / f"{truth['id']}.png", folder / "right" / f"{truth['id']}.png")
        report = result.report()
        sources.append(report["pose"]["source"])
        if sources[-1] == "rotation":
            assert any("rotation alone" in w for w in report["warnings"])
        errors.append(np.degrees(rotation_error(np.asarray(report["R"]), np.asarray(truth["R"]))))
    # measured: 5 of the 8 read as one centre, their R 0.04-0.14° off (the other three: 0.06° by an
    # essential matrix, 0.8° and 2.5° by the pose head, too few matches)
    turned = [e for e, source in zip(errors, sources, strict=True) if source == "rotation"]
    assert len(turned) >= 4, sources
    assert np.median(turned) < 0.15 and max(turned) < 0.3, turned


def test_the_transfer_jacobian_is_the_derivative_of_its_residuals():
    from stereogeo_cli.fuse.one_centre import _Transfer, default_conf

    rng = np.random.default_rng(6)
    K_left, K_right = intrinsic_matrix(500, *SIZE), intrinsic_matrix(520, *SIZE)
    left = rng.uniform(0, SIZE[0], (50, 2))
    right = left + rng.normal(0, 3, (50, 2))
    R = rotation_from_axis_angle(np.radians([2.0, 5.0, 1.0]))

    def priors(R):
        return (R @ np.array([0.0, -1.0, 0.0]) - np.array([0.05, -1.0, 0.02])) / 0.01

    for free in ([True, True], [False, True], [True, False]):
        for shift in (None, np.array([13.0, 10.0])):
            problem = _Transfer(
                left,
                right,
                K_left,
                K_right,
                0.3,
                np.array(free),
                priors,
                np.eye(sum(free)),
                default_conf,
                shift,
            )
            x = (R, np.array([0.1, -0.05]), np.array([2.0, -1.0]))
            columns = []
            for k in range(problem.size):
                step = np.zeros(problem.size)
                step[k] = 1e-6
                moved = problem.residuals(problem.moved(x, step)) - problem.residuals(problem.moved(x, -step))
                columns.append(moved / 2e-6)
            numeric = np.stack(columns, axis=1)
            assert np.abs(problem.jacobian(x) - numeric).max() < 1e-6 * np.abs(numeric).max()
