"""``stereogeo batch-calibrate``: pair discovery, sharding, bad pairs, summaries, workers, --same-rig, and
stopping on SIGINT / SIGTERM with --resume."""

from __future__ import annotations

import csv
import hashlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from test_cli_calibrate import assert_error, invoke

from stereogeo_cli.batch.resume import EVIDENCE, MARKER, evidence_bytes, existing_results, read_evidence
from stereogeo_cli.batch.same_rig import pool_matches
from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.fuse import Matches, fuse_relative_pose
from stereogeo_cli.fuse.assemble import CameraEstimate
from stereogeo_cli.geometry import intrinsic_matrix, rotation_angle, rotation_error, rotation_from_axis_angle
from stereogeo_cli.io.pairs import discover_pairs, parse_shard, select_shard
from stereogeo_cli.jobs.interrupt import Interrupted, Stop, interruptible, protected
from stereogeo_cli.rig.combine import chordal_mean, combine_focals
from stereogeo_cli.rig.evidence import PairEvidence


def _cameras(size: tuple[int, int], focals: tuple[float, float], k: float = 0.0) -> tuple:
    """A pair's two cameras as its evidence holds them (no gravity, a focal sigma of 1 px, division k)."""
    return tuple(CameraEstimate(f, *size, None, {"focal_px": 1.0}, division_k=k) for f in focals)


def touch(folder: Path, *names: str) -> None:
    for name in names:
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"")  # discovery never reads the files


def described(entries) -> list[tuple]:
    return [(e.name, e.left and e.left.name, e.right and e.right.name, e.problem is None) for e in entries]


# ------------------------------------------------------------------------------------------------ discovery
def test_left_right_folders_match_by_stem_in_natural_order(tmp_path):
    touch(tmp_path, "left/img10.png", "right/img10.PNG", "left/img2.jpg", "right/img2.png", "left/img1.tif")
    touch(tmp_path, "right/img1.TIFF", "right/lonely.png", "left/notes.txt", "calib.jsonl")
    entries = discover_pairs(tmp_path)
    assert described(entries) == [
        ("img1", "img1.tif", "img1.TIFF", True),
        ("img2", "img2.jpg", "img2.png", True),
        ("img10", "img10.png", "img10.PNG", True),
        ("lonely", None, "lonely.png", False),
    ]
    assert "left/" in entries[-1].problem


def test_two_images_of_one_name_are_ambiguous(tmp_path):
    touch(tmp_path, "left/a.png", "left/a.jpg", "right/a.png", "left/b.png", "right/b.png")
    entries = discover_pairs(tmp_path)
    assert described(entries)[1] == ("b", "b.png", "b.png", True)
    assert entries[0].name == "a" and "a.jpg" in entries[0].problem and "a.png" in entries[0].problem


def test_cam0_cam1_and_euroc_data_folders(tmp_path):
    touch(tmp_path / "plain", "cam0/1.png", "cam1/1.png")
    touch(tmp_path / "euroc", "cam0/data/1403.png", "cam1/data/1403.png", "cam0/sensor.yaml")
    assert described(discover_pairs(tmp_path / "plain")) == [("1", "1.png", "1.png", True)]
    assert described(discover_pairs(tmp_path / "euroc")) == [("1403", "1403.png", "1403.png", True)]


def test_suffix_names_in_one_folder(tmp_path):
    touch(tmp_path, "a_left.png", "a_right.png", "b_L.JPG", "b_R.jpeg", "c_Left.bmp", "c_r.bmp")
    touch(tmp_path, "d_left.png", "overview.png", "readme.md")
    entries = discover_pairs(tmp_path)
    assert described(entries) == [
        ("a", "a_left.png", "a_right.png", True),
        ("b", "b_L.JPG", "b_R.jpeg", True),
        ("c", "c_Left.bmp", "c_r.bmp", True),
        ("d", "d_left.png", None, False),
        ("overview", None, None, False),
    ]
    assert "_left, _right, _L or _R" in entries[-1].problem


def test_folders_without_pairs_are_errors(tmp_path):
    for make, match in (
        (lambda p: None, "no stereo pairs"),
        (lambda p: touch(p, "x_left.png"), "no stereo pairs .*1 unmatched"),
        (lambda p: touch(p, "left/a.png"), "no right/ folder"),
    ):
        folder = tmp_path / f"case{len(list(tmp_path.iterdir()))}"
        folder.mkdir()
        make(folder)
        with pytest.raises(StereoGeoError, match=match) as err:
            discover_pairs(folder)
        assert err.value.exit_code == 2
    with pytest.raises(StereoGeoError, match="not found"):
        discover_pairs(tmp_path / "missing")


@pytest.mark.parametrize("text, expected", [("1/1", (1, 1)), ("1/4", (1, 4)), (" 4 / 4 ", (4, 4))])
def test_shard_numbers_are_one_based(text, expected):
    assert parse_shard(text) == expected


@pytest.mark.parametrize("text", ["0/4", "5/4", "1/0", "a/b", "1-4", "", "-1/4", "1/4/2"])
def test_bad_shards_are_usage_errors(text):
    with pytest.raises(StereoGeoError) as err:
        parse_shard(text)
    assert err.value.exit_code == 2 and "\n" not in str(err.value)


def test_shards_cover_every_entry_once():
    entries = list(range(11))
    shards = [select_shard(entries, (i, 3)) for i in (1, 2, 3)]
    assert shards[0] == [0, 3, 6, 9] and sorted(sum(shards, [])) == entries
    assert select_shard(entries, None) == entries


# ------------------------------------------------------------------------------------------ the command
@pytest.fixture(scope="module")
def small_images(example_pair) -> tuple[np.ndarray, np.ndarray]:
    """The example pair at 320x240, BGR (quick to calibrate)."""
    return tuple(
        cv2.resize(cv2.imread(str(p)), (320, 240), interpolation=cv2.INTER_AREA) for p in example_pair
    )


def pair_folder(folder: Path, images, names=("a", "b")) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for name in names:
        cv2.imwrite(str(folder / f"{name}_left.png"), images[0])
        cv2.imwrite(str(folder / f"{name}_right.png"), images[1])
    return folder


