"""make-data --sequence with the effects of real recordings, and the drive motion: each effect does what it
says, each is off by default, and switching one on leaves the rest of the sequence as it was.

Tiny renders (EGL, Mesa llvmpipe) of 5 frames at 160×120, as in test_synth_sequence.py.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from stereogeo_cli.cli import app
from stereogeo_cli.synth.check import reproject_depth
from stereogeo_cli.synth.effects import SequenceEffects, exposure_gains
from stereogeo_cli.synth.sequence import (
    DRIVE_RATE_HZ,
    make_sequence,
    plan_sequence,
    read_sequence_ground_truth,
    sequence_config,
)
from stereogeo_cli.synth.traffic import ROAD_CAMERA_HEIGHT_M

CONFIG = sequence_config(short_side=120, texture_size=128, texture_layers=24, depth=True)
FLAT = CONFIG.replace(augment=0.0)  # no photometric changes: colour renders comparable pixel for pixel
FRAMES = 5
SEED = 3


class Renders:
    """Sequences rendered once per module, by name."""

    def __init__(self, root: Path):
        self.root, self.made = root, {}

    def __call__(self, name: str, motion: str, config=CONFIG, **effects) -> Path:
        if name not in self.made:
            folder = self.root / name
            make_sequence(
                folder, motion, FRAMES, SEED, config, progress=False, effects=SequenceEffects(**effects)
            )
            self.made[name] = folder
        return self.made[name]


@pytest.fixture(scope="module")
def render(tmp_path_factory) -> Renders:
    return Renders(tmp_path_factory.mktemp("effects"))


def _calib(folder: Path) -> dict:
    return json.loads((folder / "calib.json").read_text())


def _image(folder: Path, side: str, k: int) -> np.ndarray:
    return cv2.imread(str(folder / side / f"{k:06d}.png"), cv2.IMREAD_UNCHANGED).astype(np.float64)


def _depth(folder: Path, side: str, k: int) -> np.ndarray:
    return np.load(folder / "depth" / side / f"{k:06d}.npy")


def _same_world(a: Path, b: Path) -> None:
    """The two sequences share scene draws and poses: only the effect differs."""
    ca, cb = _calib(a), _calib(b)
    for key in ("gt_poses", "R", "T", "timestamps", "scene"):
        assert ca[key] == cb[key], key
    assert ca["extra"]["scene_attempts"] == cb["extra"]["scene_attempts"]


def _reprojection_error(depth_from: np.ndarray, depth_to: np.ndarray, calib: dict) -> float:
    """Median relative disagreement of the left depth moved by calib (K, R, T) with the right depth map."""
    x, y, z = reproject_depth(depth_from, calib)
    h, w = depth_to.shape
    inside = (z > 0) & (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
    x, y, z = x[inside].astype(np.float32), y[inside].astype(np.float32), z[inside]
    seen = np.concatenate(
        [
            cv2.remap(depth_to, x[None, i : i + 30000], y[None, i : i + 30000], cv2.INTER_LINEAR)[0]
            for i in range(0, len(x), 30000)
        ]
    )  # fmt: skip  (remap maps < 32767 wide)
    visible = seen > 0.97 * z
    assert visible.sum() > 1000
    return float(np.median(np.abs(seen[visible] - z[visible]) / z[visible]))


def test_defaults_are_off_and_change_nothing(render, tmp_path):
    assert not SequenceEffects().active
    base = render("base", "turning")
    calib = _calib(base)
    assert "effects" not in calib["extra"] and "principal point exactly (w/2, h/2)" in calib["notes"]
    K = np.array(calib["left"]["K"])
    assert (K[0, 2], K[1, 2], K[0, 0]) == (80.0, 60.0, K[1, 1])
    assert sorted(p.name for p in base.iterdir()) == ["calib.json", "depth", "left", "right"]
    # effects set to their neutral values: the very same frames
    neutral = tmp_path / "neutral"
    make_sequence(neutral, "turning", FRAMES, SEED, CONFIG, progress=False,
                  effects=SequenceEffects(principal_offset=(0.0, 0.0), exposure_stops=0.0))  # fmt: skip
    for path in sorted(base.rglob("*.png")) + sorted(base.rglob("*.npy")):
        assert (neutral / path.relative_to(base)).read_bytes() == path.read_bytes(), path
    _same_world(base, neutral)


def test_principal_offset_moves_the_render_with_K(render):
    """dx = 4 px, dy = -3 px: the frames are the centred ones moved by (4, -3) pixels, and K says so."""
    base = render("flat", "turning", FLAT)
    moved = render("flat-offset", "turning", FLAT, principal_offset=(4 / 160, -3 / 120))
    _same_world(base, moved)
    calib = _calib(moved)
    for side in ("left", "right"):
        K = np.array(calib[side]["K"])
        np.testing.assert_allclose(K[:2, 2], [84.0, 57.0], atol=1e-12)
    assert "principal point (84, 57)" in calib["notes"] and "exactly" not in calib["notes"]
    assert calib["extra"]["effects"]["principal_offset"] == [0.025, -0.025]
    for k in (0, FRAMES - 1):
        for side in ("left", "right"):
            d0, d1 = _depth(base, side, k), _depth(moved, side, k)
            np.testing.assert_allclose(d1[:-3, 4:], d0[3:, :-4], rtol=1e-5)  # pixel (u, v) → (u + 4, v - 3)
            difference = np.abs(_image(moved, side, k)[:-3, 4:] - _image(base, side, k)[3:, :-4])
            assert difference.mean() < 0.5


def test_focal_aspect_and_offset_render_with_the_K_of_calib_json(render):
    """Depth moved left → right with calib.json's K (fy = 1.02 fx, principal point off-centre) lands on the
    right depth to float precision; the ideal K (fx = fy, centred) misses by far more."""
    folder = render("aspect", "turning", focal_aspect=1.02, principal_offset=(-0.03, 0.02))
    calib = _calib(folder)
    K = np.array(calib["left"]["K"])
    assert K[1, 1] == pytest.approx(1.02 * K[0, 0], rel=1e-12)
    np.testing.assert_allclose(K[:2, 2], [80 - 0.03 * 160, 60 + 0.02 * 120], atol=1e-12)
    assert calib["right"]["K"][1][1] == pytest.approx(1.02 * calib["right"]["K"][0][0], rel=1e-12)
    ideal = json.loads(json.dumps(calib))
    for side in ("left", "right"):
        f = ideal[side]["K"][0][0]
        ideal[side]["K"] = [[f, 0.0, 80.0], [0.0, f, 60.0], [0.0, 0.0, 1.0]]
    for k in (0, FRAMES - 1):
        left, right = _depth(folder, "left", k), _depth(folder, "right", k)
        assert _reprojection_error(left, right, calib) < 3e-4
        assert _reprojection_error(left, right, ideal) > 3 * _reprojection_error(left, right, calib)


def test_projection_with_K_lands_on_the_drawn_road(render):
    """A drive with an off-centre principal point and fy ≠ fx: the road's pixels at the bottom of the
    image, moved back to the world with calib.json's K and pose, lie on the road plane (z = 0)."""
    folder = render("drive-K", "drive", CONFIG, principal_offset=(0.03, -0.03), focal_aspect=0.99)
    gt = read_sequence_ground_truth(folder)
    for k in (0, FRAMES - 1):
        depth = _depth(folder, "left", k)
        h, w = depth.shape
        ys, xs = np.mgrid[h - 12 : h, w // 2 - 20 : w // 2 + 20]
        f = gt["K_left"][0, 0]
        heights = {}
        for name, K in (
            ("calib", gt["K_left"]),
            ("ideal", np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]])),
        ):
            rays = np.linalg.inv(K) @ np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)])
            X = gt["gt_poses"][k][:3, :3] @ (rays * depth[ys, xs].ravel()) + gt["gt_poses"][k][:3, 3:]
            heights[name] = float(np.median(np.abs(X[2])))
        assert heights["calib"] < 2e-3 and heights["ideal"] > 5 * heights["calib"] + 5e-3


