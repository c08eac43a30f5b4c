"""make-data as a user meets it: the dataset layout, same seed → same bytes, resume, the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from stereogeo_cli.cli import app
from stereogeo_cli.synth.config import SynthConfig
from stereogeo_cli.synth.dataset import make_dataset, read_done_ids
from stereogeo_cli.synth.sample import sample_pair

CONFIG = SynthConfig(texture_size=128, texture_layers=24, aspects=(4 / 3, 1.0), depth=True)


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_layout_and_calib_lines(tmp_path):
    make_dataset(tmp_path, 3, seed=11, config=CONFIG, progress=False)
    lines = (tmp_path / "calib.jsonl").read_text().splitlines()
    assert len(lines) == 3
    for line in lines:
        record = json.loads(line)
        assert set(record) >= {"id", "left", "right", "R", "T", "notes"}
        for side in ("left", "right"):
            assert set(record[side]) == {"K", "dist", "width", "height", "gravity_up"}
            image = cv2.imread(str(tmp_path / side / f"{record['id']}.png"), cv2.IMREAD_UNCHANGED)
            assert image.shape == (record[side]["height"], record[side]["width"], 3)
            depth = np.load(tmp_path / "depth" / side / f"{record['id']}.npy")
            assert depth.shape == image.shape[:2] and depth.dtype == np.float32
        np.testing.assert_allclose(
            np.array(record["R"]) @ record["left"]["gravity_up"], record["right"]["gravity_up"], atol=1e-12
        )


def test_same_seed_same_bytes_with_workers_and_after_interruption(tmp_path):
    one, two, resumed = tmp_path / "one", tmp_path / "two", tmp_path / "resumed"
    make_dataset(one, 5, seed=5, config=CONFIG, workers=1, progress=False)
    make_dataset(two, 5, seed=5, config=CONFIG, workers=2, progress=False)
    assert _files(one) == _files(two)

    # an interrupted run: 3 pairs done, the last calib line half written, a temporary file left behind
    make_dataset(resumed, 3, seed=5, config=CONFIG, progress=False)
    calib = resumed / "calib.jsonl"
    text = calib.read_text()
    calib.write_text(text[: len(text) - 40])
    (resumed / "left" / ".tmp-999-000003.png").write_bytes(b"partial")
    assert read_done_ids(calib) == {"000000", "000001"}
    summary = make_dataset(resumed, 5, seed=5, config=CONFIG, progress=False)
    assert (summary.written, summary.skipped) == (3, 2)
    assert _files(resumed) == _files(one)

    # the images are exactly what the Python API returns
    sample = sample_pair(5, 4, CONFIG)
    image = cv2.cvtColor(cv2.imread(str(one / "left" / "000004.png")), cv2.COLOR_BGR2RGB)
    assert np.array_equal(image, sample.left)


def test_resume_refuses_other_settings(tmp_path):
    from stereogeo_cli.errors import StereoGeoError

    make_dataset(tmp_path, 1, seed=1, config=CONFIG, progress=False)
    with pytest.raises(StereoGeoError, match="other settings"):
        make_dataset(tmp_path, 2, seed=2, config=CONFIG, progress=False)


def test_folders_made_before_close_range_scenes_and_narrow_crops_resume_as_they_were_made(tmp_path):
    from stereogeo_cli.errors import StereoGeoError

    old = CONFIG.replace(close_share=0.0, panorama_max_upsampling=1.5)
    make_dataset(tmp_path, 1, seed=1, config=old, progress=False)
    settings = tmp_path / "make-data.json"
    text = json.loads(settings.read_text())
    del text["config"]["close_share"], text["config"]["panorama_max_upsampling"]  # older writers' settings
    settings.write_text(json.dumps(text))
    make_dataset(tmp_path, 2, seed=1, config=old, progress=False)
    assert len((tmp_path / "calib.jsonl").read_text().splitlines()) == 2
    with pytest.raises(StereoGeoError, match="other settings"):
        make_dataset(tmp_path, 3, seed=1, config=CONFIG.replace(close_share=0.5), progress=False)
    with pytest.raises(StereoGeoError, match="other settings"):
        make_dataset(tmp_path, 3, seed=1, config=old.replace(panorama_max_upsampling=3.0), progress=False)


@pytest.mark.parametrize("max_upsampling", [1.5, 3.5])
def test_panorama_crops_magnify_their_panorama_at_most_panorama_max_upsampling(max_upsampling):
    from stereogeo_cli.synth.rigs import sample_rig
    from stereogeo_cli.synth.sample import _panorama_rig

    cfg = CONFIG.replace(vfov_deg=(18.0, 105.0), panorama_max_upsampling=max_upsampling)
    rng = np.random.default_rng(5)
    vfovs, floors = [], []
    for _ in range(400):
        crop = _panorama_rig(sample_rig(rng, cfg), cfg, panorama_width=1024)
        # crop pixels per degree at the centre, against the panorama's 1024 / 360
        for vfov in (crop.vfov_left, crop.vfov_right):
            magnification = crop.height / (2 * np.tan(vfov / 2)) * np.radians(1.0) / (1024 / 360)
            assert magnification <= max_upsampling * 1.0001
            vfovs.append(np.degrees(vfov))
        floors.append(crop.height * 360 / (max_upsampling * 1024))
        assert not crop.offset.any()  # crops of one panorama: a pure rotation
    assert np.min(vfovs) < np.max(floors) + 3  # the floor is reached: narrow crops are widened, not dropped
    assert np.max(vfovs) > 90


def test_cli_writes_dataset_and_preview(tmp_path):
    runner = CliRunner()
    out, sheet = tmp_path / "set", tmp_path / "sheet.png"
    result = runner.invoke(
        app, ["make-data", str(out), "-n", "2", "--size", "96", "--aspects", "4:3", "--preview", str(sheet)]
    )
    assert result.exit_code == 0, result.output
    assert len((out / "calib.jsonl").read_text().splitlines()) == 2
    assert cv2.imread(str(sheet)) is not None


@pytest.mark.parametrize(
    "args",
    [
        ["--aspects", "4:x"],
        ["--vfov-min", "120", "--vfov-max", "30"],
        ["--close-share", "1.5"],
        ["--panorama-max-upsampling", "0.5"],
        ["--textures", "/nonexistent/folder"],
        [],  # neither an output folder nor --preview
    ],
)
def test_cli_bad_options_give_one_line_and_exit_2(tmp_path, args):
    out = [str(tmp_path / "x")] if args else []
    result = CliRunner().invoke(app, ["make-data", *out, *args])
    assert result.exit_code == 2
    assert "Traceback" not in result.output