def read_csv(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_bad_pairs_are_reported_and_the_rest_written(small_images, onnx_model, tmp_path):
    folder = pair_folder(tmp_path / "in", small_images)
    cv2.imwrite(str(folder / "c_left.png"), small_images[0])  # no right
    (folder / "d_left.png").write_text("not an image")
    cv2.imwrite(str(folder / "d_right.png"), small_images[1])
    cv2.imwrite(str(folder / "e_left.png"), small_images[0])
    cv2.imwrite(str(folder / "e_right.png"), np.full_like(small_images[1], 77))  # blank
    out = tmp_path / "out"
    result = invoke("batch-calibrate", folder, "-o", out, "--model", onnx_model, "--format", "json,ros")
    assert result.exit_code == 4, result.output
    assert "Traceback" not in result.output
    failures = [line for line in result.stderr.splitlines() if "failed" in line or "unmatched" in line]
    assert len(failures) == 3
    assert any("c_left.png has no right image" in f for f in failures)
    assert any("d_left.png" in f for f in failures) and any("blank" in f for f in failures)
    for name in ("a", "b"):
        assert sorted(p.name for p in (out / name).iterdir()) == [
            MARKER,
            "left.yaml",
            "report.json",
            "right.yaml",
        ]
    assert not (out / "c").exists() and not (out / "d").exists()
    rows = read_csv(out / "summary.csv")
    assert [(r["name"], r["status"]) for r in rows] == [
        ("a", "ok"), ("b", "ok"), ("c", "failed"), ("d", "failed"), ("e", "failed"),
    ]  # fmt: skip
    assert float(rows[0]["left_focal_px"]) > 0 and rows[0]["error"] == "" and "blank" in rows[4]["error"]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["counts"] == {"pairs": 5, "ok": 2, "failed": 3, "not_run": 0}
    assert summary["interrupted"] is None and summary["resumed"] == 0
    assert summary["medians"]["left_focal_px"] == pytest.approx(float(rows[0]["left_focal_px"]))
    assert summary["pairs"][0]["report"]["left"]["K"] and summary["pairs"][2]["report"] is None


def test_all_pairs_ok_json_on_stdout(small_images, onnx_model, tmp_path):
    folder = tmp_path / "in"
    for side, image in zip(("left", "right"), small_images, strict=True):
        (folder / side).mkdir(parents=True)
        for name in ("x1", "x2"):
            cv2.imwrite(str(folder / side / f"{name}.png"), image)
    out = tmp_path / "out"
    result = invoke("batch-calibrate", folder, "-o", out, "--model", onnx_model, "--json")
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout)
    assert summary["counts"] == {"pairs": 2, "ok": 2, "failed": 0, "not_run": 0}
    assert summary == json.loads((out / "summary.json").read_text())
    assert (out / "x1" / "intrinsics.yml").is_file() and (out / "x2" / "report.json").is_file()


def test_no_lines_reaches_every_worker(small_images, onnx_model, tmp_path):
    folder = pair_folder(tmp_path / "in", small_images)
    for workers in ("1", "2"):
        out = tmp_path / f"out{workers}"
        args = ("batch-calibrate", folder, "-o", out, "--model", onnx_model, "--json", "--workers", workers)
        result = invoke(*args, "--no-lines")
        assert result.exit_code == 0, result.output
        summary = json.loads(result.stdout)
        assert [p["report"]["vertical_segments"] for p in summary["pairs"]] == [[0, 0], [0, 0]]


def test_empty_folder(onnx_model, tmp_path):
    (tmp_path / "empty").mkdir()
    assert_error(invoke("batch-calibrate", tmp_path / "empty", "-o", tmp_path / "out", "--model", onnx_model),
                 2, "no stereo pairs")  # fmt: skip


def test_a_folder_without_pairs_is_told_the_layouts_in_the_message_itself(onnx_model, tmp_path):
    # the installed package has no docs/ folder: the one line says what a folder of pairs looks like
    (tmp_path / "empty").mkdir()
    touch(tmp_path / "sides", "left/a.png", "right/b.png")
    for folder, layouts in (
        ("empty", ("left/ + right/", "cam0/ + cam1/", "<name>_left + <name>_right", "<name>_L + <name>_R")),
        ("sides", ("left/", "right/", "same name")),
    ):
        args = ("batch-calibrate", tmp_path / folder, "-o", tmp_path / "out", "--model", onnx_model)
        line = assert_error(invoke(*args), 2, "no stereo pairs", *layouts)
        assert "docs" not in line and ".md" not in line, line


def test_usage_errors(small_images, onnx_model, tmp_path):
    folder = pair_folder(tmp_path, small_images, ("a",))
    blocker = tmp_path / "file"
    blocker.write_text("x")
    base = ("batch-calibrate", folder, "--model", onnx_model)
    assert_error(invoke(*base, "-o", blocker), 2, "not a folder")
    assert_error(invoke(*base, "-o", blocker / "sub"), 2, "file")
    assert_error(invoke(*base, "-o", tmp_path / "o", "--shard", "0/2"), 2, "numbered from 1")
    assert_error(invoke(*base, "-o", tmp_path / "o", "--format", "pdf"), 2, "pdf")
    assert_error(invoke(*base, "-o", tmp_path / "o", "--baseline", "-2"), 2, "--baseline")
    assert_error(invoke(*base, "-o", tmp_path / "o", "--workers", "0"), 2, "--workers")
    corrupt = tmp_path / "bad.onnx"
    corrupt.write_bytes(b"\x08\x01garbage")
    for workers in ("1", "2"):
        assert_error(
            invoke(*base[:2], "-o", tmp_path / "o", "--model", corrupt, "--workers", workers), 2, "bad.onnx"
        )
    assert not (tmp_path / "o" / "a").exists()


def test_one_pair_is_counted_as_one_pair(small_images, onnx_model, tmp_path):
    folder = pair_folder(tmp_path / "in", small_images, ("a",))
    base = ("batch-calibrate", folder, "-o", tmp_path / "out", "--model", onnx_model, "--format", "json")
    result = invoke(*base)
    assert result.exit_code == 0, result.output
    assert result.stdout.startswith("1 pair: 1 ok, 0 failed; results in "), result.stdout
    result = invoke(*base, "--resume")
    assert result.exit_code == 0, result.output
    assert "resuming: 1 of 1 pair taken from " in result.stderr, result.stderr
    assert result.stdout.startswith("1 pair: 1 ok, 0 failed (1 kept from before); "), result.stdout
    assert "1 pairs" not in result.output