def test_h264_changes_the_pixels_but_keeps_them_close(render, tmp_path):
    base = render("base", "turning")
    coded = render("h264", "turning", h264_kbps=40.0, keep_video=True)
    _same_world(base, coded)
    for side in ("left", "right"):
        for k in range(FRAMES):
            a, b = _image(base, side, k), _image(coded, side, k)
            assert a.shape == b.shape and not np.array_equal(a, b)
            psnr = 10 * np.log10(255.0**2 / np.mean((a - b) ** 2))
            assert 22.0 < psnr < 50.0, psnr
        capture = cv2.VideoCapture(str(coded / f"{side}.mp4"))  # what calibrate-sequence --video reads
        frames = []
        while (grabbed := capture.read())[0]:
            frames.append(grabbed[1])
        capture.release()
        assert len(frames) == FRAMES and frames[0].shape == (120, 160, 3)
        assert np.abs(frames[2].astype(float) - _image(coded, side, 2)).mean() < 3.0
    extra = _calib(coded)["extra"]
    assert extra["h264"]["kbps"] == 40.0 and extra["h264"]["video"] == ["left.mp4", "right.mp4"]
    again = tmp_path / "again"
    make_sequence(
        again, "turning", FRAMES, SEED, CONFIG, progress=False, effects=SequenceEffects(h264_kbps=40.0)
    )
    assert not (again / "left.mp4").exists()
    for path in sorted(coded.rglob("*.png")):
        assert (again / path.relative_to(coded)).read_bytes() == path.read_bytes()  # the same bytes


