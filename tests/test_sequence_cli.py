"""``stereogeo calibrate-sequence`` as a user runs it: rendered sequences with exact ground truth, the files
it writes read back by their readers, bad sources, and an interrupted run."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from stereogeo_cli.geometry import rotation_angle

pytestmark = pytest.mark.slow


def _render(folder: Path, motion: str, frames: int, seed: int) -> Path:
    pytest.importorskip("moderngl")
    from stereogeo_cli.synth.sequence import make_sequence, sequence_config

    # 320 x 240 in a room (texture on every side), as small as COLMAP still matches well
    make_sequence(
        folder, motion, frames, seed, sequence_config(short_side=240, outdoor_share=0.0), progress=False
    )
    return folder


def _stereogeo(*args, check=True, timeout=900) -> subprocess.CompletedProcess:
    env = {**os.environ, "COLUMNS": "120"}
    done = subprocess.run(
        [sys.executable, "-m", "stereogeo_cli", *map(str, args)], capture_output=True, text=True,
        timeout=timeout, env=env,
    )  # fmt: skip
    if check and done.returncode != 0:
        raise AssertionError(f"exit {done.returncode}: {done.stderr}")
    return done


@pytest.fixture(scope="module")
def turning(tmp_path_factory) -> tuple[Path, dict, Path, dict]:
    """A rig turning in a room (16 frames at 320 x 240), calibrated once: (sequence, its ground truth,
    output folder, report)."""
    folder = _render(tmp_path_factory.mktemp("turning") / "seq", "turning", 16, 7)
    out = folder.parent / "out"
    done = _stereogeo("calibrate-sequence", folder, "-o", out, "--json")
    return folder, json.loads((folder / "calib.json").read_text()), out, json.loads(done.stdout)


def test_a_turning_rig_gets_its_focal_length_r_and_t_from_the_sequence(turning):
    _, truth, _, report = turning
    seq = report["sequence"]
    assert seq["frames_registered"] == seq["frames_read"] == 16
    assert seq["focal_observable"] is True
    assert seq["rotation_span_deg"] > 30
    for side in ("left", "right"):
        f_true = truth[side]["K"][0][0]
        error = report[side]["focal_px"] / f_true - 1
        # the pairs alone read renders to ~3 %; the adjustment of 16 frames to well under 1 %
        assert abs(error) < 0.015, (side, error)
        assert abs(error) * f_true < 3 * report[side]["sigma"]["focal_px"]
    R_error = math.degrees(rotation_angle(np.array(report["R"]) @ np.array(truth["R"]).T))
    assert R_error < 0.15
    T, T_true = np.array(report["T"]), np.array(truth["T"])
    assert math.degrees(math.acos(T @ T_true / np.linalg.norm(T) / np.linalg.norm(T_true))) < 1.0
    assert R_error < 3 * report["pose"]["sigma_rotation_deg"]


def test_each_frame_gets_its_roll_and_pitch_in_a_world_with_z_up(turning):
    folder, truth, _, report = turning
    up = np.array(truth["gravity_up_world"])
    errors = []
    for frame in report["sequence"]["frames"]:
        g = np.array(truth["gt_poses"][frame["index"]])[:3, :3].T @ up
        errors.append(math.degrees(math.acos(np.clip(g @ np.array(frame["left"]["gravity_up"]), -1, 1))))
    # one world up from 32 readings (the network's, about 1° each at 320 x 240), within its sigma: the
    # frames' gravity errs as that one up does, the poses add nothing
    sigma = report["sequence"]["world"]["sigma_up_deg"]
    assert np.ptp(errors) < 0.2
    assert np.median(errors) < min(3 * sigma, 2.5)


def test_the_files_load_in_their_readers(turning):
    pycolmap = pytest.importorskip("pycolmap")
    import cv2

    _, _, out, report = turning
    assert json.loads((out / "report.json").read_text()) == report
    fs = cv2.FileStorage(str(out / "intrinsics.yml"), cv2.FILE_STORAGE_READ)
    np.testing.assert_allclose(fs.getNode("M1").mat(), report["left"]["K"])
    model = pycolmap.Reconstruction(out / "sparse" / "0")
    assert model.num_reg_frames() == report["sequence"]["frames_registered"]
    lines = [line for line in (out / "trajectory.txt").read_text().splitlines() if not line.startswith("#")]
    assert len(lines) == report["sequence"]["frames_registered"]
    stamps = [float(line.split()[0]) for line in lines]
    assert stamps == sorted(stamps)
    first = np.array(lines[0].split()[1:4], dtype=float)
    np.testing.assert_allclose(first, 0.0, atol=1e-9)  # the world starts at the first left camera


def test_a_rig_mounted_upside_down_gets_its_gravity_with_rotate_180(tmp_path, turning):
    """The turning rig turned 180° about its view, its cameras keeping their names (each sees the other's
    view turned): without --rotate every frame's gravity comes out reversed; with it, as upright."""
    import cv2

    folder, truth, _, upright = turning
    turned = tmp_path / "turned"
    for side, other in (("left", "right"), ("right", "left")):
        (turned / side).mkdir(parents=True)
        for path in sorted((folder / other).iterdir()):
            cv2.imwrite(
                str(turned / side / path.name), cv2.imread(str(path), cv2.IMREAD_UNCHANGED)[::-1, ::-1]
            )
    up, R = np.array(truth["gravity_up_world"]), np.array(truth["R"])
    flip = np.diag([-1.0, -1.0, 1.0])  # the named left camera's frame is the right camera's turned

    def errors(report):
        out = []
        for frame in report["sequence"]["frames"]:
            g = flip @ R @ np.array(truth["gt_poses"][frame["index"]])[:3, :3].T @ up
            out.append(math.degrees(math.acos(np.clip(g @ np.array(frame["left"]["gravity_up"]), -1, 1))))
        return np.array(out)

    plain = json.loads(_stereogeo("calibrate-sequence", turned, "--json", "--no-progress").stdout)
    assert np.median(errors(plain)) > 170
    report = json.loads(
        _stereogeo("calibrate-sequence", turned, "--json", "--no-progress", "--rotate", "180").stdout
    )
    assert report["sequence"]["frames_registered"] == 16 and report["rotate_deg"] == 180
    assert np.median(errors(report)) < min(3 * report["sequence"]["world"]["sigma_up_deg"], 2.5)
    assert report["left"]["focal_px"] == pytest.approx(upright["right"]["focal_px"], rel=0.015)
    T_upright = flip @ (-np.array(upright["R"]).T @ np.array(upright["T"]))
    assert (
        np.degrees(
            np.arccos(T_upright @ report["T"] / np.linalg.norm(T_upright) / np.linalg.norm(report["T"]))
        )
        < 1
    )