def test_counts_in_messages():
    from stereogeo_cli.io.text import plural

    assert [plural(n, "pair") for n in (0, 1, 2)] == ["0 pairs", "1 pair", "2 pairs"]
    assert [plural(n, "process", "processes") for n in (1, 3)] == ["1 process", "3 processes"]


def test_shard_writes_its_own_summary(small_images, onnx_model, tmp_path):
    folder = pair_folder(tmp_path / "in", small_images, ("p1", "p2", "p3"))
    out = tmp_path / "out"
    result = invoke("batch-calibrate", folder, "-o", out, "--model", onnx_model, "--shard", "2/2")
    assert result.exit_code == 0, result.output
    assert [r["name"] for r in read_csv(out / "summary-shard-2-of-2.csv")] == ["p2"]
    assert sorted(p.name for p in out.iterdir()) == [
        "p2",
        "summary-shard-2-of-2.csv",
        "summary-shard-2-of-2.json",
    ]


def test_two_workers_keep_the_sorted_order(small_images, onnx_model, tmp_path):
    folder = pair_folder(tmp_path / "in", small_images, ("n3", "n1", "n2"))
    args = ("-o", tmp_path / "out", "--model", onnx_model, "--workers", "2", "--threads", "2")
    result = invoke("batch-calibrate", folder, *args)
    assert result.exit_code == 0, result.output
    rows = read_csv(tmp_path / "out" / "summary.csv")
    assert [(r["name"], r["status"]) for r in rows] == [("n1", "ok"), ("n2", "ok"), ("n3", "ok")]


def test_same_rig_writes_one_joint_calibration(small_images, onnx_model, tmp_path):
    folder = pair_folder(tmp_path / "in", small_images, ("a", "b"))
    cv2.imwrite(str(folder / "c_left.png"), small_images[0])  # unmatched: reported, not part of the rig
    out = tmp_path / "out"
    result = invoke(
        "batch-calibrate", folder, "-o", out, "--model", onnx_model, "--same-rig", "--baseline", "0.12"
    )
    assert result.exit_code == 4, result.output
    assert sorted(p.name for p in (out / "rig").iterdir()) == [
        "camchain.yaml", "cameras.txt", "extrinsics.yml", "intrinsics.yml", "left.yaml", "report.html",
        "report.json", "right.yaml",
    ]  # fmt: skip
    rig = json.loads((out / "rig" / "report.json").read_text())
    assert rig["baseline_m"] == pytest.approx(0.12) and rig["scale_source"] == "baseline"
    assert [p["name"] for p in rig["pairs"]] == ["a", "b"]
    for p in rig["pairs"]:
        assert len(p["gravity_left"]) == 3 and len(p["gravity_right"]) == 3
        assert {"left_roll_deg", "left_pitch_deg", "right_roll_deg", "right_pitch_deg"} <= set(p)
    assert rig["left"]["sigma"]["focal_px"] > 0
    assert json.loads((out / "summary.json").read_text())["rig"]["folder"] == "rig"


def test_same_rig_of_a_rig_mounted_upside_down_with_rotate_180(small_images, onnx_model, tmp_path):
    """The rig turned 180° (each camera sees the other's view turned, the files keep their cameras' names),
    calibrated with --rotate 180: the joint calibration is the upright rig's, turned into each camera's frame
    (the pooled fit works on the matches turned back)."""
    upright = pair_folder(tmp_path / "up", small_images, ("a", "b"))
    turned = pair_folder(tmp_path / "turned", [image[::-1, ::-1] for image in small_images[::-1]], ("a", "b"))
    rigs = []
    for folder, extra in ((upright, ()), (turned, ("--rotate", "180"))):
        out = tmp_path / f"out_{folder.name}"
        result = invoke("batch-calibrate", folder, "-o", out, "--model", onnx_model, "--same-rig", *extra)
        assert result.exit_code == 0, result.output
        rigs.append(json.loads((out / "rig" / "report.json").read_text()))
    up, rig = rigs
    assert rig["rotate_deg"] == 180 and "rotate_deg" not in up
    assert rig["left"]["focal_px"] == pytest.approx(up["right"]["focal_px"], rel=0.01)
    assert rig["right"]["focal_px"] == pytest.approx(up["left"]["focal_px"], rel=0.01)
    flip = np.diag([-1.0, -1.0, 1.0])
    R_up = np.array(up["R"])
    assert np.degrees(rotation_angle(np.array(rig["R"]).T @ flip @ R_up.T @ flip)) < 0.1
    for p_up, p in zip(up["pairs"], rig["pairs"], strict=True):
        g = flip @ np.array(p_up["gravity_right"])
        assert np.degrees(np.arccos(np.clip(g @ p["gravity_left"], -1, 1))) < 0.5


def test_same_rig_needs_one_image_size(small_images, onnx_model, tmp_path):
    folder = pair_folder(tmp_path / "in", small_images, ("a",))
    cv2.imwrite(str(folder / "b_left.png"), cv2.resize(small_images[0], (400, 300)))
    cv2.imwrite(str(folder / "b_right.png"), cv2.resize(small_images[1], (400, 300)))
    result = invoke("batch-calibrate", folder, "-o", tmp_path / "out", "--model", onnx_model, "--same-rig")
    assert_error_line = [line for line in result.stderr.splitlines() if line.startswith("error:")]
    assert result.exit_code == 2 and len(assert_error_line) == 1 and "differ in size" in assert_error_line[0]
    assert (tmp_path / "out" / "a" / "report.json").is_file() and (tmp_path / "out" / "summary.csv").is_file()


