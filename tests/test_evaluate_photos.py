"""`stereogeo evaluate` on single photographs (a folder with a labels.jsonl): reading, scoring, the split."""

import json
import math
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from stereogeo_cli.cli import app
from stereogeo_cli.evaluate import sigma_coverage, weighted_quantile
from stereogeo_cli.evaluate_photos import (
    camera_ids,
    evaluate_photos,
    is_photo_set,
    make_split,
    read_labels,
    score_photos,
    select,
    weighted_auc,
)
from stereogeo_cli.metrics import auc

ROOT = Path(__file__).resolve().parents[1]


def _label(file: str, width: int, height: int, focal: float, **extra) -> dict:
    K = [[focal, 0.0, width / 2], [0.0, focal, height / 2], [0.0, 0.0, 1.0]]
    return {"file": file, "width": width, "height": height, "K": K, "dist": [], "gravity_up": None, **extra}


def _photo_set(folder: Path, labels: list[dict], image: np.ndarray | None = None) -> Path:
    """Images of the labels' sizes (cuts of ``image``, or noise) and the labels.jsonl."""
    rng = np.random.default_rng(0)
    for label in labels:
        path = folder / label["file"]
        path.parent.mkdir(parents=True, exist_ok=True)
        size = (label["height"], label["width"])
        pixels = rng.integers(0, 255, (*size, 3), np.uint8) if image is None else image[: size[0], : size[1]]
        assert cv2.imwrite(str(path), np.ascontiguousarray(pixels[..., ::-1]))
    (folder / "labels.jsonl").write_text("".join(json.dumps(label) + "\n" for label in labels))
    return folder


def _vfov(focal: float, height: int) -> float:
    return math.degrees(2 * math.atan(height / (2 * focal)))


# --- the maths, on known inputs


def test_weighted_auc_with_equal_weights_is_the_auc():
    rng = np.random.default_rng(1)
    errors = np.r_[rng.exponential(4.0, 40), np.inf, 0.3, 0.3]
    for min_error in (None, 1.0):
        got = weighted_auc(errors, np.ones(errors.size), (1.0, 5.0, 10.0), min_error)
        assert got == pytest.approx(auc(errors, (1.0, 5.0, 10.0), min_error))


def test_weighted_quantile_and_coverage():
    rng = np.random.default_rng(2)
    for n in (1, 2, 5, 8):
        values = rng.normal(size=n)
        assert weighted_quantile(values, np.ones(n), 0.5) == pytest.approx(np.median(values))
    # one camera of three images at 0.5, one of one image at 20: each weighs one
    values, weights = np.array([0.5, 0.5, 0.5, 20.0]), np.array([1 / 3, 1 / 3, 1 / 3, 1.0])
    assert weighted_quantile(values, weights, 0.5) == pytest.approx(10.25)  # between the two cameras
    assert weighted_quantile([], [], 0.5) is None
    z = np.array([0.5, 0.5, 0.5, 2.0])
    assert sigma_coverage(z, weights)["within_1_sigma"] == pytest.approx(0.5)  # not 3 / 4
    assert sigma_coverage(z, weights)["within_3_sigma"] == 1.0
    assert sigma_coverage(z) == sigma_coverage(z, np.ones(4)) | {"scale_for_68": np.percentile(z, 68.27)}


def _row(camera: str, source: str, error: float | None, z: float = 0.5, naive: float = 8.0) -> dict:
    row = {"camera": camera, "source": source, "set": "photo", "naive_vfov_error_deg": naive,
           "naive_vfov_bias_deg": naive, "naive_focal_error_rel": 0.2}  # fmt: skip
    if error is None:
        return {**row, "error": "failed"}
    return {**row, "photo_vfov_error_deg": error, "photo_vfov_bias_deg": -error, "photo_vfov_z": z,
            "photo_focal_error_rel": error / 50}  # fmt: skip


