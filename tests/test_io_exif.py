"""The EXIF focal length as a prior (stereogeo_cli/io/exif.py): what is read from the tags, what is refused,
and what ``calibrate`` and ``batch-calibrate --same-rig`` make of it."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from stereogeo_cli.cli import app
from stereogeo_cli.io import load_image
from stereogeo_cli.io.exif import SIGMA_35MM, SIGMA_FOCAL_PLANE, read_exif_focal
from stereogeo_cli.refine import combine_focal
from stereogeo_cli.rig.combine import FocalEstimate, with_prior

DIAGONAL_35MM = math.hypot(36.0, 24.0)
runner = CliRunner()


def write_jpeg(path: Path, rgb: np.ndarray | None = None, size=(400, 300), **tags) -> Path:
    """A JPEG with the given EXIF tags: orientation in IFD0, the rest (by number) in the Exif IFD."""
    image = Image.fromarray(rgb) if rgb is not None else Image.new("RGB", size, (90, 120, 150))
    exif = Image.Exif()
    if "orientation" in tags:
        exif[0x0112] = tags.pop("orientation")
    ifd = exif.get_ifd(0x8769)
    for number, value in tags.items():
        ifd[int(number, 16)] = value
    image.save(path, quality=95, exif=exif.tobytes())
    return path


def test_35mm_equivalent_scales_by_the_diagonal(tmp_path):
    path = write_jpeg(tmp_path / "a.jpg", **{"0xA405": 26})
    found, reason = read_exif_focal(path, 400, 300)
    assert reason is None and found.tag == "FocalLengthIn35mmFilm" and found.value_mm == 26
    assert found.focal_px == pytest.approx(26 * 500 / DIAGONAL_35MM, rel=1e-12)
    assert found.sigma_rel == SIGMA_35MM


def test_a_turned_photo_is_not_mistaken_for_a_cropped_one(tmp_path):
    # stored 400x300 with the sensor size recorded, shown turned (orientation 6) as 300x400
    path = write_jpeg(tmp_path / "a.jpg", orientation=6, **{"0xA405": 26, "0xA002": 4000, "0xA003": 3000})
    image = load_image(path)
    assert image.shape[:2] == (400, 300)  # as displayed
    found, reason = read_exif_focal(path, image.shape[1], image.shape[0])
    assert reason is None and found.focal_px == pytest.approx(26 * 500 / DIAGONAL_35MM)


def test_a_cropped_photo_is_refused_with_the_reason(tmp_path):
    path = write_jpeg(tmp_path / "a.jpg", size=(300, 300), **{"0xA405": 26, "0xA002": 4032, "0xA003": 3024})
    found, reason = read_exif_focal(path, 300, 300)
    assert found is None and "cropped" in reason and "4032x3024" in reason


def test_focal_length_and_focal_plane_resolution_of_a_resized_photo(tmp_path):
    # 4.2 mm, 1.4 µm pixels (7142.86 per cm), shot at 4032x3024 and saved at a tenth of that
    path = write_jpeg(
        tmp_path / "a.jpg", size=(403, 302),
        **{"0x920A": 4.2, "0xA20E": 7142.857, "0xA210": 3, "0xA002": 4032, "0xA003": 3024},
    )  # fmt: skip
    found, reason = read_exif_focal(path, 403, 302)
    assert reason is None and found.tag == "FocalLength" and found.sigma_rel == SIGMA_FOCAL_PLANE
    assert found.focal_px == pytest.approx(4.2 / 0.0014 * 403 / 4032, rel=1e-4)


def _png_chunks(data: bytes) -> list[tuple[bytes, bytes]]:
    """(type, whole chunk with its length and CRC) of each chunk of a PNG file's bytes."""
    chunks, at = [], 8
    while at < len(data):
        length = int.from_bytes(data[at : at + 4], "big")
        chunks.append((data[at + 4 : at + 8], data[at : at + 12 + length]))
        at += 12 + length
    return chunks


def test_a_png_gives_the_tags_of_its_exif_chunk_before_or_after_its_pixels(tmp_path):
    """A PNG's EXIF (an eXIf chunk) is read from its chunk list, wherever the chunk sits, without decoding
    the pixels; the focal length is the one Pillow reads from the whole file."""
    exif = Image.Exif()
    exif.get_ifd(0x8769)[0xA405] = 26
    before = tmp_path / "before.png"
    Image.new("RGB", (400, 300), (90, 120, 150)).save(before, exif=exif.tobytes())
    chunks = _png_chunks(before.read_bytes())
    kinds = [kind for kind, _ in chunks]
    assert kinds.index(b"eXIf") < kinds.index(b"IDAT")
    # the same file with the chunk moved behind the pixels, where some writers put it
    moved = [c for kind, c in chunks if kind not in (b"eXIf", b"IEND")]
    after = tmp_path / "after.png"
    after.write_bytes(b"\x89PNG\r\n\x1a\n" + b"".join(moved) + dict(chunks)[b"eXIf"] + dict(chunks)[b"IEND"])
    with Image.open(after) as image:
        assert dict(image.getexif().get_ifd(0x8769))[0xA405] == 26  # Pillow agrees the file is whole
    for path in (before, after):
        found, reason = read_exif_focal(path, 400, 300)
        assert reason is None and found.tag == "FocalLengthIn35mmFilm" and found.value_mm == 26
        assert found.focal_px == pytest.approx(26 * 500 / DIAGONAL_35MM, rel=1e-12)
    cut = tmp_path / "cut.png"
    cut.write_bytes(before.read_bytes()[:40])  # a file cut short in its chunk list
    assert read_exif_focal(cut, 400, 300) == (None, None)