# ------------------------------------------------------------------------------------------ same-rig maths
def test_focal_combination_beats_single_pairs_and_drops_outliers():
    rng = np.random.default_rng(3)
    true_f, errors_single, errors_joint = 600.0, [], []
    for _ in range(200):
        sigma_log = rng.uniform(0.03, 0.15, 8)
        focals = true_f * np.exp(rng.normal(0.0, sigma_log))
        focals[0] = 3 * true_f  # a confidently wrong pair
        sigma_log[0] = 0.03
        estimate = combine_focals(focals, focals * sigma_log)
        assert not estimate.used[0]
        errors_single.append(np.median(np.abs(np.log(focals[1:] / true_f))))
        errors_joint.append(abs(np.log(estimate.focal_px / true_f)))
    assert np.median(errors_joint) < 0.5 * np.median(errors_single)
    one = combine_focals([500.0], [25.0])
    assert one.focal_px == pytest.approx(500.0) and one.sigma_px == pytest.approx(25.0) and one.used.all()


def test_focal_combination_keeps_the_error_common_to_a_rig():
    """Pairs of one camera that all read it 30 % short (a bias of the network on that camera) with
    10 % sigmas: more pairs must not make the combined focal length look more certain than one pair."""
    rng = np.random.default_rng(5)
    true_f = 700.0
    for n in (2, 10, 50):
        focals = true_f * 0.7 * np.exp(rng.normal(0.0, 0.02, n))
        estimate = combine_focals(focals, 0.1 * focals)
        assert estimate.sigma_px / estimate.focal_px == pytest.approx(0.1, rel=0.05)
        # the truth stays within 4 reported sigmas, however many pairs
        assert abs(np.log(estimate.focal_px / true_f)) < 4 * estimate.sigma_px / estimate.focal_px


def synthetic_rig_matches(rng, K_left, K_right, R, T, n=60, noise_px=0.7, outliers=0.15) -> Matches:
    X = np.column_stack([rng.uniform(-4, 4, n), rng.uniform(-3, 3, n), rng.uniform(3, 25, n)])
    left = (X / X[:, 2:]) @ K_left.T
    Xr = X @ R.T + T
    right = (Xr / Xr[:, 2:]) @ K_right.T
    left, right = (
        left[:, :2] + rng.normal(0, noise_px, (n, 2)),
        right[:, :2] + rng.normal(0, noise_px, (n, 2)),
    )
    bad = rng.random(n) < outliers
    right[bad] = rng.uniform(0, 640, (bad.sum(), 2))
    return Matches(left, right)


def test_pooled_matches_give_a_better_pose_than_single_pairs():
    """Several pairs of one rig (exact K, R, T; few noisy matches each): one pooled estimate is better."""
    rng = np.random.default_rng(7)
    K_left, K_right = intrinsic_matrix(500.0, 640, 480), intrinsic_matrix(520.0, 640, 480)
    R, T = rotation_from_axis_angle(np.radians([0.5, 2.0, 0.3])), np.array([-0.12, 0.003, 0.002])
    evidence, single, single_t = [], [], []

    def direction_error(t):
        return np.degrees(np.arccos(np.clip(t @ T / np.linalg.norm(T), -1.0, 1.0)))

    for _ in range(8):
        m = synthetic_rig_matches(rng, K_left, K_right, R, T)
        pose = fuse_relative_pose(m, K_left, K_right)
        single.append(np.degrees(rotation_error(pose.R, R)))
        single_t.append(direction_error(pose.t_direction))
        evidence.append(PairEvidence(_cameras((640, 480), (500.0, 520.0)), pose.R, pose.t_direction,
                                     pose.source, 0.12, m.left, m.right))  # fmt: skip
    pooled, counts = pool_matches(evidence, K_left, K_right)
    assert len(pooled) == sum(counts) and min(counts) > 30
    t_mean = np.sum([e.t_direction for e in evidence], axis=0)
    joint = fuse_relative_pose(pooled, K_left, K_right, prior_R=chordal_mean([e.R for e in evidence]),
                               prior_t=t_mean)  # fmt: skip
    joint_error = np.degrees(rotation_error(joint.R, R))
    assert joint_error < 0.5 * np.median(single), (joint_error, single)
    assert direction_error(joint.t_direction) < np.median(single_t), (joint.t_direction, single_t)


def test_pooling_judges_each_pair_after_undoing_its_lens():
    """A barrel lens (division k = -0.2) on both cameras: with each pair's fitted k every match pools as an
    inlier; without it some at the edges are dropped. Pooled matches stay as observed."""
    from stereogeo_cli.geometry import undistort_division

    rng = np.random.default_rng(8)
    K = intrinsic_matrix(500.0, 640, 480)
    R, T = rotation_from_axis_angle(np.radians([0.5, 2.0, 0.3])), np.array([-0.3, 0.003, 0.002])

    def distort(points, k):  # the division model's inverse: r_u = r_d / (1 + k r_d²), solved for r_d
        x = (points - K[:2, 2]) / 500.0
        r_u = np.linalg.norm(x, axis=1, keepdims=True)
        r_d = (1.0 - np.sqrt(1.0 - 4.0 * k * r_u**2)) / (2.0 * k * r_u)
        return K[:2, 2] + 500.0 * x * r_d / r_u

    X = np.column_stack([rng.uniform(-0.6, 0.6, 300), rng.uniform(-0.45, 0.45, 300), np.ones(300)])
    X *= rng.uniform(1.5, 4.0, 300)[:, None]  # near: disparities that show the lens
    xl, xr = X @ K.T, (X @ R.T + T) @ K.T
    m = Matches(xl[:, :2] / xl[:, 2:], xr[:, :2] / xr[:, 2:])
    seen = Matches(distort(m.left, -0.2), distort(m.right, -0.2))
    np.testing.assert_allclose(undistort_division(seen.left, K, -0.2), m.left, atol=1e-9)

    def evidence(k):
        return PairEvidence(_cameras((640, 480), (500.0, 500.0), k), R, T / 0.3, "matches", 0.3, seen.left,
                            seen.right)  # fmt: skip

    pooled, (kept,) = pool_matches([evidence(-0.2)], K, K)
    assert kept == len(seen)
    np.testing.assert_array_equal(pooled.left, seen.left)  # as observed: the joint fit finds the lens again
    _, (kept_pinhole,) = pool_matches([evidence(0.0)], K, K)
    assert kept_pinhole < len(seen)  # the edges' matches bend past the 2 px a pinhole allows


