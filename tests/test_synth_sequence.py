"""make-data --sequence: the folder layout, motions that are what they say, and exact per-frame ground truth.

These tests render (EGL, Mesa llvmpipe), like the other synth tests: tiny sequences of 5 frames at 160×120.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from stereogeo_cli.cli import app
from stereogeo_cli.geometry import gravity_from_roll_pitch, rotation_angle, rotation_from_axis_angle
from stereogeo_cli.synth.check import depth_agreement, reproject_depth
from stereogeo_cli.synth.sequence import (
    MOTIONS,
    distance_to_triangles,
    make_sequence,
    read_sequence_ground_truth,
    sequence_config,
)

CONFIG = sequence_config(short_side=120, texture_size=128, texture_layers=24, depth=True)
FRAMES = 5
SEED = 3


@pytest.fixture(scope="module")
def sequences(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("sequences")
    for motion in MOTIONS:
        make_sequence(root / motion, motion, FRAMES, seed=SEED, config=CONFIG, progress=False)
    return {motion: root / motion for motion in MOTIONS}


def _relative(P_from: np.ndarray, P_to: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, T) with x_to = R x_from + T for two camera-to-world poses [4 x 4]."""
    M = np.linalg.inv(P_to) @ P_from
    return M[:3, :3], M[:3, 3]


def _angles_deg(gt: dict) -> np.ndarray:
    """Rotation of every frame against frame 0, degrees [N]."""
    R0 = gt["gt_poses"][0, :3, :3]
    return np.array([np.degrees(rotation_angle(R0.T @ P[:3, :3])) for P in gt["gt_poses"]])


def _span(gt: dict) -> float:
    c = gt["gt_poses"][:, :3, 3]
    return float(np.linalg.norm(c[:, None] - c[None], axis=-1).max())