def test_no_usable_tags_mean_no_prior(tmp_path):
    plain = tmp_path / "plain.png"
    Image.new("RGB", (200, 100)).save(plain)
    assert read_exif_focal(plain, 200, 100) == (None, None)
    assert read_exif_focal(write_jpeg(tmp_path / "zero.jpg", **{"0xA405": 0}), 400, 300) == (None, None)
    broken = tmp_path / "broken.jpg"
    broken.write_bytes(b"\xff\xd8\xff\xe1\x00\x10Exif\x00\x00garbage-garbage")
    assert read_exif_focal(broken, 400, 300) == (None, None)
    found, reason = read_exif_focal(write_jpeg(tmp_path / "wide.jpg", **{"0xA405": 1}), 400, 300)
    assert found is None and "vFoV" in reason


def test_same_rig_counts_the_photos_prior_once():
    fields = FocalEstimate(500.0, 50.0, np.ones(3, bool))
    combined = with_prior(fields, [(600.0, 30.0)] * 3)
    assert (combined.focal_px, combined.sigma_px) == pytest.approx(combine_focal(500.0, 50.0, 600.0, 30.0))
    assert with_prior(fields, []) is fields


def test_combine_focal_weighs_by_inverse_variance_in_log_f():
    focal, sigma = combine_focal(400.0, 40.0, 500.0, 25.0)  # sigmas of log f: 0.1 and 0.05
    assert math.log(focal) == pytest.approx((math.log(400) / 0.01 + math.log(500) / 0.0025) / 500.0)
    assert sigma / focal == pytest.approx(math.sqrt(1 / 500.0))
    assert combine_focal(400.0, float("nan"), 500.0, 25.0) == pytest.approx((500.0, 25.0))


def calibrate_json(*args) -> dict:
    result = runner.invoke(app, ["calibrate", *map(str, args), "--json"])
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)


def jpeg_pair(folder: Path, left: Path, right: Path, f35: tuple[float | None, float | None]):
    paths = []
    for name, src, tag in (("left", left, f35[0]), ("right", right, f35[1])):
        tags = {} if tag is None else {"0xA405": int(round(tag))}
        paths.append(write_jpeg(folder / f"{name}.jpg", load_image(src), **tags))
    return paths


def _not_exif(prior: dict | None) -> bool:
    """A camera's report entry without a tag: none, or its straight edges' (refine/manhattan.py)."""
    return prior is None or prior["source"] == "lines"


def test_calibrate_combines_the_exif_focal_with_the_fields_and_warns_when_they_disagree(
    example_pair, onnx_model, tmp_path
):
    left, right = example_pair
    h, w = load_image(left).shape[:2]
    # the tag of a focal length three times the fields' reading on the left; none on the right
    plain = calibrate_json(left, right, "--model", onnx_model)
    tagged = 3 * plain["left"]["focal_px"] * DIAGONAL_35MM / math.hypot(w, h)
    jl, jr = jpeg_pair(tmp_path, left, right, (tagged, None))
    report = calibrate_json(jl, jr, "--model", onnx_model)
    prior, none = report["focal_prior"]
    assert _not_exif(none) and prior["source"] == "exif" and prior["tag"] == "FocalLengthIn35mmFilm"
    assert prior["focal_px"] == pytest.approx(int(round(tagged)) * math.hypot(w, h) / DIAGONAL_35MM)
    # combined by their sigmas: between the two readings, and where the weights put it (the matches move
    # the pre-fusion value by their focal ratio only)
    fields, fields_sigma = prior["fields_focal_px"], prior["fields_sigma_px"]
    expected, _ = combine_focal(fields, fields_sigma, prior["focal_px"], prior["sigma_px"])
    assert prior["combined_focal_px"] == pytest.approx(expected)
    assert fields < prior["combined_focal_px"] < prior["focal_px"]
    assert report["left"]["sigma"]["focal_px"] < fields_sigma
    assert any("EXIF focal length" in w and "--no-exif" in w for w in report["warnings"])
    # --no-exif: the images alone
    alone = calibrate_json(jl, jr, "--model", onnx_model, "--no-exif")
    assert all(map(_not_exif, alone["focal_prior"])) and not any("EXIF" in w for w in alone["warnings"])
    # a known focal length wins over the tag
    known = calibrate_json(jl, jr, "--model", onnx_model, "--focal-left", 300)
    assert known["focal_prior"][0] is None and known["left"]["focal_px"] == pytest.approx(300.0)