PINHOLE = {"distortion": False}


def test_pooling_real_pairs_of_one_rig(shared_data):
    """EuRoC: 10 pairs of one rig, with the ground-truth intrinsics (undistorted matches)."""
    from stereogeo_cli.fuse import match_features
    from stereogeo_cli.io import load_image

    folder = shared_data / "real-dev" / "euroc"
    evidence, single = [], []
    for line in (folder / "calib.jsonl").read_text().splitlines():
        calib = json.loads(line)
        images = [load_image(folder / side / f"{calib['id']}.png") for side in ("left", "right")]
        K = [np.array(calib[side]["K"]) for side in ("left", "right")]
        m = match_features(*images)
        undistorted = [
            cv2.undistortPoints(pts.reshape(-1, 1, 2), k, np.array(calib[side]["dist"]), P=k).reshape(-1, 2)
            for pts, k, side in ((m.left, K[0], "left"), (m.right, K[1], "right"))
        ]
        m = Matches(*undistorted)
        pose = fuse_relative_pose(m, *K, conf=PINHOLE)  # undistorted with the true lens already
        R_true = np.array(calib["R"])
        single.append(np.degrees(rotation_error(pose.R, R_true)))
        evidence.append(PairEvidence(_cameras((752, 480), (0.0, 0.0)), pose.R, pose.t_direction, pose.source,
                                     0.11, m.left, m.right))  # fmt: skip
    pooled, _ = pool_matches(evidence, *K)
    t_mean = np.sum([e.t_direction for e in evidence], axis=0)
    joint = fuse_relative_pose(
        pooled, *K, prior_R=chordal_mean([e.R for e in evidence]), prior_t=t_mean, conf=PINHOLE
    )
    joint_error = np.degrees(rotation_error(joint.R, R_true))
    assert joint_error < np.median(single), (joint_error, sorted(single))


def test_same_rig_on_raw_euroc_finds_the_lens_and_the_focal(shared_data, tmp_path):
    """Ten raw EuRoC pairs of one rig (k1 = -0.28): the joint calibration fits the lens and the focal
    lengths (their ratio refined with the pose, as for one pair) and beats the pairs' own rotations."""
    from stereogeo_cli.batch import BatchOptions, run_batch

    folder = shared_data / "real-dev" / "euroc"
    truth = [json.loads(line) for line in (folder / "calib.jsonl").read_text().splitlines()]
    summary = run_batch(folder, tmp_path, BatchOptions(same_rig=True, workers=1))
    assert summary.rig is not None and summary.failed == 0
    rig = summary.rig.to_report()
    R_true = np.array(truth[0]["R"])  # one rig: the same R for every pair
    for side in ("left", "right"):
        assert rig[side]["dist"][0] == pytest.approx(truth[0][side]["dist"][0], abs=0.05)
        assert rig[side]["focal_px"] == pytest.approx(truth[0][side]["K"][0][0], rel=0.03)
    single = [np.degrees(rotation_error(np.array(o.report["R"]), R_true)) for o in summary.outcomes]
    assert np.degrees(rotation_error(np.array(rig["R"]), R_true)) < np.median(single), single


def test_same_rig_reports_the_focal_sigma_widened_as_single_pairs_do(
    small_images, onnx_model, tmp_path, monkeypatch
):
    import onnx

    from stereogeo_cli.pipeline import default_conf

    # the fusion's move of the focal lengths widens the sigma too (read_spread): not here
    monkeypatch.setitem(default_conf, "read_spread", 0.0)

    model = onnx.load(str(onnx_model))
    entries = {p.key: p for p in model.metadata_props}
    if "photo_sigma_scale" not in entries:
        entries["photo_sigma_scale"] = model.metadata_props.add(key="photo_sigma_scale")
    entries["photo_sigma_scale"].value = "1,1,3"
    wide = tmp_path / "wide.onnx"
    onnx.save(model, str(wide))
    folder = pair_folder(tmp_path / "in", small_images, ("a", "b"))
    sigmas = {}
    for name, path in (("plain", onnx_model), ("wide", wide)):
        out = tmp_path / name
        args = ("batch-calibrate", folder, "-o", out, "--model", path, "--same-rig", "--baseline", "0.12")
        result = invoke(*args)
        assert result.exit_code == 0, result.output
        left = json.loads((out / "rig" / "report.json").read_text())["left"]
        sigmas[name] = left["sigma"]["focal_px"] / left["focal_px"]
    from stereogeo_cli.pipeline import Calibrator

    calibrator = Calibrator(onnx_model)
    base = calibrator.photo_sigma_scale[2]  # the shipped model's own, 1 for an untrained one
    # the photo scale widens the combination's own sigma; the camera bias is added to it in quadrature
    bias = calibrator.conf["camera_bias_sigma"]
    own = {name: (s**2 - bias**2) ** 0.5 for name, s in sigmas.items()}
    assert own["wide"] == pytest.approx(own["plain"] * 3.0 / base, rel=1e-6)


# --------------------------------------------------------------------------- stopping (SIGINT, SIGTERM)
def wait_until(condition, timeout: float = 5.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def test_first_signal_asks_to_stop_a_second_stops_at_once_and_handlers_come_back():
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    with interruptible() as stop:
        assert not stop.requested and stop.exit_code is None and stop.name is None
        os.kill(os.getpid(), signal.SIGTERM)  # a cluster's time limit: recorded, nothing raised
        wait_until(lambda: stop.requested)
        assert (stop.name, stop.exit_code) == ("SIGTERM", 143)
        with pytest.raises(Interrupted):  # a second signal: at once
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(5)
        finished = []
        with pytest.raises(Interrupted):  # ...but not inside protected(): at its end
            with protected():
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.05)
                finished.append(True)
        assert finished and stop.count == 3 and stop.exit_code == 143  # the first signal's code
        with interruptible() as inner:
            assert inner is stop
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before
    asked = Stop()
    asked.request()
    assert asked.requested and asked.exit_code == 130 and asked.name == "SIGINT"