def test_exposure_changes_from_frame_to_frame_and_between_the_cameras(render):
    still = render("static-flat", "static", FLAT)
    lit = render("static-exposure", "static", FLAT, exposure_stops=0.7)
    _same_world(still, lit)
    gains = np.array(_calib(lit)["extra"]["exposure_gain"])
    assert gains.shape == (FRAMES, 2) and np.ptp(np.log2(gains[:, 0])) > 0.2
    assert np.abs(np.log2(gains[:, 1] / gains[:, 0])).max() > 0.005
    np.testing.assert_array_equal(gains, exposure_gains(SEED, 4, np.linspace(0, 5, FRAMES), 0.7))
    for side, column in (("left", 0), ("right", 1)):
        reference = _image(still, side, 0)
        assert all(np.array_equal(_image(still, side, k), reference) for k in range(FRAMES))
        means = np.array([_image(lit, side, k).mean() for k in range(FRAMES)])
        assert np.ptp(means) > 5.0
        unclipped = reference < 150  # pixels the brightest gain does not saturate
        measured = [np.median(_image(lit, side, k)[unclipped] / np.maximum(reference[unclipped], 1)) for k in
                    range(FRAMES)]  # fmt: skip
        np.testing.assert_allclose(measured, gains[:, column], rtol=0.03)


def test_motion_blur_smears_along_the_motion(render):
    sharp = render("flat", "turning", FLAT)
    blurred = render("flat-blur", "turning", FLAT, motion_blur_ms=60.0)
    _same_world(sharp, blurred)
    assert _calib(blurred)["extra"]["motion_blur_subframes"] >= 4
    for k in (1, FRAMES - 2):
        a, b = _image(sharp, "left", k), _image(blurred, "left", k)
        detail = [cv2.Laplacian(cv2.cvtColor(im.astype(np.uint8), cv2.COLOR_BGR2GRAY), cv2.CV_64F).var()
                  for im in (a, b)]  # fmt: skip
        assert detail[1] < 0.8 * detail[0]
        # a turn sweeps the view sideways: the blur is horizontal, so rows stay sharper than columns
        dx, dy = (
            np.abs(np.diff(b, axis=axis)).mean() / np.abs(np.diff(a, axis=axis)).mean() for axis in (1, 0)
        )
        assert dx < dy
        np.testing.assert_array_equal(
            _depth(sharp, "left", k), _depth(blurred, "left", k)
        )  # depth: mid-exposure


def test_moving_objects_move_against_the_world(render):
    """A rig standing still in a street: between frames only the moving cars and people change the depth."""
    config = CONFIG.replace(outdoor_share=1.0)
    still = render("static-street", "static", config)
    busy = render("static-street-movers", "static", config, moving_objects=8)
    _same_world(still, busy)
    movers = _calib(busy)["extra"]["moving_objects"]
    assert 1 <= len(movers) <= 8 and {m["kind"] for m in movers} <= {"car", "person"}
    d_still = [_depth(still, "left", k) for k in range(FRAMES)]
    d_busy = [_depth(busy, "left", k) for k in range(FRAMES)]
    assert all(np.array_equal(d, d_still[0]) for d in d_still)
    changed = [np.mean(d_busy[k] != d_busy[0]) for k in range(1, FRAMES)]
    assert max(changed) > 0.002  # something moved...
    assert max(changed) < 0.5  # ...and the world did not
    unchanged = d_busy[0] == d_busy[-1]
    np.testing.assert_array_equal(d_busy[0][unchanged], d_still[0][unchanged])
    # where the world shows, it is the world of the sequence without movers; movers are nearer
    nearer = d_busy[0] != d_still[0]
    assert np.all((d_busy[0][nearer] < d_still[0][nearer]) | (d_still[0][nearer] == 0))


