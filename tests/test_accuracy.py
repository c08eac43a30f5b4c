"""Accuracy as a user meets it: ``stereogeo calibrate`` and ``stereogeo_cli.calibrate`` with the shipped model
on pairs with exact ground truth: each camera's focal length, roll and pitch, the rig's R and T's direction.

The errors are computed here from the report and the ground truth alone (the README's conventions), not with
the evaluation code under test. Each case's tolerances are a few times the shipped model's error measured on
that pair, and tight enough that a rotation 0.5° off or a focal length 5 % off fails every case (checked by
hand: pipeline.py patched to turn the fused R by 0.5° about x, y or z, or to scale both final focal lengths
by 1.05 or 0.95, failed each accuracy test here and in tests/test_batch_pairs.py, the tightest margin R
0.38° against 0.3° on street-long). Calibration is deterministic on one machine; the margins are for another
machine's floats (SIFT, RANSAC and the renderer), measured here by adding ±1 grey level of noise to every
pixel, which moves the results far more than that: the "noise" figures below are the largest errors of four
such runs.
A new shipped model is measured again and the table updated.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples"


@dataclass(frozen=True)
class Tolerance:
    focal_rel: float  # |f / f_true - 1|, per camera
    roll_deg: float  # per camera
    pitch_deg: float  # per camera
    rotation_deg: float  # the angle of R · R_trueᵀ
    direction_deg: float  # the angle between T and T_true


# Per case: the measured errors (the larger of the two cameras'; "noise": the largest under ±1 grey level of
# noise), and the tolerance. Focal: below 5 % minus the pair's error (what a 5 % scaling leaves at the least,
# either way), and three to four times the error. R: below 0.5° minus the pair's error (what a 0.5° turn
# leaves at the least, whatever its axis), and 1.6 to 2.2 times the largest error under noise. Roll, pitch
# and T's direction: two and a half to three times the measured error, with a floor of 0.15° for roll and
# pitch (the example pair's are hundredths of a degree); T's direction is the least accurate on small renders.
TOLERANCES = {
    # examples/: 640 x 480, the shipped model: focal 1.07 % (noise 1.39 %), roll 0.094° (0.136°), pitch
    # 0.014° (0.039°), R 0.0087° (0.046°), T 1.36° (2.11°)
    "example": Tolerance(focal_rel=0.03, roll_deg=0.3, pitch_deg=0.15, rotation_deg=0.1, direction_deg=4.0),
    # 960011: 240 x 240 street, a 90° lens pitched 36° up: focal 0.51 % (noise 0.55 %), roll 0.32° (0.20°),
    # pitch 0.91° (0.70°), R 0.087° (0.157°), T 4.87° (5.75°)
    "street-wide": Tolerance(
        focal_rel=0.02, roll_deg=1.0, pitch_deg=2.5, rotation_deg=0.3, direction_deg=10.0
    ),
    # 960041: 360 x 240 street, a 37° lens: focal 0.54 % (noise 0.45 %), roll 0.31° (0.35°), pitch 1.15°
    # (1.36°), R 0.133° (0.189°), T 4.64° (4.61°)
    "street-long": Tolerance(
        focal_rel=0.02, roll_deg=1.0, pitch_deg=3.0, rotation_deg=0.3, direction_deg=10.0
    ),
}
# Of conftest.RENDERED_SEEDS, the pairs held to accuracy. At 240 px the shipped model's errors vary widely
# from pair to pair (on the 91 pairs measured, seeds 960001-960063: R 0.005° to 8.7°, focal 0 to 99 %), and a
# pair held to a few times its error must be one whose error is small and stays small under the noise above,
# else no tolerance could both hold and catch a 0.5° or 5 % error. Of the seeds' first pairs (one render
# each), four had focal < 1.5 % and R < 0.2°; these two kept their errors under the noise (960040 and 960059
# moved R to 0.39° and T's direction to 21° under it).
RENDERED = ("street-wide", "street-long")


def roll_pitch_deg(gravity_up) -> tuple[float, float]:
    """The README's convention: g = (-sin r cos p, -cos r cos p, sin p)."""
    g = np.asarray(gravity_up, dtype=float)
    g = g / np.linalg.norm(g)
    return math.degrees(math.atan2(-g[0], -g[1])), math.degrees(math.asin(np.clip(g[2], -1.0, 1.0)))