def test_same_rig_evidence_is_kept_exactly():
    rng = np.random.default_rng(1)
    cameras = (
        CameraEstimate(500.123456789, 640, 480, rng.normal(size=3), {"focal_px": 12.25, "gravity_deg": 0.5},
                       division_k=-0.1, focal_prior=(600.0, 30.5)),
        CameraEstimate(510.5, 320, 240, rng.normal(size=3), {"focal_px": float("inf"), "gravity_deg": 1.5}),
    )  # fmt: skip
    ev = PairEvidence(
        cameras, rotation_from_axis_angle(rng.normal(size=3)), rng.normal(size=3), "matches", 0.1234567,
        rng.normal(size=(7, 2)) * 100, rng.normal(size=(7, 2)) * 100, sigma_baseline_rel=0.02, lens=True,
    )  # fmt: skip
    back = read_evidence(evidence_bytes(ev))

    def same(value, kept, name):
        if isinstance(value, np.ndarray):
            assert kept.dtype == np.float64 and np.array_equal(kept, value), name
        else:
            assert kept == value and type(kept) is type(value), name

    for name, value in vars(ev).items():
        if name != "cameras":
            same(value, getattr(back, name), name)
    for camera, kept in zip(ev.cameras, back.cameras, strict=True):
        for name, value in vars(camera).items():
            same(value, getattr(kept, name), name)
    assert back.cameras[1].focal_prior is None


def test_existing_results_are_the_pairs_own(tmp_path):
    touch(tmp_path, "a/report.json", "summary-shard-2-of-2.csv", "rig/report.json")
    (tmp_path / "b").mkdir()  # an empty folder holds nothing
    assert existing_results(tmp_path, ["b", "c"], "summary-shard-1-of-2", None) == []
    found = existing_results(tmp_path, ["a", "b"], "summary-shard-2-of-2", "rig")
    assert [p.name for p in found] == ["a", "rig", "summary-shard-2-of-2.csv"]


def test_output_folder_with_results_needs_resume_or_overwrite(small_images, onnx_model, tmp_path):
    folder = pair_folder(tmp_path / "in", small_images, ("a", "b"))
    out = tmp_path / "out"
    touch(out, "a/report.json")
    base = ("batch-calibrate", folder, "-o", out, "--model", onnx_model)
    assert_error(invoke(*base), 2, str(out), "--resume", "--overwrite")
    assert_error(invoke(*base, "--resume", "--overwrite"), 2, "--resume", "--overwrite")
    assert (out / "a" / "report.json").read_bytes() == b"" and not (out / "summary.csv").exists()


def test_an_empty_shard_writes_an_empty_summary(small_images, onnx_model, tmp_path):
    folder = pair_folder(tmp_path / "in", small_images, ("a", "b"))
    result = invoke(
        "batch-calibrate", folder, "-o", tmp_path / "out", "--model", onnx_model, "--shard", "3/3"
    )
    assert result.exit_code == 0, result.output
    assert read_csv(tmp_path / "out" / "summary-shard-3-of-3.csv") == []


def test_a_stop_before_the_first_pair_lists_every_pair_as_not_run(small_images, onnx_model, tmp_path):
    from stereogeo_cli.batch import BatchOptions, run_batch

    folder = pair_folder(tmp_path / "in", small_images, ("a", "b"))
    (folder / "c_left.png").write_bytes(b"")  # unmatched: failed, as always
    stop = Stop()
    stop.request(signal.SIGTERM)
    summary = run_batch(folder, tmp_path / "out", BatchOptions(model=onnx_model, same_rig=True), stop)
    assert summary.interrupted == "SIGTERM" and (summary.not_run, summary.failed) == (2, 1)
    saved = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert saved["counts"] == {"pairs": 3, "ok": 0, "failed": 1, "not_run": 2}
    assert saved["interrupted"] == "SIGTERM" and saved["rig"]["error"] == "not run: interrupted by SIGTERM"
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["summary.csv", "summary.json"]


@pytest.mark.slow
def test_resume_calibrates_again_what_does_not_match(small_images, onnx_model, tmp_path):
    folder = pair_folder(tmp_path / "in", small_images, ("a", "b", "c"))
    out = tmp_path / "out"
    base = ("batch-calibrate", folder, "-o", out, "--model", onnx_model)
    assert invoke(*base, "--format", "json,ros").exit_code == 0
    kept = {p.name: p.stat().st_mtime_ns for p in (out / "c").iterdir()}
    (out / "a" / "left.yaml").unlink()  # a file missing
    cv2.imwrite(str(folder / "b_right.png"), cv2.GaussianBlur(small_images[1], (3, 3), 0))  # another image
    result = invoke(*base, "--format", "json,ros", "--resume")
    assert result.exit_code == 0, result.output
    assert "resuming: 1 of 3 pairs" in result.stderr and "(1 kept from before)" in result.stdout
    assert json.loads((out / "summary.json").read_text())["resumed"] == 1
    assert {p.name: p.stat().st_mtime_ns for p in (out / "c").iterdir()} == kept
    assert (out / "a" / "left.yaml").is_file()
    # other options: every pair again; the formats no longer asked for are removed
    result = invoke(*base, "--format", "json", "--resume", "--no-lines")
    assert result.exit_code == 0 and "resuming: 0 of 3 pairs" in result.stderr, result.output
    for name in "abc":
        assert sorted(p.name for p in (out / name).iterdir()) == [MARKER, "report.json"]
        assert json.loads((out / name / MARKER).read_text())["options"]["lines"] is False
    result = invoke(*base, "--format", "json", "--resume", "--no-lines", "--rotate", "180")
    assert result.exit_code == 0 and "resuming: 0 of 3 pairs" in result.stderr, result.output
    assert json.loads((out / "a" / MARKER).read_text())["options"]["rotate_deg"] == 180
    assert json.loads((out / "a" / "report.json").read_text())["rotate_deg"] == 180


def leftover(folder: Path, target: str) -> Path:
    """A temporary file of write_files_atomically for ``target``, as a killed write leaves it."""
    fd, name = tempfile.mkstemp(dir=folder, prefix=f".{target}.", suffix=".tmp")
    os.write(fd, b"half written")
    os.close(fd)
    return Path(name)


