"""``batch-calibrate`` on pairs that differ in size and content: each pair's report is its own images'.

Five pairs (the example pair and four renders, 640 x 480 down to 240 x 240, landscape and portrait, four
scenes and lenses) in one folder, two workers: every pair's report must be the one
``stereogeo_cli.calibrate`` gives for that pair's files, and no other pair's; the pairs with ground truth are
as accurate as tests/test_accuracy.py holds them; every file written reads back as its report
(tests/test_formats_readback.py). ``--same-rig`` on two pairs of one size: the rig's files read back, and
each pair keeps its own gravity.
"""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import cv2
import pytest
from test_accuracy import EXAMPLE, TOLERANCES, assert_accurate, example_truth, roll_pitch_deg
from test_cli_calibrate import invoke, report_differences
from test_formats_readback import ALL_FILES, assert_folder_matches_report, written_files

# pair name in the folder -> the pair: "example" or a conftest.RENDERED_SEEDS name. The names sort in another
# order than the sizes and the seeds, with the slow large pair in the middle
PAIRS = {
    "d-room": "example",  # 640 x 480
    "b-street": "street-wide",  # 240 x 240
    "e-street": "street-long",  # 360 x 240
    "a-open": "open-portrait",  # 240 x 360
    "c-street": "street-square",  # 240 x 240
}
SAME_RIG = ("b-street", "c-street")  # one image size, as --same-rig needs
SAME_REPORT_TOLERANCE = 1e-9  # the batch and the API run the same code on the same pixels


@pytest.fixture(scope="module")
def sources(rendered_pairs) -> dict[str, tuple[Path, Path]]:
    """Pair name -> its (left, right) image files."""
    files = {"example": (EXAMPLE / "left.png", EXAMPLE / "right.png")}
    files |= {name: (pair.left, pair.right) for name, pair in rendered_pairs.items()}
    return {name: files[source] for name, source in PAIRS.items()}


def pair_folder(folder: Path, sources: dict[str, tuple[Path, Path]], names) -> Path:
    """A batch folder of ``names`` in the left/ + right/ layout."""
    for side in ("left", "right"):
        (folder / side).mkdir(parents=True)
    for name in names:
        for side, src in zip(("left", "right"), sources[name], strict=True):
            shutil.copy(src, folder / side / f"{name}.png")
    return folder


@pytest.fixture(scope="module")
def batch(sources, tmp_path_factory) -> tuple[dict, Path]:
    """``batch-calibrate FOLDER -o OUT --workers 2 --json`` on the five pairs: (summary, OUT)."""
    root = tmp_path_factory.mktemp("batch")
    folder = pair_folder(root / "in", sources, PAIRS)
    out = root / "out"
    result = invoke("batch-calibrate", folder, "-o", out, "--workers", 2, "--json")
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout), out


def reports_by_name(summary: dict) -> dict[str, dict]:
    return {p["name"]: p["report"] for p in summary["pairs"]}


def test_every_pair_gets_the_calibration_of_its_own_images(batch, sources, calibrate_api):
    summary, out = batch
    assert (summary["counts"]["pairs"], summary["counts"]["ok"], summary["counts"]["failed"]) == (5, 5, 0)
    assert [p["name"] for p in summary["pairs"]] == sorted(PAIRS)
    reports = reports_by_name(summary)
    alone = {name: calibrate_api(*sources[name]) for name in PAIRS}  # each pair on its own, in-process
    for name, report in reports.items():
        for side, path in zip(("left", "right"), sources[name], strict=True):
            h, w = cv2.imread(str(path)).shape[:2]
            assert (report[side]["width"], report[side]["height"]) == (w, h), (name, side)
        assert report_differences(report, alone[name], SAME_REPORT_TOLERANCE) == [], name
        # and no other pair's: the comparison tells every pair from every other
        for other in PAIRS:
            if other != name:
                assert report_differences(report, alone[other], SAME_REPORT_TOLERANCE) != [], (name, other)
        # the pair's folder holds the same report
        assert json.loads((out / name / "report.json").read_text()) == report