def test_every_camera_counts_once():
    """Three frames of camera a read within 1°, one of camera b 20° off: half the cameras are within 1°."""
    rows = [_row("a", "s1", 0.5) for _ in range(3)] + [_row("b", "s2", 20.0, z=2.0, naive=2.0)]
    m = score_photos(rows)
    whole = m["all"]
    assert (whole["images"], whole["cameras"], whole["failed"]) == (4, 2, 0)
    assert whole["vfov_deg"]["auc@1"] == pytest.approx(0.5)  # 0.75 if each frame counted
    # recall 0.5 from 0 to 10°: the curve is held at the share within 1° below 1°
    assert whole["vfov_deg"]["auc@10"] == pytest.approx(0.5)
    assert whole["vfov_deg"]["median"] == pytest.approx(10.25)
    assert whole["vfov_deg"]["mean"] == pytest.approx(10.25)
    assert whole["vfov_bias_deg"]["median"] == pytest.approx(-10.25)
    assert whole["vfov_sigma"]["within_1_sigma"] == pytest.approx(0.5)
    assert whole["vfov_sigma"]["within_3_sigma"] == 1.0
    # the naive guess, scored the same way: 8° on camera a, 2° on camera b
    assert whole["naive_vfov_deg"]["median"] == pytest.approx(5.0)
    assert whole["naive_vfov_deg"]["auc@1"] == 0.0
    assert whole["naive_focal_rel"]["median"] == pytest.approx(0.2)
    assert set(m["sources"]) == {"s1", "s2"} and set(m["sets"]) == {"photo"}
    assert m["sources"]["s1"]["vfov_deg"]["median"] == pytest.approx(0.5)
    assert m["sources"]["s1"]["vfov_deg"]["auc@1"] == 1.0
    assert "roll_deg" not in whole  # no gravity known


def test_a_failed_photo_is_never_recalled_but_has_no_median():
    rows = [_row("a", "s", 0.5), _row("b", "s", None)]
    whole = score_photos(rows)["all"]
    assert whole["failed"] == 1
    assert whole["vfov_deg"]["median"] == 0.5 and whole["vfov_deg"]["auc@1"] == pytest.approx(0.5)
    assert whole["naive_vfov_deg"]["median"] == 8.0  # the naive guess never fails


# --- labels, cameras and the split


def test_camera_ids_and_the_split():
    labels = [_label(f"phone/{i}.jpg", 640, 480, 500, camera="Acme One", train_ok=False) for i in range(5)]
    labels += [_label(f"lund/{i}.jpg", 640, 480, 500, camera="", train_ok=True) for i in range(3)]
    labels += [_label(f"many/{i}.jpg", 640, 480, 500, camera=f"Model {i}", train_ok=True) for i in range(6)]
    labels += [_label("other/0.jpg", 640, 480, 500, camera="model  3", train_ok=True)]  # model 3's twin
    ids = camera_ids(labels)
    assert ids[:8] == ["phone"] * 5 + ["lund"] * 3
    assert ids[8:14] == [f"many/Model {i}" for i in range(6)] and ids[14] == "other"
    records = [
        {**r, "source": r["file"].split("/")[0], "camera_id": i} for r, i in zip(labels, ids, strict=True)
    ]
    split = make_split(records)
    assert split == make_split(list(reversed(records)))  # from the labels, not their order
    assert sorted(split["train"] + split["measure"]) == sorted(set(ids))
    assert "phone" in split["measure"]  # measure-only images
    many = ids[8:14]
    assert sum(c in split["train"] for c in many) == 3  # a source of many cameras is halved
    side = "train" if "many/Model 3" in split["train"] else "measure"
    assert "other" in split[side]  # one camera model, one side