@pytest.mark.slow
def test_resume_removes_what_killed_writes_left_and_nothing_else(small_images, onnx_model, tmp_path):
    folder = pair_folder(tmp_path / "in", small_images, ("a", "b"))
    out = tmp_path / "out"
    base = ("batch-calibrate", folder, "-o", out, "--model", onnx_model, "--format", "json,ros")
    assert invoke(*base).exit_code == 0
    planted = [leftover(out, "summary.csv"), leftover(out, "summary.json"), leftover(out / "a", "left.yaml"),
               leftover(out / "a", MARKER), leftover(out / "b", "report.json")]  # fmt: skip
    (out / "b" / "report.json").unlink()  # the pair was being written when the run was killed
    (out / ".b.abcd1234.tmp").mkdir()  # a folder of that name is no temporary file
    unrelated = {
        out / "notes.tmp": b"mine",
        out / ".summary.csv.tmp": b"no random part",
        out / ".summary-shard-1-of-2.csv.abcd_123.tmp": b"another shard's, maybe in the making",
        out / ".b.abcd1234.tmp" / "inside": b"in a folder",
        out / "a" / "left.yaml.abcd1234.tmp": b"no leading dot",
        out / "a" / ".left.yaml.ABCD1234.tmp": b"not mkstemp's letters",
        out / "a" / ".left.yaml.abcd1234.tmp.bak": b"another suffix",
    }
    for path, data in unrelated.items():
        path.write_bytes(data)
    kept = {p.name: p.stat().st_mtime_ns for p in (out / "a").iterdir() if p not in [*planted, *unrelated]}
    result = invoke(*base, "--resume")
    assert result.exit_code == 0, result.output
    assert "resuming: 1 of 2 pairs" in result.stderr
    assert not [p for p in planted if p.exists()]
    assert {p: p.read_bytes() for p in unrelated} == unrelated
    assert {p.name: p.stat().st_mtime_ns for p in (out / "a").iterdir() if p.name in kept} == kept
    assert sorted(p.name for p in (out / "b").iterdir()) == [MARKER, "left.yaml", "report.json", "right.yaml"]
    assert json.loads((out / "summary.json").read_text())["counts"]["ok"] == 2


# The real command in a subprocess, stopped as a terminal's Ctrl-C or a cluster's time limit stops it: the
# signal goes to every process of the command (its process group), workers included.
PAIRS = 6


@pytest.fixture(scope="module")
def many_pairs(small_images, tmp_path_factory) -> Path:
    return pair_folder(tmp_path_factory.mktemp("many"), small_images, [f"p{i}" for i in range(PAIRS)])


def batch_command(*args) -> list[str]:
    return [sys.executable, "-m", "stereogeo_cli", "batch-calibrate", *(str(a) for a in args)]


@pytest.fixture(scope="module")
def reference(many_pairs, onnx_model, tmp_path_factory) -> dict:
    """An uninterrupted --same-rig run over the pairs: its summary.json."""
    out = tmp_path_factory.mktemp("reference") / "out"
    run = subprocess.run(batch_command(many_pairs, "-o", out, "--model", onnx_model, "--same-rig", "--json"),
                         capture_output=True, text=True, timeout=300)  # fmt: skip
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout)


def stopped_run(args, out: Path, first: int, second_after: float | None = None, timeout: float = 180):
    """Run the batch until its first pair is written, send ``first`` (and SIGINT ``second_after`` seconds
    later); return (exit code, stdout, stderr, seconds from the last signal to the exit)."""
    proc = subprocess.Popen(batch_command(*args, "-o", out), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)  # fmt: skip
    try:
        deadline = time.monotonic() + timeout
        while not list(out.glob(f"*/{MARKER}")):
            assert proc.poll() is None, f"the batch ended before a pair was written: {proc.communicate()}"
            assert time.monotonic() < deadline, "no pair written in time"
            time.sleep(0.02)
        os.killpg(proc.pid, first)
        if second_after is not None:
            time.sleep(second_after)
            os.killpg(proc.pid, signal.SIGINT)
        sent = time.monotonic()
        stdout, stderr = proc.communicate(timeout=timeout)
        return proc.returncode, stdout, stderr, time.monotonic() - sent
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()


def complete_folders(out: Path) -> set[str]:
    """The pair folders of ``out`` whose marker lists files that are all there as written; no folder and
    no file is left half written (no temporary file anywhere)."""
    assert not [p for p in out.rglob("*.tmp")]
    complete = set()
    for folder in (p for p in out.iterdir() if p.is_dir() and p.name != "rig"):
        marker = json.loads((folder / MARKER).read_text())
        for name, digest in marker["files"].items():
            assert hashlib.sha256((folder / name).read_bytes()).hexdigest() == digest, (folder, name)
        complete.add(folder.name)
    return complete


def without_timing(report: dict) -> dict:
    return {k: v for k, v in report.items() if k != "timing_ms"}


def check_stopped(out: Path, stderr: str, signal_name: str) -> list[dict]:
    """The summary of a stopped batch: some pairs ok, the others "not run", each ok pair's folder
    complete; one line on stderr says how far it got and how to go on. Returns the csv rows."""
    assert "Traceback" not in stderr, stderr
    lines = [line for line in stderr.splitlines() if line.startswith(f"interrupted by {signal_name}: ")]
    assert len(lines) == 1, stderr
    rows = read_csv(out / "summary.csv")
    ok = [r["name"] for r in rows if r["status"] == "ok"]
    assert 1 <= len(ok) < PAIRS, rows
    assert all(r["status"] == "not run" and r["left_focal_px"] == "" for r in rows if r["name"] not in ok)
    assert f"{len(ok)} of {PAIRS} pairs done" in lines[0] and "--resume" in lines[0]
    assert complete_folders(out) == set(ok)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] == signal_name
    assert summary["counts"] == {"pairs": PAIRS, "ok": len(ok), "failed": 0, "not_run": PAIRS - len(ok)}
    return rows


