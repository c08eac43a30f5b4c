"""`stereogeo evaluate` on a small rendered dataset: metrics present, missing ground truth skipped."""

import json
import shutil

import numpy as np
import pytest
from typer.testing import CliRunner

from stereogeo_cli.cli import app
from stereogeo_cli.metrics import auc, summarize


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    from stereogeo_cli.synth.config import SynthConfig
    from stereogeo_cli.synth.dataset import make_dataset

    folder = tmp_path_factory.mktemp("eval") / "set"
    make_dataset(folder, 3, 21, SynthConfig(short_side=240, panorama_share=0.0), workers=1, progress=False)
    return folder


def test_auc_is_the_area_under_the_recall_curve():
    assert auc([0.5, 2.0, 20.0], (1.0,))[0] == pytest.approx(0.25)  # (0,0)→(0.5,1/3), flat to 1°
    assert auc(np.zeros(5)) == [1.0, 1.0, 1.0]
    assert auc(np.full(4, 50.0)) == [0.0, 0.0, 0.0]
    s = summarize(np.array([1.0, 2.0, 3.0]))
    assert s["median"] == 2.0 and s["mean"] == 2.0 and 0 < s["auc@5"] < 1


def test_auc_held_flat_below_one_degree_as_geocalib():
    """GeoCalib's variant: below min_error the curve is held at the recall of min_error."""
    errors = [0.2, 0.5, 2.0, 20.0]
    a1, a5 = auc(errors, (1.0, 5.0), min_error=1.0)
    assert a1 == pytest.approx(0.5)  # share of errors ≤ 1°, whatever their values below 1°
    # 0→1° at 0.5, 1°→2° trapezoid 0.5→0.75, 2°→5° at 0.75: (0.5 + 0.625 + 2.25) / 5
    assert a5 == pytest.approx((0.5 + 0.625 + 2.25) / 5)
    assert auc([0.01, 0.9], (1.0,), min_error=1.0) == auc([0.5, 0.99], (1.0,), min_error=1.0) == [1.0]
    # without it, errors below 1° lose area: 0.2 and 0.5 are rewarded differently
    assert auc(errors, (1.0,))[0] < a1


def test_failures_count_against_the_auc_but_not_the_median():
    s = summarize(np.array([0.5, 0.5, np.inf, np.nan]), min_error=1.0)
    assert s["median"] == 0.5 and s["auc@1"] == pytest.approx(0.5)


def test_evaluate_json_reports_the_papers_metrics(dataset, onnx_model):
    result = CliRunner().invoke(
        app, ["evaluate", str(dataset), "--json", "--baselines", "--model", str(onnx_model)]
    )
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    metrics = report["metrics"]
    for key in ("roll_deg", "pitch_deg", "vfov_deg"):
        assert set(metrics[key]) >= {"median", "mean", "auc@1", "auc@5", "auc@10"}
    for key in (
        "rotation_error_deg",
        "direction_error_deg",
        "translation_error_m",
        "baseline_error_rel",
        "sift+essential_rotation_error_deg",
    ):
        assert set(metrics[key]) >= {"median", "mean", "std"}
    assert metrics["pairs"] == {"evaluated": 3, "total": 3}
    assert len(report["pairs"]) == 3 and report["skipped"] == []
    # the signed vFoV error says which way the lens is misread; its size is the unsigned error
    for row in report["pairs"]:
        for view in ("left", "right"):
            assert abs(row[f"{view}_vfov_bias_deg"]) == pytest.approx(row[f"{view}_vfov_error_deg"])
    biases = [row[f"{v}_vfov_bias_deg"] for row in report["pairs"] for v in ("left", "right")]
    assert metrics["vfov_bias_deg"]["median"] == pytest.approx(np.median(biases))
    # the pose's errors in units of its reported sigmas, and their share within 1 sigma
    for name in ("rotation", "direction"):
        z = [row[f"{name}_z"] for row in report["pairs"]]
        assert all(v > 0 for v in z)
        assert metrics[f"{name}_sigma"]["within_1_sigma"] == pytest.approx(np.mean(np.array(z) <= 1))
        assert metrics[f"{name}_sigma"]["scale_for_68"] == pytest.approx(np.percentile(z, 68.27))
    # a sanity bound for the baseline's conventions (a flipped R or T, or a wrong K, gives tens of degrees);
    # three small renders are too few for an accuracy figure
    assert metrics["sift+essential_rotation_error_deg"]["median"] < 10.0


def test_missing_ground_truth_is_skipped_and_said(dataset, onnx_model, tmp_path):
    copy = tmp_path / "nogravity"
    shutil.copytree(dataset, copy)
    lines = [json.loads(line) for line in (copy / "calib.jsonl").read_text().splitlines()]
    for record in lines:
        record["left"]["gravity_up"] = record["right"]["gravity_up"] = None
        record["R"] = record["T"] = None
    (copy / "calib.jsonl").write_text("".join(json.dumps(r) + "\n" for r in lines))
    result = CliRunner().invoke(app, ["evaluate", str(copy), "--model", str(onnx_model)])
    assert result.exit_code == 0, result.output
    assert "skipped: roll: no ground truth" in result.stdout
    assert "skipped: relative pose: no ground truth" in result.stdout
    # with no gravity and no pose, only the vFoV's sigmas can be checked
    share = result.stdout.split("errors within the reported 1 / 3 sigma")[1].splitlines()[0]
    assert "vFoV" in share and "roll" not in share and "rotation" not in share


def test_the_table_says_how_many_errors_lie_within_their_sigmas(dataset, onnx_model):
    result = CliRunner().invoke(app, ["evaluate", str(dataset), "--model", str(onnx_model)])
    assert result.exit_code == 0, result.output
    share = result.stdout.split("errors within the reported 1 / 3 sigma")[1].splitlines()[0]
    for label in ("roll", "pitch", "vFoV", "rotation", "t direction"):
        assert f"{label} " in share


def test_not_a_dataset_is_exit_2(tmp_path, onnx_model):
    result = CliRunner().invoke(app, ["evaluate", str(tmp_path), "--model", str(onnx_model)])
    assert result.exit_code == 2
    assert "is not a dataset folder" in result.stderr