def test_exif_focal_fixes_a_long_lens_the_fields_read_wide(shared_data, tmp_path):
    """Middlebury's Adirondack (27° vFoV): stereogeo-m14's fields read its focal length 58 % short; with
    the focal length tagged as a phone would tag it (35 mm equivalent, whole millimetres) it is within
    10 %."""
    folder = shared_data / "real-dev" / "middlebury"
    record = json.loads((folder / "calib.jsonl").read_text().splitlines()[0])
    name = record["id"]
    left, right = folder / "left" / f"{name}.png", folder / "right" / f"{name}.png"
    width, height = record["left"]["width"], record["left"]["height"]
    f35 = [record[v]["K"][0][0] * DIAGONAL_35MM / math.hypot(width, height) for v in ("left", "right")]
    jl, jr = jpeg_pair(tmp_path, left, right, (f35[0], f35[1]))
    report = calibrate_json(jl, jr)
    for side in ("left", "right"):
        assert report["focal_prior"][int(side == "right")]["tag_mm"] == round(f35[int(side == "right")])
        assert abs(report[side]["focal_px"] / record[side]["K"][0][0] - 1) < 0.10


def test_batch_and_same_rig_take_the_tags_and_no_exif_turns_them_off(example_pair, onnx_model, tmp_path):
    """Two pairs of one rig tagged with the same 35 mm focal length: every pair's report takes the tag in,
    and the joint focal length of --same-rig is the fields' (over both pairs) combined with the tag once."""
    images = [load_image(p)[::2, ::2].copy() for p in example_pair]  # 320x240: quick
    h, w = images[0].shape[:2]
    f35 = 300.0 * DIAGONAL_35MM / math.hypot(w, h)  # a tag far from the fields' reading (about 170 px)
    folder = tmp_path / "in"
    folder.mkdir()
    for name in ("a", "b"):
        for side, image in zip(("left", "right"), images, strict=True):
            write_jpeg(folder / f"{name}_{side}.jpg", image, **{"0xA405": int(round(f35))})
    out = tmp_path / "out"
    args = ["batch-calibrate", folder, "-o", out, "--model", onnx_model, "--same-rig", "--baseline", "0.12"]
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 0, result.output
    reports = [json.loads((out / name / "report.json").read_text()) for name in ("a", "b")]
    prior = reports[0]["focal_prior"][0]
    assert prior["source"] == "exif" and reports[1]["focal_prior"][1]["tag_mm"] == round(f35)
    rig = json.loads((out / "rig" / "report.json").read_text())
    # the two (identical) pairs' fields combined, then the tag once: the fields' error on one camera is
    # common to its pairs, so two pairs weigh as one (FOCAL_COMMON_SHARE in rig/combine.py); the tag
    # counted twice would give 0.82 of this
    fields_rel = prior["fields_sigma_px"] / prior["fields_focal_px"]
    once = (1 / fields_rel**2 + 1 / (prior["sigma_px"] / prior["focal_px"]) ** 2) ** -0.5
    assert rig["left"]["sigma"]["focal_px"] / rig["left"]["focal_px"] == pytest.approx(once, rel=0.02)
    assert prior["fields_focal_px"] < rig["left"]["focal_px"] < prior["focal_px"]
    result = runner.invoke(app, [str(a) for a in [*args[:3], tmp_path / "plain", *args[4:], "--no-exif"]])
    assert result.exit_code == 0, result.output
    assert all(
        map(_not_exif, json.loads((tmp_path / "plain" / "a" / "report.json").read_text())["focal_prior"])
    )


def test_a_focal_length_given_with_a_sigma_is_combined_as_a_tag_is(example_pair, onnx_model):
    """The pipeline's ``known_focal_sigma``: a given focal length becomes a prior, not a held value, with a
    meaningful sigma (a soft prior inside the refiner met the fields' uninflated information and came out
    with a sigma of 150 %)."""
    from stereogeo_cli.pipeline import Calibrator

    left, right = (load_image(p) for p in example_pair)
    held = Calibrator(onnx_model, threads=1).calibrate(left, right, focal_left=500.0)
    assert held.left.focal_px == pytest.approx(500.0) and held.report()["focal_prior"][0] is None
    soft = Calibrator(onnx_model, threads=1, conf={"known_focal_sigma": 0.05})
    result = soft.calibrate(left, right, focal_left=500.0)
    prior = result.report()["focal_prior"][0]
    assert prior["source"] == "given" and prior["tag_mm"] is None and prior["focal_px"] == 500.0
    expected, sigma = combine_focal(prior["fields_focal_px"], prior["fields_sigma_px"], 500.0, 25.0)
    assert prior["combined_focal_px"] == pytest.approx(expected)
    assert prior["fields_focal_px"] < result.left.focal_px < 500.0
    assert result.left.sigma["focal_px"] / result.left.focal_px == pytest.approx(sigma / expected, rel=0.05)