@pytest.mark.slow
def test_ctrl_c_keeps_the_pairs_done_and_resume_does_the_rest(many_pairs, onnx_model, reference, tmp_path):
    out = tmp_path / "out"
    code, _, stderr, _ = stopped_run((many_pairs, "--model", onnx_model), out, signal.SIGINT)
    assert code == 130, stderr
    rows = check_stopped(out, stderr, "SIGINT")
    done = {r["name"]: r for r in rows if r["status"] == "ok"}
    written = {p: p.stat().st_mtime_ns for name in done for p in (out / name).iterdir()}
    again = subprocess.run(batch_command(many_pairs, "-o", out, "--model", onnx_model), capture_output=True,
                           text=True, timeout=120)  # fmt: skip
    assert again.returncode == 2 and again.stderr.count("\n") == 1 and "--resume" in again.stderr
    resumed = subprocess.run(batch_command(many_pairs, "-o", out, "--model", onnx_model, "--resume"),
                             capture_output=True, text=True, timeout=300)  # fmt: skip
    assert resumed.returncode == 0, resumed.stderr
    rows = read_csv(out / "summary.csv")
    assert [r["status"] for r in rows] == ["ok"] * PAIRS
    assert [r for r in rows if r["name"] in done] == list(done.values())  # as when they were calibrated
    assert {p: p.stat().st_mtime_ns for p in written} == written  # taken, not written again
    summary = json.loads((out / "summary.json").read_text())
    assert summary["resumed"] == len(done) and summary["interrupted"] is None
    assert [without_timing(p["report"]) for p in summary["pairs"]] == [
        without_timing(p["report"]) for p in reference["pairs"]
    ]
    assert complete_folders(out) == {f"p{i}" for i in range(PAIRS)}


@pytest.mark.slow
def test_sigterm_with_workers_and_same_rig_then_resume(many_pairs, onnx_model, reference, tmp_path):
    out = tmp_path / "out"
    args = (many_pairs, "--model", onnx_model, "--workers", "2", "--same-rig")
    code, stdout, stderr, _ = stopped_run(args, out, signal.SIGTERM)
    assert code == 143, stderr
    check_stopped(out, stderr, "SIGTERM")
    assert "the other" in stderr and not (out / "rig").exists()
    assert json.loads((out / "summary.json").read_text())["rig"] == {
        "folder": None, "error": "not run: interrupted by SIGTERM",
    }  # fmt: skip
    assert all((out / name / EVIDENCE).is_file() for name in complete_folders(out))
    resumed = subprocess.run(batch_command(*args, "-o", out, "--resume", "--json"), capture_output=True,
                             text=True, timeout=300)  # fmt: skip
    assert resumed.returncode == 0, resumed.stderr
    summary = json.loads(resumed.stdout)
    assert summary["counts"]["ok"] == PAIRS and summary["resumed"] >= 1
    # the joint calibration from kept and new pairs alike is the uninterrupted run's
    assert without_timing(summary["rig"]["report"]) == without_timing(reference["rig"]["report"])
    assert without_timing(json.loads((out / "rig" / "report.json").read_text())) == without_timing(
        reference["rig"]["report"]
    )


@pytest.mark.slow
def test_a_second_ctrl_c_stops_the_workers_at_once(many_pairs, onnx_model, tmp_path):
    out = tmp_path / "out"
    args = (many_pairs, "--model", onnx_model, "--workers", "2")
    code, _, stderr, seconds = stopped_run(args, out, signal.SIGINT, second_after=0.1)
    assert code == 130 and "Traceback" not in stderr, stderr
    assert seconds < 10, seconds
    rows = read_csv(out / "summary.csv")
    ok = {r["name"] for r in rows if r["status"] == "ok"}
    assert ok and {r["status"] for r in rows} <= {"ok", "not run"}
    # every file is whole; the pair a killed worker was writing (if any) has no marker: not done
    assert not list(out.rglob("*.tmp"))
    assert {p.parent.name for p in out.glob(f"*/{MARKER}")} == ok


def process_states() -> dict[int, tuple[int, str]]:
    """Every process's (parent pid, state) from /proc."""
    states = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:
            continue  # gone meanwhile
        # "pid (comm) state ppid ...", where comm may hold ")"
        state, ppid = text[text.rindex(")") + 2 :].split()[:2]
        states[int(stat.parent.name)] = (int(ppid), state)
    return states


def descendants(pid: int) -> set[int]:
    """The live processes below ``pid``: its children, theirs, and so on."""
    states = process_states()
    found, todo = set(), [pid]
    while todo:
        parent = todo.pop()
        for child, (ppid, state) in states.items():
            if ppid == parent and state != "Z" and child not in found:
                found.add(child)
                todo.append(child)
    return found


def alive(pid: int) -> bool:
    """The process is there and not a zombie (one whose parent is gone is reaped by init, if ever)."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return text[text.rindex(")") + 2] != "Z"


def command_line(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/stat").is_file(), reason="reads the processes from /proc")
def test_workers_and_the_resource_tracker_end_when_the_batch_is_killed(many_pairs, onnx_model, tmp_path):
    out, log = tmp_path / "out", tmp_path / "stderr.txt"
    args = (many_pairs, "-o", out, "--model", onnx_model, "--workers", "2")
    with open(log, "w") as stderr:
        proc = subprocess.Popen(batch_command(*args), stdout=subprocess.DEVNULL, stderr=stderr,
                                start_new_session=True)  # fmt: skip
    try:
        deadline = time.monotonic() + 180
        while not list(out.glob(f"*/{MARKER}")):  # the workers are up and calibrating
            assert proc.poll() is None, f"the batch ended before a pair was written: {log.read_text()}"
            assert time.monotonic() < deadline, "no pair written in time"
            time.sleep(0.05)
        below = descendants(proc.pid)
        workers = [pid for pid in below if "spawn_main" in command_line(pid)]
        trackers = [pid for pid in below if "resource_tracker" in command_line(pid)]
        assert len(workers) == 2 and len(trackers) == 1, {pid: command_line(pid) for pid in below}
        os.kill(proc.pid, signal.SIGKILL)  # the parent alone, as the OOM killer or `kill -9` does
        proc.wait(timeout=10)
        deadline = time.monotonic() + 10
        while [pid for pid in below if alive(pid)] and time.monotonic() < deadline:
            time.sleep(0.1)
        left = {pid: command_line(pid) for pid in below if alive(pid)}
        assert not left, f"still running 10 s after the batch was killed: {left}"
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait()
