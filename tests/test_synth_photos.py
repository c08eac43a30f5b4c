"""Training pairs from real photographs (make-data --photos) and the loss that learns from their focal
length."""

import json
import math

import cv2
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from stereogeo_cli.cli import app  # noqa: E402
from stereogeo_cli.network.data import FolderPairs, training_sample  # noqa: E402
from stereogeo_cli.network.losses import compute_losses  # noqa: E402
from stereogeo_cli.synth.photos import centre_cut, make_photo_pairs  # noqa: E402


def _photo_folder(tmp_path):
    """Three photographs: a textured one, a black one (left out) and one not to be trained on."""
    folder = tmp_path / "photos"
    (folder / "cam").mkdir(parents=True)
    rng = np.random.default_rng(0)
    records = []
    for name, image, ok in (
        ("a.jpg", rng.integers(0, 255, (480, 640, 3), dtype=np.uint8), True),
        ("black.jpg", np.zeros((480, 640, 3), np.uint8), True),
        ("private.jpg", rng.integers(0, 255, (480, 640, 3), dtype=np.uint8), False),
    ):
        cv2.imwrite(str(folder / "cam" / name), image)
        K = [[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]]
        records.append({"file": f"cam/{name}", "width": 640, "height": 480, "K": K, "gravity_up": None,
                        "camera": "one", "train_ok": ok})  # fmt: skip
    (folder / "labels.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    return folder


def test_a_centred_cut_keeps_the_focal_length_exact():
    image = np.zeros((480, 640, 3), np.uint8)
    K = np.array([[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]])
    cut, K_cut = centre_cut(image, K, 0.5, 160)
    assert cut.shape[:2] == (160, 213)
    # the central half (240 rows) resized to 160: f scales by 160/240, the vFoV is the cut's
    assert K_cut[1, 1] == pytest.approx(500 * 160 / 240, rel=0.01)
    assert math.degrees(2 * math.atan(160 / 2 / K_cut[1, 1])) == pytest.approx(
        math.degrees(2 * math.atan(120 / 500)), abs=0.3
    )
    assert (K_cut[0, 2], K_cut[1, 2]) == ((213 - 1) / 2, (160 - 1) / 2)


def test_photo_pairs_are_each_view_sharp_and_softened_with_its_truth(tmp_path):
    folder = _photo_folder(tmp_path)
    written = make_photo_pairs(folder, tmp_path / "out", split=None, zooms=(1.0, 0.5), short_side=120)
    assert written == 2  # one photo to train on (the black and the private one left out), two zooms
    pairs = FolderPairs(tmp_path / "out")
    left, right, record = pairs[1]
    assert record["R"] is None and record["left"]["gravity_up"] is None and record["zoom"] == 0.5
    assert left.shape == right.shape
    assert (
        np.abs(np.diff(right.astype(float), axis=1)).mean()
        < np.abs(np.diff(left.astype(float), axis=1)).mean()
    )
    expected = math.degrees(2 * math.atan(240 / 2 / 500))
    assert record["vfov_deg"] == pytest.approx(expected, abs=0.3)
    sample = training_sample(left, right, record, (128, 96))
    assert not sample["has_pose"] and torch.isnan(sample["gravity"]).all()


def test_make_data_photos_writes_the_pairs_and_refuses_a_bad_split(tmp_path):
    from typer.testing import CliRunner

    folder = _photo_folder(tmp_path)
    runner = CliRunner()
    done = runner.invoke(
        app, ["make-data", str(tmp_path / "out"), "--photos", str(folder), "--photo-split", "all"]
    )
    assert done.exit_code == 0, done.output
    assert len((tmp_path / "out" / "calib.jsonl").read_text().splitlines()) == 3
    bad = runner.invoke(
        app, ["make-data", str(tmp_path / "o2"), "--photos", str(folder), "--photo-split", "x"]
    )
    assert bad.exit_code == 2 and "photo-split" in bad.output


def _outputs(batch: int, height: int, width: int, latitude_shift: float):
    """Fields of a level camera with focal 0.9·height, the latitude scaled to read another focal length."""
    from stereogeo_cli.network.losses import ground_truth_fields

    g = torch.tensor([[0.0, -1.0, 0.0]] * batch)
    up, lat = ground_truth_fields(g, torch.full((batch,), 0.9 * height), width, height)
    out = {}
    for view in ("left", "right"):
        out[f"{view}_up"] = up.clone()
        out[f"{view}_latitude"] = (lat * (1.0 + latitude_shift)).clone().requires_grad_(True)
        out[f"{view}_up_confidence"] = torch.full((batch, height // 4, width // 4), 0.9)
        out[f"{view}_latitude_confidence"] = torch.full((batch, height // 4, width // 4), 0.9)
    return out


def test_the_photo_loss_is_the_vfov_error_after_the_refiner_and_moves_the_latitude_field():
    height, width = 96, 128
    batch = {
        "focal": torch.full((2, 2), 0.9 * height), "gravity": torch.full((2, 2, 3), float("nan")),
        "has_pose": torch.zeros(2, dtype=torch.bool), "has_translation": torch.zeros(2, dtype=torch.bool),
        "left": torch.zeros(2, 3, height, width), "R": torch.eye(3).repeat(2, 1, 1), "T": torch.zeros(2, 3),
    }  # fmt: skip
    conf = {"photo_weight": 1.0, "rotation_weight": 0.0, "translation_weight": 0.0}
    right = compute_losses(_outputs(2, height, width, 0.0), batch, conf)
    assert float(right["photo"].detach()) < math.radians(0.5)
    assert "up" not in right and "camera" not in right  # no gravity: nothing else to learn from
    wrong = _outputs(2, height, width, 0.15)
    losses = compute_losses(wrong, batch, conf)
    assert float(losses["photo"].detach()) > math.radians(2.0)
    losses["total"].backward()
    assert wrong["left_latitude"].grad.abs().sum() > 0
    assert "photo" not in compute_losses(
        _outputs(2, height, width, 0.15), batch, {**conf, "photo_weight": 0.0}
    )