def test_select_by_split_file_and_by_image_list(tmp_path):
    labels = [_label("a/0.png", 96, 64, 80), _label("a/1.png", 96, 64, 80), _label("b/0.png", 96, 64, 80)]
    folder = _photo_set(tmp_path / "set", labels)
    assert is_photo_set(folder) and not is_photo_set(tmp_path)
    records = read_labels(folder)
    assert [r["camera_id"] for r in records] == ["a", "a", "b"]
    split_file = tmp_path / "split.json"
    split_file.write_text(json.dumps({"train": ["a"], "measure": ["b"]}))
    assert [r["file"] for r in select(records, "train", split_file)] == ["a/0.png", "a/1.png"]
    assert [r["file"] for r in select(records, "measure", split_file)] == ["b/0.png"]
    (tmp_path / "ids.txt").write_text("# two images\na/1.png\nb/0.png\n")
    assert [r["file"] for r in select(records, str(tmp_path / "ids.txt"))] == ["a/1.png", "b/0.png"]
    split_file.write_text(json.dumps({"train": ["a"], "measure": []}))
    with pytest.raises(Exception, match="does not place camera"):
        select(records, "measure", split_file)


class _FixedCalibrator:
    """Reads every photo 10 % too long in focal length, roll 1° and pitch 2° off, sigmas of 2° / 1° / 1°."""

    def __init__(self):
        self.pairs = []

    def calibrate(self, left, right):
        self.pairs.append((left.shape, right.shape))
        assert isinstance(left, np.ndarray) and isinstance(right, np.ndarray)  # arrays: no EXIF read
        assert np.array_equal(right, left[:, 8:])
        height = left.shape[0]
        focal = 1.1 * self.truth
        fit = SimpleNamespace(focal_px=focal, vfov_deg=_vfov(focal, height), roll_deg=1.0, pitch_deg=-2.0)
        sigma = {"vfov_deg": 2.0, "roll_deg": 1.0, "pitch_deg": 1.0}
        return SimpleNamespace(left=fit, calibration=SimpleNamespace(sigma_left=sigma))


def test_each_photo_is_calibrated_as_a_pair_of_arrays_and_scored(tmp_path):
    labels = [_label("cam/0.png", 120, 90, 100.0, camera="X", set="photo", gravity_up=[0.0, -1.0, 0.0])]
    folder = _photo_set(tmp_path / "set", labels)
    calibrator = _FixedCalibrator()
    calibrator.truth = 100.0
    results = evaluate_photos(folder, calibrator)
    assert calibrator.pairs == [((90, 120, 3), (90, 112, 3))]
    assert results["layout"] == "photos" and results["failed"] == [] and results["skipped"] == []
    row = results["photos"][0]
    error = _vfov(100.0, 90) - _vfov(110.0, 90)
    assert row["photo_vfov_error_deg"] == pytest.approx(error)
    assert row["photo_vfov_bias_deg"] == pytest.approx(-error)  # read too narrow
    assert row["photo_vfov_z"] == pytest.approx(error / 2.0)
    assert row["photo_focal_error_rel"] == pytest.approx(0.1)
    assert row["photo_roll_error_deg"] == pytest.approx(1.0) and row[
        "photo_pitch_error_deg"
    ] == pytest.approx(2.0)
    assert row["photo_pitch_z"] == pytest.approx(2.0)
    # the naive guess: f = 0.7 * 120 = 84 px, a level camera
    assert row["naive_focal_error_rel"] == pytest.approx(0.16)
    assert row["naive_vfov_bias_deg"] == pytest.approx(_vfov(84.0, 90) - _vfov(100.0, 90))
    assert row["naive_roll_error_deg"] == pytest.approx(0.0, abs=1e-9)
    whole = results["photo_metrics"]["all"]
    assert whole["pitch_sigma"]["within_1_sigma"] == 0.0 and whole["pitch_sigma"]["within_3_sigma"] == 1.0


# --- the command, with the network


