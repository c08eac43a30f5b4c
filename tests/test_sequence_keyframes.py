"""Keyframes of ``calibrate-sequence``: the optical flow from the last kept frame decides which frames are
kept (synthetic images shifted, turned and torn apart), the cap spreads them, the second pass yields them,
and the report counts what was read, kept and left out."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import cv2
import numpy as np
import pytest

from stereogeo_cli.sequence.keyframes import (
    KeyframeChoice,
    KeyframeSource,
    Motion,
    _Tracker,
    choose_keyframes,
    decide,
    default_conf,
    spread,
    with_frames_counted,
)
from stereogeo_cli.sequence.sources import FramePair, FrameSource

W, H = 320, 240  # under the tracked size: the flow is measured in these pixels


def _texture(seed: int = 0, size: int = 640) -> np.ndarray:
    """A grey texture of blobs, larger than a frame, to cut frames from."""
    noise = np.random.default_rng(seed).uniform(0, 255, (size // 8, size // 8)).astype(np.float32)
    return cv2.resize(noise, (size, size), interpolation=cv2.INTER_CUBIC).clip(0, 255).astype(np.uint8)


def _frame(texture: np.ndarray, dx: float = 0.0, dy: float = 0.0, angle_deg: float = 0.0) -> np.ndarray:
    """A W x H RGB frame: the texture's centre turned by ``angle_deg`` and shifted by (dx, dy) pixels."""
    c = texture.shape[0] / 2
    M = cv2.getRotationMatrix2D((c, c), angle_deg, 1.0)
    M[:, 2] += (dx - (c - W / 2), dy - (c - H / 2))
    grey = cv2.warpAffine(texture, M, (W, H), flags=cv2.INTER_LINEAR)
    return cv2.cvtColor(grey, cv2.COLOR_GRAY2RGB)