def test_the_summary_table_lists_each_pairs_own_numbers(batch, sources):
    summary, out = batch
    reports = reports_by_name(summary)
    with open(out / "summary.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [row["name"] for row in rows] == sorted(PAIRS)
    for row in rows:
        report = reports[row["name"]]
        assert row["status"] == "ok" and row["error"] == ""
        for side in ("left", "right"):
            for key in ("focal_px", "vfov_deg", "roll_deg", "pitch_deg"):
                assert float(row[f"{side}_{key}"]) == report[side][key], (row["name"], side, key)
        assert float(row["baseline_m"]) == report["baseline_m"]
        assert int(row["matches"]) == report["matches"]["found"]
        assert int(row["inliers"]) == report["matches"]["inliers"]
        assert Path(row["left_file"]).name == Path(row["right_file"]).name == f"{row['name']}.png"
        assert Path(row["left_file"]).parent.name == "left" and Path(row["right_file"]).parent.name == "right"


@pytest.mark.parametrize("name", ["d-room", "b-street", "e-street"])
def test_pairs_of_a_batch_are_as_accurate_as_alone(batch, rendered_pairs, name):
    """The pairs with tolerances in tests/test_accuracy.py, through batch-calibrate, against each its own
    ground truth (the five have different focal lengths and gravity)."""
    summary, _ = batch
    source = PAIRS[name]
    truth = example_truth() if source == "example" else rendered_pairs[source].truth
    assert_accurate(reports_by_name(summary)[name], truth, TOLERANCES[source])


def test_every_pairs_files_read_back_as_its_report(batch, tmp_path):
    summary, out = batch
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == sorted(PAIRS)  # no folder of another name
    for name, report in reports_by_name(summary).items():
        scratch = tmp_path / name
        scratch.mkdir()
        assert_folder_matches_report(out / name, report, scratch)


# --------------------------------------------------------------------------------------------------- same rig
@pytest.fixture(scope="module")
def same_rig(sources, tmp_path_factory) -> tuple[dict, Path]:
    """``batch-calibrate FOLDER -o OUT --same-rig --json`` on two 240 x 240 pairs: (summary, OUT)."""
    root = tmp_path_factory.mktemp("same-rig")
    folder = pair_folder(root / "in", sources, SAME_RIG)
    out = root / "out"
    result = invoke("batch-calibrate", folder, "-o", out, "--same-rig", "--json")
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout), out


def test_same_rig_files_read_back_as_the_rigs_report(same_rig, batch, tmp_path):
    summary, out = same_rig
    assert summary["rig"]["folder"] == "rig"
    rig = summary["rig"]["report"]
    assert json.loads((out / "rig" / "report.json").read_text()) == rig
    (tmp_path / "rig").mkdir()
    assert_folder_matches_report(out / "rig", rig, tmp_path / "rig")
    # each pair's own folder: its first calibration, alone, as in a plain batch
    plain = reports_by_name(batch[0])
    for name, report in reports_by_name(summary).items():
        assert written_files(out / name) == ALL_FILES
        assert report_differences(report, plain[name], SAME_REPORT_TOLERANCE) == [], name
        (tmp_path / name).mkdir()
        assert_folder_matches_report(out / name, report, tmp_path / name)


def test_same_rig_keeps_each_pairs_gravity(same_rig, rendered_pairs):
    """The rig's report lists each pair's gravity, found with the rig's focal lengths: each near its own
    pair's ground truth. Measured: within 0.62° in roll and 0.47° in pitch (each pair alone: 0.32° and
    0.91°); the two pairs' cameras are 12° apart in roll and 35° in pitch, so 2° tells them apart."""
    summary, _ = same_rig
    pairs = summary["rig"]["report"]["pairs"]
    assert [p["name"] for p in pairs] == list(SAME_RIG)
    for entry in pairs:
        truth = rendered_pairs[PAIRS[entry["name"]]].truth
        for side in ("left", "right"):
            roll, pitch = roll_pitch_deg(truth[side]["gravity_up"])
            assert abs(entry[f"{side}_roll_deg"] - roll) < 2.0, (entry["name"], side, entry, roll)
            assert abs(entry[f"{side}_pitch_deg"] - pitch) < 2.0, (entry["name"], side, entry, pitch)