def rotation_angle_deg(A, B) -> float:
    cos = (np.trace(np.asarray(A, dtype=float) @ np.asarray(B, dtype=float).T) - 1.0) / 2.0
    return math.degrees(math.acos(np.clip(cos, -1.0, 1.0)))


def direction_angle_deg(a, b) -> float:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return math.degrees(math.acos(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0, 1.0)))


def errors(report: dict, truth: dict) -> dict[str, float]:
    """The report's errors against a ``calib.jsonl`` record (K and gravity_up per camera, R, T)."""
    found = {}
    for side in ("left", "right"):
        cam, true = report[side], truth[side]
        assert (cam["width"], cam["height"]) == (true["width"], true["height"]), side
        true_focal = true["K"][0][0]
        found[f"{side}_focal_rel"] = abs(cam["focal_px"] / true_focal - 1.0)
        # the focal length the files are written from is the reported one
        assert cam["K"][0][0] == cam["K"][1][1] == pytest.approx(cam["focal_px"], rel=1e-12)
        roll, pitch = roll_pitch_deg(true["gravity_up"])
        found[f"{side}_roll_deg"] = abs((cam["roll_deg"] - roll + 180.0) % 360.0 - 180.0)
        found[f"{side}_pitch_deg"] = abs(cam["pitch_deg"] - pitch)
    found["rotation_deg"] = rotation_angle_deg(report["R"], truth["R"])
    found["direction_deg"] = direction_angle_deg(report["T"], truth["T"])
    return found


def assert_accurate(report: dict, truth: dict, tolerance: Tolerance) -> None:
    """Every error within its tolerance; the message lists them all."""
    found = errors(report, truth)
    limits = {
        key: getattr(tolerance, key.removeprefix("left_").removeprefix("right_")) for key in found
    }  # e.g. left_focal_rel -> focal_rel
    over = {key: (round(found[key], 4), limits[key]) for key in found if not found[key] <= limits[key]}
    assert not over, f"errors over their tolerances (error, tolerance): {over}; all errors: {found}"


def example_truth() -> dict:
    return json.loads((EXAMPLE / "ground_truth.json").read_text())


# ------------------------------------------------------------------------------------------------- the tests
def test_the_command_calibrates_the_example_pair(calibrate_cli):
    report, _ = calibrate_cli(EXAMPLE / "left.png", EXAMPLE / "right.png")
    assert_accurate(report, example_truth(), TOLERANCES["example"])


def test_the_python_api_calibrates_the_example_pair(calibrate_api):
    report = calibrate_api(EXAMPLE / "left.png", EXAMPLE / "right.png")
    assert_accurate(report, example_truth(), TOLERANCES["example"])


@pytest.mark.parametrize("name", RENDERED)
def test_the_command_calibrates_rendered_pairs(rendered_pairs, calibrate_cli, name):
    pair = rendered_pairs[name]
    report, _ = calibrate_cli(pair.left, pair.right)
    assert_accurate(report, pair.truth, TOLERANCES[name])


@pytest.mark.parametrize("name", RENDERED)
def test_the_python_api_calibrates_rendered_pairs(rendered_pairs, calibrate_api, name):
    pair = rendered_pairs[name]
    assert_accurate(calibrate_api(pair.left, pair.right), pair.truth, TOLERANCES[name])


def test_the_errors_are_measured_as_the_readme_defines_them():
    """The helpers above against hand-made cases: a level camera, 10° of roll, 5° of pitch; a rotation of
    0.5° about y; T turned by 3°."""
    assert roll_pitch_deg([0.0, -1.0, 0.0]) == pytest.approx((0.0, 0.0), abs=1e-12)
    r, p = math.radians(10.0), math.radians(5.0)
    g = [-math.sin(r) * math.cos(p), -math.cos(r) * math.cos(p), math.sin(p)]
    assert roll_pitch_deg(g) == pytest.approx((10.0, 5.0), abs=1e-9)
    a = math.radians(0.5)
    Ry = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    assert rotation_angle_deg(Ry, np.eye(3)) == pytest.approx(0.5, abs=1e-9)
    b = math.radians(3.0)
    assert direction_angle_deg([-1, 0, 0], [-math.cos(b), 0, math.sin(b)]) == pytest.approx(3.0, abs=1e-9)