def test_evaluate_reads_and_scores_a_photo_folder(tmp_path, onnx_model):
    from stereogeo_cli.io import load_image

    image = load_image(ROOT / "examples" / "left.png")
    h, w = image.shape[:2]
    labels = [
        _label("one/a.png", w, h, 0.8 * w, camera="One", set="photo", gravity_up=[0.0, -1.0, 0.0]),
        _label("one/b.png", w - 64, h - 48, 0.8 * w, camera="One", set="photo", gravity_up=[0.0, -1.0, 0.0]),
        _label("two/a.png", w - 32, h - 32, 0.6 * w, camera="Two", set="car"),
    ]
    folder = _photo_set(tmp_path / "photos", labels, image)
    split_file = tmp_path / "split.json"
    split_file.write_text(json.dumps({"train": ["two"], "measure": ["one"]}))
    runner = CliRunner()
    result = runner.invoke(
        app, ["evaluate", str(folder), "--json", "--model", str(onnx_model), "--split", "measure",
              "--split-file", str(split_file), "--plot", str(tmp_path / "cdf.png")],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    assert report["layout"] == "photos" and report["split"] == "measure"
    assert [r["id"] for r in report["photos"]] == ["one/a.png", "one/b.png"]
    whole = report["photo_metrics"]["all"]
    assert (whole["images"], whole["cameras"]) == (2, 1)
    for key in ("vfov_deg", "naive_vfov_deg", "roll_deg", "pitch_deg"):
        assert set(whole[key]) == {"median", "mean", "auc@1", "auc@5", "auc@10"}
    assert set(report["photo_metrics"]["sources"]) == {"one"}
    assert (tmp_path / "cdf.png").is_file()
    # the table, and the options that belong to the other layout
    table = runner.invoke(app, ["evaluate", str(folder), "--model", str(onnx_model)])
    assert table.exit_code == 0, table.output
    assert "every camera counting once" in table.stdout and "naive" in table.stdout
    assert "set car" in table.stdout and "two" in table.stdout
    baselines = runner.invoke(app, ["evaluate", str(folder), "--baselines", "--model", str(onnx_model)])
    assert baselines.exit_code == 2 and "needs stereo pairs" in baselines.stderr


# --- the real photographs


def test_the_split_file_places_every_camera_of_the_real_photographs(shared_data):
    folder = shared_data / "real-photos"
    records = read_labels(folder)
    split = json.loads((ROOT / "benchmarks" / "real_photos_split.json").read_text())
    assert split["train"] == make_split(records)["train"]  # the file is what the rule makes
    assert not set(split["train"]) & set(split["measure"])
    measured = {
        r["camera_id"] for r in select(records, "measure", ROOT / "benchmarks" / "real_photos_split.json")
    }
    assert all(r["camera_id"] in measured for r in records if r.get("train_ok") is False)


def test_evaluate_on_a_few_real_photographs(shared_data, onnx_model, tmp_path):
    folder = shared_data / "real-photos"
    records = read_labels(folder)
    chosen = [next(r["file"] for r in records if r["source"] == s) for s in ("mei_exif", "udacity_carnd")]
    chosen += [r["file"] for r in records if r.get("gravity_up") is not None][:2]  # gravity known
    (tmp_path / "ids.txt").write_text("\n".join(chosen) + "\n")
    result = CliRunner().invoke(
        app,
        ["evaluate", str(folder), "--json", "--split", str(tmp_path / "ids.txt"), "--model", str(onnx_model)],
    )
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    assert sorted(r["id"] for r in report["photos"]) == sorted(chosen) and report["failed"] == []
    metrics = report["photo_metrics"]
    assert set(metrics) == {"all", "sets", "sources"} and set(metrics["sets"]) == {"photo", "car"}
    whole = metrics["all"]
    for key in ("vfov_deg", "naive_vfov_deg", "roll_deg", "pitch_deg", "naive_pitch_deg"):
        assert all(math.isfinite(v) for v in whole[key].values()), key
    for key in ("vfov_sigma", "pitch_sigma"):
        assert all(math.isfinite(v) for v in whole[key].values()), key
    for row in report["photos"]:
        assert 0 < row["photo_vfov_deg"] < 180 and math.isfinite(row["photo_vfov_error_deg"])