def _torn(texture: np.ndarray, d: float) -> np.ndarray:
    """A frame whose top half moved d pixels right and bottom half d pixels left: flow of median d that no
    homography explains (as the parallax of near and far things does)."""
    top, bottom = _frame(texture, dx=d), _frame(texture, dx=-d)
    return np.concatenate([top[: H // 2], bottom[H // 2 :]])


def _motion(first: np.ndarray, second: np.ndarray) -> Motion:
    tracker = _Tracker(dict(default_conf))
    tracker.keep(tracker.small(first))
    return tracker.motion(tracker.small(second))


class _Frames(FrameSource):
    """A source of left images (the right is the left), made one at a time as iteration asks."""

    description = "test frames"

    def __init__(self, make, n: int):
        super().__init__()
        self.make, self.n, self.made = make, n, 0

    def count(self) -> int:
        return self.n

    def __iter__(self):
        for k in range(self.n):
            self.made += 1
            image = self.make(k)
            yield FramePair(k, k / 10, f"f{k}", image, image)


def test_the_flow_is_measured_as_a_share_of_the_larger_side():
    texture = _texture()
    motion = _motion(_frame(texture), _frame(texture, dx=6.4))
    assert motion.flow_rel == pytest.approx(6.4 / W, rel=0.05)
    assert motion.tracked_share > 0.9


def test_a_shift_or_a_turn_of_the_image_is_rotational_and_torn_flow_is_not():
    texture = _texture(1)
    assert _motion(_frame(texture), _frame(texture, dx=3, dy=2)).rotational
    assert _motion(_frame(texture), _frame(texture, angle_deg=2.0)).rotational
    torn = _motion(_frame(texture), _torn(texture, 3))
    assert not torn.rotational and torn.flow_rel == pytest.approx(3 / W, rel=0.1)


def test_a_turn_is_kept_at_half_the_flow_that_parallax_needs():
    texture, conf = _texture(2), dict(default_conf)
    d = 0.35 * conf["parallax_rel"] * W + 0.65 * conf["rotation_rel"] * W  # between the two thresholds
    assert decide(_motion(_frame(texture), _frame(texture, dx=d)), conf) is None  # a turn: kept
    assert decide(_motion(_frame(texture), _torn(texture, d)), conf) == "little_motion"
    assert decide(_motion(_frame(texture), _torn(texture, 1.3 * conf["parallax_rel"] * W)), conf) is None


def test_a_still_frame_is_a_near_duplicate_and_a_new_view_is_kept():
    texture, conf = _texture(3), dict(default_conf)
    noisy = _frame(texture).astype(np.int16) + np.random.default_rng(0).integers(-2, 3, (H, W, 3))
    still = _motion(_frame(texture), noisy.clip(0, 255).astype(np.uint8))
    assert still.flow_rel < conf["still_rel"] and decide(still, conf) == "still"
    elsewhere = _motion(_frame(texture), _frame(_texture(4)))  # the view changed: nothing tracks
    assert decide(elsewhere, conf) is None
    blank = np.full((H, W, 3), 128, np.uint8)  # nothing to track: kept, not measured
    assert decide(_motion(blank, blank), conf) is None


def test_a_rig_that_stands_then_pans_keeps_one_still_frame_and_the_pan():
    texture = _texture(5)
    # 10 frames standing still, then 10 frames panning 4 px (1.25 % of the width) a frame
    source = _Frames(lambda k: _frame(texture, dx=4.0 * max(0, k - 9)), 20)
    choice = choose_keyframes(source)
    assert choice.read == 20 and source.made == 20
    assert choice.kept == [0, *range(10, 20)]
    assert choice.left_out == {"still": 9, "little_motion": 0, "cap": 0}
    assert choice.notes() == ["9 frames left out: the rig stood still"]


def test_a_slow_pan_keeps_a_frame_each_time_the_flow_reaches_the_threshold():
    texture = _texture(6)
    step = 0.36  # px a frame (over 0.32, still): the rotational threshold, 0.8 px, is reached every third
    choice = choose_keyframes(_Frames(lambda k: _frame(texture, dx=step * k), 13))
    assert choice.kept == [0, 3, 6, 9, 12]
    assert choice.left_out["little_motion"] == 8 and choice.left_out["still"] == 0


def test_a_rig_that_never_moves_keeps_its_first_and_last_frame():
    texture = _texture(7)
    choice = choose_keyframes(_Frames(lambda k: _frame(texture), 8))
    assert choice.kept == [0, 7] and choice.left_out["still"] == 6


def test_the_cap_keeps_frames_evenly_spread_over_the_recording():
    assert spread(list(range(10)), 20) == list(range(10))
    assert spread(list(range(0, 100, 2)), 5) == [0, 24, 48, 74, 98]
    texture = _texture(8)
    choice = choose_keyframes(_Frames(lambda k: _frame(texture, dx=4.0 * k), 30), {"max_kept": 6})
    assert len(choice.kept) == 6 and choice.kept[0] == 0 and choice.kept[-1] == 29
    assert choice.left_out["cap"] == 24
    assert "24 frames left out to keep at most 6 keyframes" in choice.notes()[0]


def test_the_second_pass_yields_the_kept_frames_numbered_again():
    texture = _texture(9)
    inner = _Frames(lambda k: _frame(texture, dx=k), 6)
    choice = KeyframeChoice([1, 4], 6, conf=dict(default_conf))
    source = KeyframeSource(inner, choice)
    frames = list(source)
    assert source.count() == 2
    assert [(f.index, f.name) for f in frames] == [(0, "f1"), (1, "f4")]
    assert inner.made == 5  # the pass stops at the last kept frame


def test_the_report_counts_the_frames_read_kept_and_registered():
    from stereogeo_cli.io import StereoCalibration

    calibration = StereoCalibration(
        np.eye(3), np.eye(3), (W, H), (W, H), np.eye(3), np.array([-0.1, 0, 0]),
        extra_report={"sequence": {"frames_read": 3, "frames_registered": 3, "points": 10}},
    )  # fmt: skip
    choice = KeyframeChoice([0, 5, 9], 12, conf=dict(default_conf))
    choice.left_out["still"] = 9
    sequence = with_frames_counted(calibration, KeyframeSource(_Frames(None, 12), choice), 3).extra_report[
        "sequence"
    ]
    assert list(sequence)[:4] == ["frames_read", "frames_kept", "frames_registered", "keyframes"]
    assert (sequence["frames_read"], sequence["frames_kept"], sequence["points"]) == (12, 3, 10)
    assert sequence["keyframes"]["rule"] == "motion" and sequence["keyframes"]["left_out"]["still"] == 9
    assert sequence["keyframes"]["parallax_rel"] == default_conf["parallax_rel"]
    plain = with_frames_counted(calibration, _Frames(None, 3), 3).extra_report["sequence"]
    assert plain["keyframes"] == {"rule": "all"} and plain["frames_read"] == plain["frames_kept"] == 3


@pytest.mark.slow
def test_a_render_with_each_frame_three_times_is_read_once_a_frame(tmp_path):
    """A turning render whose every frame comes three times (a camera that repeats frames, a rig halting):
    the repeats are left out as a rig standing still and counted; stdout is the report alone."""
    pytest.importorskip("moderngl")
    from stereogeo_cli.synth.sequence import make_sequence, sequence_config

    render = tmp_path / "render"
    make_sequence(render, "turning", 8, 7, sequence_config(short_side=240, outdoor_share=0.0), progress=False)
    folder = tmp_path / "seq"
    for side in ("left", "right"):
        (folder / side).mkdir(parents=True)
        for k, image in enumerate(sorted((render / side).iterdir())):
            for repeat in range(3):
                shutil.copy(image, folder / side / f"{3 * k + repeat:04d}{image.suffix}")
    done = subprocess.run(
        [sys.executable, "-m", "stereogeo_cli", "calibrate-sequence", folder, "--json"], capture_output=True,
        text=True, timeout=300, env={**os.environ, "COLUMNS": "120"},
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)  # the report alone on stdout
    seq = report["sequence"]
    assert (seq["frames_read"], seq["frames_kept"]) == (24, 8)
    assert seq["keyframes"]["left_out"] == {"still": 16, "little_motion": 0, "cap": 0}
    assert "16 frames left out: the rig stood still" in report["warnings"]
    assert "choosing keyframes by motion, 24 of 24 (8 of 24 kept)" in done.stderr
    assert "reading and calibrating frame pairs, 8 of 8" in done.stderr