@pytest.mark.parametrize("motion", MOTIONS)
def test_layout_and_calib(sequences, motion):
    folder = sequences[motion]
    calib = json.loads((folder / "calib.json").read_text())
    assert set(calib) >= {"left", "right", "R", "T", "timestamps", "gt_poses", "gravity_up_world", "extra"}
    assert (calib["motion"], calib["seed"]) == (motion, SEED)
    names = [f"{k:06d}" for k in range(FRAMES)]
    for side in ("left", "right"):
        cam = calib[side]
        assert set(cam) == {"K", "dist", "width", "height"} and cam["dist"] == []
        w, h = cam["width"], cam["height"]
        assert (w, h) == (160, 120)
        K = np.array(cam["K"])
        assert K[0, 2] == w / 2 and K[1, 2] == h / 2 and K[0, 0] == K[1, 1]  # principal point (w/2, h/2)
        assert sorted(p.stem for p in (folder / side).iterdir()) == names
        for name in names:
            image = cv2.imread(str(folder / side / f"{name}.png"), cv2.IMREAD_UNCHANGED)
            assert image.shape == (h, w, 3) and image.dtype == np.uint8
            depth = np.load(folder / "depth" / side / f"{name}.npy")
            assert depth.shape == (h, w) and depth.dtype == np.float32
    R, T = np.array(calib["R"]), np.array(calib["T"])
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    if motion == "drive":  # a car's rig, rectified: no rotation, the baseline along x
        np.testing.assert_allclose(R, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(T[1:], 0.0, atol=1e-12)
    else:
        assert 0.5 - 1e-6 <= np.degrees(rotation_angle(R)) <= 2.0 + 1e-6  # small, never the identity
    assert 0.1 <= np.linalg.norm(T) <= 0.5 and T[0] < 0  # the right camera to the left camera's right
    assert np.all(np.diff(calib["timestamps"]) > 0) and len(calib["timestamps"]) == FRAMES
    poses = np.array(calib["gt_poses"])
    assert poses.shape == (FRAMES, 4, 4)
    for P in poses:
        np.testing.assert_allclose(P[:3, :3].T @ P[:3, :3], np.eye(3), atol=1e-12)
        np.testing.assert_array_equal(P[3], [0, 0, 0, 1])
    assert calib["gravity_up_world"] == [0.0, 0.0, 1.0]


def test_reader_gives_arrays_and_the_project_gravity(sequences):
    for motion, folder in sequences.items():
        gt = read_sequence_ground_truth(folder)
        assert len(gt["left_images"]) == len(gt["right_images"]) == FRAMES
        assert gt["gt_poses"].shape == (FRAMES, 4, 4) and gt["timestamps"].shape == (FRAMES,)
        assert gt["K_left"].shape == gt["K_right"].shape == (3, 3) and gt["dist_left"].size == 0
        assert gt["R"].shape == (3, 3) and gt["T"].shape == (3,) and gt["size_left"] == (160, 120)
        # the world's up seen in the left camera: gravity_from_roll_pitch of the frame's roll and pitch
        extra = gt["extra"]
        expected = gravity_from_roll_pitch(np.radians(extra["roll_deg"]), np.radians(extra["pitch_deg"]))
        np.testing.assert_allclose(gt["gravity_left"], expected, atol=1e-12)
        np.testing.assert_allclose(gt["gravity_right"], gt["gravity_left"] @ gt["R"].T, atol=1e-12)
        assert (gt["motion"], gt["scene"]) == (motion, gt["calib"]["scene"])
        if motion not in ("handheld", "drive"):  # the rig's own small roll and pitch, held while it moves
            assert np.ptp(extra["roll_deg"]) < 1e-9 and np.ptp(extra["pitch_deg"]) <= 0.2  # road bumps
            assert max(np.abs(extra["roll_deg"]).max(), np.abs(extra["pitch_deg"]).max()) <= 5.2


def test_poses_follow_the_motion(sequences):
    gt = {motion: read_sequence_ground_truth(folder) for motion, folder in sequences.items()}
    straight, turning, handheld = gt["straight"], gt["turning"], gt["handheld"]

    assert _angles_deg(straight).max() <= 1.0
    assert _span(straight) >= 2.0
    P0, P1 = straight["gt_poses"][0], straight["gt_poses"][-1]
    direction = (P1[:3, 3] - P0[:3, 3]) @ P0[:3, :3]  # the drive in the first frame's camera coordinates
    assert direction[2] / np.linalg.norm(direction) > np.cos(np.radians(6))  # along the optical axis

    yaw_span = _angles_deg(turning)[-1]
    assert 55.0 <= yaw_span <= 100.0 and _span(turning) >= 1.0
    axis = np.array([0.0, 0.0, 1.0])  # the turn is about the world's vertical
    R_first, R_last = turning["gt_poses"][0, :3, :3], turning["gt_poses"][-1, :3, :3]
    rotvec = np.linalg.svd(R_last @ R_first.T - np.eye(3))[2][-1]
    assert abs(rotvec @ axis) > 0.99

    assert 0.05 <= _span(handheld) <= 0.8
    assert 8.0 <= _angles_deg(handheld).max() <= 60.0
    extra = handheld["extra"]
    yaw = [np.degrees(np.arctan2(P[1, 2], P[0, 2])) for P in handheld["gt_poses"]]
    assert min(np.ptp(extra["roll_deg"]), np.ptp(extra["pitch_deg"]), np.ptp(yaw)) > 2.0  # every axis

    static = gt["static"]
    assert np.all(static["gt_poses"] == static["gt_poses"][0])
    for side in ("left", "right"):
        files = [(sequences["static"] / side / f"{k:06d}.png").read_bytes() for k in range(FRAMES)]
        assert all(f == files[0] for f in files)


def _depth_error(depth_from: np.ndarray, depth_to: np.ndarray, calib: dict) -> float:
    """Median relative disagreement of the depth moved by ``calib`` (K, R, T) with the target depth map,
    read bilinearly where the target sees the point (not hidden behind something > 3 % nearer)."""
    x, y, z = reproject_depth(depth_from, calib)
    h, w = depth_to.shape
    inside = (z > 0) & (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
    x, y, z = x[inside].astype(np.float32), y[inside].astype(np.float32), z[inside]
    seen = cv2.remap(depth_to, x[None], y[None], cv2.INTER_LINEAR)[0]
    visible = seen > 0.97 * z
    assert visible.sum() > 1000
    return float(np.median(np.abs(seen[visible] - z[visible]) / z[visible]))


@pytest.mark.parametrize("motion", MOTIONS)
def test_ground_truth_is_exact(sequences, motion):
    """Depth maps moved by the ground truth land on the other depth maps, to float precision: left →
    right in every frame (K, R, T) and left frame k → left frame k + 1 (the gt_poses)."""
    folder = sequences[motion]
    calib = json.loads((folder / "calib.json").read_text())
    gt = read_sequence_ground_truth(folder)
    depth = {
        (side, k): np.load(folder / "depth" / side / f"{k:06d}.npy")
        for side in ("left", "right")
        for k in range(FRAMES)
    }
    for k in range(FRAMES):
        assert depth_agreement(depth["left", k], depth["right", k], calib).fraction >= 0.95
        assert _depth_error(depth["left", k], depth["right", k], calib) < 3e-4  # ~5e-5: float32 depth
    cam = {"K": calib["left"]["K"]}
    for k in range(FRAMES - 1):
        R, T = _relative(gt["gt_poses"][k], gt["gt_poses"][k + 1])
        step = {"left": cam, "right": cam, "R": R.tolist(), "T": T.tolist()}
        assert depth_agreement(depth["left", k], depth["left", k + 1], step).fraction >= 0.95
        assert _depth_error(depth["left", k], depth["left", k + 1], step) < 3e-4
    # a pose 1° off disagrees ten times as much
    R, T = _relative(gt["gt_poses"][0], gt["gt_poses"][1])
    tilted = rotation_from_axis_angle(np.radians([0.0, 1.0, 0.0])) @ R
    wrong = {"left": cam, "right": cam, "R": tilted.tolist(), "T": T.tolist()}
    assert _depth_error(depth["left", 0], depth["left", 1], wrong) > 1e-3


def test_same_arguments_same_bytes_and_a_rerun_replaces_the_sequence(tmp_path, sequences):
    make_sequence(tmp_path / "again", "handheld", FRAMES, seed=SEED, config=CONFIG, progress=False)
    first = sequences["handheld"]
    for path in sorted(first.rglob("*")):
        if path.is_file():
            assert (tmp_path / "again" / path.relative_to(first)).read_bytes() == path.read_bytes()
    (tmp_path / "again" / "calib.json").unlink()  # as if interrupted: frames but no calib.json yet
    make_sequence(tmp_path / "again", "handheld", 2, seed=SEED, config=CONFIG, progress=False)
    assert sorted(p.name for p in (tmp_path / "again" / "left").iterdir()) == ["000000.png", "000001.png"]
    assert len(read_sequence_ground_truth(tmp_path / "again")["gt_poses"]) == 2


def test_distance_to_triangles():
    square = np.array([[[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 0, 0], [1, 1, 0], [0, 1, 0]]], float)
    points = np.array([[0.5, 0.5, 2.0], [2.0, 0.5, 0.0], [2.0, 2.0, -1.0], [0.2, 0.7, -0.3]])
    expected = [2.0, 1.0, np.sqrt(3.0), 0.3]
    np.testing.assert_allclose(distance_to_triangles(points, square), expected, atol=1e-12)
    np.testing.assert_allclose(distance_to_triangles(points, square, 1.5), np.minimum(expected, 1.5))


def test_reader_reads_the_real_sequences(shared_data):
    REAL = shared_data / "real-dev" / "sequences"
    euroc = read_sequence_ground_truth(REAL / "euroc_mh01_excitation_stereo")
    n = len(euroc["left_images"])
    assert n == len(euroc["right_images"]) == len(euroc["timestamps"]) > 0
    assert euroc["gt_poses"] is None and euroc["dist_left"].shape == (4,) and euroc["R"].shape == (3, 3)
    mono = read_sequence_ground_truth(REAL / "vamr_ex1_checkerboard_mono")
    assert mono["right_images"] is None and mono["K_right"] is None and mono["R"] is None
    assert mono["gt_poses"].shape == (len(mono["left_images"]), 4, 4)


def test_cli_writes_a_sequence_and_refuses_bad_requests(tmp_path):
    runner = CliRunner()
    out = tmp_path / "seq"
    args = ["make-data", str(out), "--sequence", "turning", "-n", "2", "--size", "96", "--no-progress"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    calib = json.loads((out / "calib.json").read_text())
    assert (calib["left"]["width"], calib["left"]["height"], len(calib["gt_poses"])) == (128, 96, 2)
    assert 45 <= calib["extra"]["vfov_deg"][0] <= 80  # the sequence defaults
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("mine")
    for bad in (
        ["make-data", str(tmp_path / "x"), "--sequence", "spinning"],
        ["make-data", str(tmp_path / "x"), "--sequence", "static", "--preview", str(tmp_path / "p.png")],
        ["make-data", str(tmp_path / "other"), "--sequence", "static", "-n", "1"],
    ):
        result = runner.invoke(app, bad)
        assert result.exit_code == 2, (bad, result.output)
        assert "Traceback" not in result.output
    assert (tmp_path / "other" / "notes.txt").read_text() == "mine"


def test_rate_sets_the_frame_times_and_keeps_a_turns_shape(tmp_path):
    """--rate HZ: frames 1/HZ apart (calib.json and the H.264 videos), the turn shaped over the sequence as
    without it; a rate ≤ 0, or one for pairs, is refused in one line."""
    import av

    runner = CliRunner()
    base = ["--sequence", "turning", "-n", "3", "--size", "96", "--no-progress"]
    for name, extra in (("plain", []), ("rated", ["--rate", "30", "--h264", "200", "--keep-video"])):
        result = runner.invoke(app, ["make-data", str(tmp_path / name), *base, *extra])
        assert result.exit_code == 0, result.output
    plain, rated = (json.loads((tmp_path / n / "calib.json").read_text()) for n in ("plain", "rated"))
    np.testing.assert_allclose(np.diff(rated["timestamps"]), 1 / 30, rtol=1e-12)
    assert rated["timestamps"][0] == 0.0
    assert rated["extra"]["rate_hz"] == 30.0 and rated["extra"]["duration_s"] == pytest.approx(2 / 30)
    assert plain["extra"]["rate_hz"] == pytest.approx(2 / 6.0)  # the turn's own 6 s without --rate
    np.testing.assert_allclose(rated["gt_poses"], plain["gt_poses"], atol=1e-12)  # same turn, faster
    with av.open(str(tmp_path / "rated" / "left.mp4")) as video:
        assert video.streams.video[0].average_rate == 30
    for bad in (["--rate", "0"], ["--rate", "-5"]):
        result = runner.invoke(app, ["make-data", str(tmp_path / "bad"), *base, *bad])
        assert result.exit_code == 2, result.output
        assert "--rate must be > 0" in result.output and "Traceback" not in result.output
    result = runner.invoke(app, ["make-data", str(tmp_path / "pairs"), "-n", "2", "--rate", "30"])
    assert result.exit_code == 2 and "--rate" in result.output, result.output
    assert not (tmp_path / "bad").exists()


def test_rate_lets_a_handheld_sweep_run_in_seconds():
    """A hand-held sweep's sinusoids are in seconds: at a rate its time, not its shape over u, is kept, and
    its peak stays within the drawn amplitude over a longer sequence."""
    from stereogeo_cli.synth.sequence import sample_motion

    short = sample_motion(np.random.default_rng(7), "handheld", False)
    long = sample_motion(np.random.default_rng(7), "handheld", False, duration=50.0)
    t = np.linspace(0.0, 5.0, 101)
    xyz_short = short.at(t / 5.0)[0]
    xyz_long = long.at(t / 50.0)[0]
    # the same sinusoids at the same seconds, scaled by their peak over 5 s and over 50 s
    peaks = np.array([[m.params[k]["peak"] for k in ("x", "y", "z")] for m in (short, long)])
    assert np.all(peaks[1] >= peaks[0])
    np.testing.assert_allclose(xyz_long, xyz_short * peaks[0] / peaks[1], rtol=1e-9, atol=1e-15)
    full = long.at(np.linspace(0.0, 1.0, 4001))[0]
    amplitude = [long.params[k]["amplitude"] for k in ("x", "y", "z")]
    assert np.all(np.abs(full).max(axis=0) <= np.array(amplitude) * (1 + 1e-3))