def test_drive_has_a_cars_height_rate_and_turn():
    config = sequence_config("drive", short_side=94, texture_size=128, texture_layers=24)
    assert (config.short_side, config.vfov_deg, config.baseline_m) == (94, (27.0, 33.0), (0.45, 0.6))
    frames = 40
    plan = plan_sequence("drive", frames, seed=SEED, config=config)
    plan.release()
    calib, extra = plan.calib, plan.calib["extra"]
    params = extra["motion_params"]
    assert (calib["left"]["width"], calib["left"]["height"]) == (310, 94)  # a quarter of 1240 × 376
    assert calib["scene"] == "road" and extra["rate_hz"] == DRIVE_RATE_HZ == 10.0
    np.testing.assert_allclose(calib["timestamps"], np.arange(frames) / 10.0, atol=1e-12)
    poses = np.array(calib["gt_poses"])
    assert np.all(np.abs(poses[:, 2, 3] - ROAD_CAMERA_HEIGHT_M) < 0.02)  # 1.6 m above the road, bouncing
    speed = extra["path_length_m"] / extra["duration_s"]
    assert 8.0 <= speed <= 12.2 and params["speed_mps"] == pytest.approx(speed, rel=0.01)
    # the heading turns by 6–12° in all, about the vertical, and the drive runs along the optical axis
    heading = np.degrees(np.arctan2(poses[:, 1, 2], poses[:, 0, 2]))
    assert 6.0 <= abs(heading[-1] - heading[0]) <= 12.0
    assert heading[-1] - heading[0] == pytest.approx(np.degrees(params["turn_rad"]), abs=0.3)
    step = poses[1, :3, 3] - poses[0, :3, 3]
    assert (step @ poses[0, :3, 2]) / np.linalg.norm(step) > 0.99
    # the suspension: pitch and roll bounce by a few tenths of a degree around the rig's mounting
    for key in ("roll_deg", "pitch_deg"):
        assert 0.05 < np.ptp(extra[key]) < 1.0
    # a car's rig, rectified: a baseline of 0.45–0.6 m along x, no rotation, one K for both cameras
    T = np.array(calib["T"])
    assert 0.45 <= np.linalg.norm(T) <= 0.6
    np.testing.assert_allclose(T[1:], 0.0, atol=1e-9)
    np.testing.assert_allclose(np.array(calib["R"]), np.eye(3), atol=1e-9)
    np.testing.assert_allclose(calib["left"]["K"], calib["right"]["K"], atol=1e-9)


def test_cli_takes_the_effects_and_refuses_bad_ones(tmp_path):
    runner = CliRunner()
    out = tmp_path / "drive"
    args = ["make-data", str(out), "--sequence", "drive", "-n", "2", "--no-progress",
            "--principal-offset", "0.01,-0.02", "--focal-aspect", "1.01"]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    calib = _calib(out)
    K = np.array(calib["left"]["K"])
    assert (calib["left"]["width"], calib["left"]["height"]) == (1240, 376)  # the drive's defaults
    np.testing.assert_allclose(K[:2, 2], [620 + 12.4, 188 - 7.52], atol=1e-9)
    assert K[1, 1] == pytest.approx(1.01 * K[0, 0]) and 27 <= calib["extra"]["vfov_deg"][0] <= 33
    x = str(tmp_path / "x")
    for bad in (
        ["make-data", x, "--sequence", "turning", "--principal-offset", "0.05,0"],
        ["make-data", x, "--sequence", "turning", "--principal-offset", "left"],
        ["make-data", x, "--sequence", "turning", "--focal-aspect", "1.2"],
        ["make-data", x, "--sequence", "turning", "--keep-video"],
        ["make-data", x, "--sequence", "turning", "--h264", "0"],
        ["make-data", x, "--sequence", "turning", "--moving-objects", "-1"],
        ["make-data", x, "-n", "1", "--motion-blur", "20"],  # pairs have no effects
    ):
        result = runner.invoke(app, bad)
        assert result.exit_code == 2, (bad, result.output)
        assert "Traceback" not in result.output