def test_a_static_rig_is_calibrated_from_its_pairs_and_says_so(tmp_path):
    folder = _render(tmp_path / "seq", "static", 4, 7)
    done = _stereogeo("calibrate-sequence", folder, "--json", check=False)
    assert "Traceback" not in done.stderr
    if done.returncode == 3:  # nothing to reconstruct from: one line saying why
        assert len(done.stderr.strip().splitlines()) == 1
        return
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert report["sequence"]["focal_observable"] is False
    truth = json.loads((folder / "calib.json").read_text())
    f_true = truth["left"]["K"][0][0]
    assert abs(report["left"]["focal_px"] - f_true) < 3 * report["left"]["sigma"]["focal_px"]


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["missing-folder"], "missing-folder"),
        (["--sbs", "broken.mp4"], "broken.mp4"),
    ],
)
def test_a_bad_source_is_one_line_and_exit_2(tmp_path, args, words):
    (tmp_path / "broken.mp4").write_bytes(os.urandom(4096))
    done = subprocess.run(
        [sys.executable, "-m", "stereogeo_cli", "calibrate-sequence", *args, "-o", "out"], cwd=tmp_path,
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0]
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_an_interrupted_sequence_writes_nothing_and_exits_130(tmp_path, turning):
    folder = turning[0]
    out = tmp_path / "out"
    process = subprocess.Popen(
        [sys.executable, "-m", "stereogeo_cli", "calibrate-sequence", folder, "-o", out, "--no-progress"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    time.sleep(6)  # the network is loaded and frames are being read
    process.send_signal(signal.SIGINT)
    stdout, stderr = process.communicate(timeout=300)
    assert process.returncode == 130, stderr
    assert "Traceback" not in stderr
    assert "nothing was written" in stderr
    assert not out.exists() or not any(out.rglob("*"))


def test_a_side_by_side_video_calibrates_as_its_frames_do(tmp_path, turning):
    """The turning sequence as one lossless side-by-side video: the same rig from the video's frames."""
    import cv2
    from test_sequence_sources import write_video

    folder, truth, _, report = turning
    frames = []
    for name in sorted(p.name for p in (folder / "left").iterdir()):
        left, right = (cv2.imread(str(folder / side / name))[..., ::-1] for side in ("left", "right"))
        frames.append(np.concatenate([left, right], axis=1))
    write_video(tmp_path / "sbs.mkv", frames, "FFV1", fps=8)
    done = _stereogeo("calibrate-sequence", "--sbs", tmp_path / "sbs.mkv", "--json")
    from_video = json.loads(done.stdout)
    assert from_video["sequence"]["frames_read"] == 16
    assert from_video["sequence"]["frames"][1]["time"] == pytest.approx(1 / 8)
    for side in ("left", "right"):
        assert from_video[side]["focal_px"] == pytest.approx(truth[side]["K"][0][0], rel=0.015)


def test_a_bag_without_the_topic_is_one_line_and_exit_2(tmp_path):
    from test_sequence_sources import ROS1, image_msg, write_bag

    store = ROS1
    image = np.zeros((80, 96), np.uint8)
    write_bag(tmp_path / "run.bag", {"/cam0/image_raw": [image_msg(store, 10**9, image, "mono8")]})
    done = subprocess.run(
        [sys.executable, "-m", "stereogeo_cli", "calibrate-sequence", "run.bag", "--left-topic",
         "/cam0/image_raw", "--right-topic", "/cam1/image_raw", "-o", "out"], cwd=tmp_path,
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "/cam1/image_raw" in lines[0]
    assert not (tmp_path / "out").exists()
