"""``stereogeo calibrate`` as a user meets it: real image files, every way an input can be wrong (DESIGN §8).

Errors must be one line on stderr (``error: ...``), never a traceback, with the exit code of DESIGN §8.
The installed Click (8.2+) keeps stderr apart: ``result.stdout`` is stdout only, ``result.stderr`` stderr.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from stereogeo_cli.cli import app

ROOT = Path(__file__).resolve().parents[1]
runner = CliRunner()


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def assert_error(result, code: int, *words: str) -> str:
    """The command failed with ``code``, one ``error:`` line on stderr naming ``words``, nothing on stdout."""
    assert result.exit_code == code, (result.exit_code, result.output)
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("error: ") and "Traceback" not in result.output
    for word in words:
        assert word in lines[0], lines[0]
    assert result.stdout == ""
    return lines[0]


def write_rgb(path: Path, rgb: np.ndarray) -> Path:
    assert cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR) if rgb.ndim == 3 else rgb)
    return path


@pytest.fixture(scope="module")
def pair(example_pair, tmp_path_factory) -> tuple[Path, Path]:
    """The example pair at 320x240 (quick to calibrate) as PNG files."""
    folder = tmp_path_factory.mktemp("small")
    paths = []
    for name, src in zip(("left", "right"), example_pair, strict=True):
        image = cv2.imread(str(src), cv2.IMREAD_COLOR)
        small = cv2.resize(image, (320, 240), interpolation=cv2.INTER_AREA)
        path = folder / f"{name}.png"
        cv2.imwrite(str(path), small)
        paths.append(path)
    return paths[0], paths[1]


def rgb(path: Path) -> np.ndarray:
    return cv2.cvtColor(cv2.imread(str(path), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


# ------------------------------------------------------------------------------------------------ bad input
def test_missing_file(pair, onnx_model, tmp_path):
    assert_error(invoke("calibrate", tmp_path / "nope.png", pair[1], "--model", onnx_model), 2, "not found")


def test_not_an_image(pair, onnx_model, tmp_path):
    text = tmp_path / "notes.png"
    text.write_text("these are my holiday notes, not a picture\n")
    assert_error(invoke("calibrate", pair[0], text, "--model", onnx_model), 2, "notes.png")


def test_truncated_png(pair, onnx_model, tmp_path):
    data = pair[0].read_bytes()
    cut = tmp_path / "cut.png"
    cut.write_bytes(data[: len(data) // 2])
    assert_error(invoke("calibrate", cut, pair[1], "--model", onnx_model), 2, "truncated")


def test_one_pixel_image(pair, onnx_model, tmp_path):
    tiny = write_rgb(tmp_path / "tiny.png", np.full((1, 1, 3), 128, np.uint8))
    assert_error(invoke("calibrate", tiny, pair[1], "--model", onnx_model), 2, "too small")


def test_blank_image_fails_calibration_with_the_reason(pair, onnx_model, tmp_path):
    blank = write_rgb(tmp_path / "blank.png", np.full((240, 320, 3), 90, np.uint8))
    assert_error(invoke("calibrate", pair[0], blank, "--model", onnx_model), 3, "blank")


def report_differences(a, b, tol: float, path: str = "") -> list[str]:
    """Where two JSON reports differ, numbers by more than ``tol`` (absolute); timings are not compared."""
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            return [f"{path}: keys {sorted(set(a) ^ set(b))}"]
        return [d for k in a if k != "timing_ms" for d in report_differences(a[k], b[k], tol, f"{path}.{k}")]
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{path}: {len(a)} != {len(b)} items"]
        return [
            d
            for i, (x, y) in enumerate(zip(a, b, strict=True))
            for d in report_differences(x, y, tol, f"{path}[{i}]")
        ]
    if _number(a) and _number(b):
        return [] if abs(a - b) <= tol else [f"{path}: {a} != {b}"]
    return [] if a == b else [f"{path}: {a!r} != {b!r}"]


def _number(value) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


@pytest.fixture(scope="module")
def eight_bit_reports(pair, onnx_model, tmp_path_factory) -> dict[str, dict]:
    """The reports of the pair with its right image as 8-bit RGB ("colour") and as 8-bit RGB of its grey
    version, three equal channels ("grey"): what the other encodings of those pixels must give."""
    folder = tmp_path_factory.mktemp("eight-bit")
    grey = write_rgb(folder / "grey-rgb.png", cv2.cvtColor(cv2.cvtColor(rgb(pair[1]), cv2.COLOR_RGB2GRAY),
                                                           cv2.COLOR_GRAY2RGB))  # fmt: skip
    reports = {}
    for name, right in (("colour", pair[1]), ("grey", grey)):
        result = invoke("calibrate", pair[0], right, "--model", onnx_model, "--json")
        assert result.exit_code == 0, result.output
        reports[name] = json.loads(result.stdout)
    return reports


@pytest.mark.parametrize(
    "kind, reference",
    [("16-bit", "colour"), ("rgba", "colour"), ("16-bit rgba", "colour"), ("grey", "grey"),
     ("16-bit grey", "grey")],
)  # fmt: skip
def test_16_bit_rgba_and_grey_images_give_the_8_bit_report(pair, onnx_model, eight_bit_reports, tmp_path,
                                                          kind, reference):  # fmt: skip
    """The same pixels stored as 16 bits (8-bit value x 257), with an alpha channel, or as one grey channel
    calibrate exactly as the 8-bit RGB file does (docs/io.md, "Input images")."""
    bgr = cv2.cvtColor(rgb(pair[1]), cv2.COLOR_RGB2BGR)
    image = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY) if "grey" in kind else bgr
    if "rgba" in kind:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2BGRA)
        image[..., 3] = 200  # transparency is dropped, not blended
    if "16-bit" in kind:
        image = image.astype(np.uint16) * 257
    path = tmp_path / "right.png"
    assert cv2.imwrite(str(path), image)
    assert cv2.imread(str(path), cv2.IMREAD_UNCHANGED).dtype == image.dtype  # stored as meant
    result = invoke("calibrate", pair[0], path, "--model", onnx_model, "--json")
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    assert report["right"]["width"] == 320
    assert report_differences(report, eight_bit_reports[reference], 1e-6) == []
    if reference == "grey":  # not the colour one's: the comparison tells the two apart
        assert report_differences(report, eight_bit_reports["colour"], 1e-6) != []


def test_output_folder_that_is_a_file(pair, onnx_model, tmp_path):
    blocker = tmp_path / "taken"
    blocker.write_text("a file where the output folder should go")
    assert_error(invoke("calibrate", *pair, "--model", onnx_model, "-o", blocker), 2, "not a folder")
    # a folder under a file cannot be made either (permission bits do not stop root, this does)
    assert_error(invoke("calibrate", *pair, "--model", onnx_model, "-o", blocker / "sub"), 2, "taken")
    assert_error(
        invoke("calibrate", *pair, "--model", onnx_model, "--preview", blocker / "p.png"), 2, "taken"
    )


@pytest.mark.parametrize("content", [b"", b"not an onnx model at all" * 10])
def test_corrupt_model_file(pair, tmp_path, content):
    model = tmp_path / "model.onnx"
    model.write_bytes(content)
    assert_error(invoke("calibrate", *pair, "--model", model), 2, "model.onnx")


def test_missing_model_file(pair, tmp_path):
    assert_error(invoke("calibrate", *pair, "--model", tmp_path / "gone.onnx"), 2, "model file not found")


def test_bad_format(pair, onnx_model, tmp_path):
    result = invoke("calibrate", *pair, "--model", onnx_model, "-o", tmp_path, "--format", "opencv,matlab")
    assert_error(result, 2, "matlab", "opencv, ros")


@pytest.mark.parametrize("value", ["0", "-0.1", "nan", "inf"])
def test_bad_baseline(pair, onnx_model, value):
    assert_error(invoke("calibrate", *pair, "--model", onnx_model, "--baseline", value), 2, "--baseline")


def test_rotate_takes_quarter_turns(pair, onnx_model):
    assert_error(invoke("calibrate", *pair, "--model", onnx_model, "--rotate", "45"), 2, "--rotate", "180")


def test_rotate_reaches_the_report(pair, onnx_model, tmp_path):
    """An upside-down pair read with --rotate 180: the network reads the upright pair, so the gravity written
    is the upright reading turned by 180° about the view (roll +180°, pitch the same)."""
    upright = json.loads(invoke("calibrate", *pair, "--model", onnx_model, "--json").stdout)
    turned = [write_rgb(tmp_path / f"{n}.png", rgb(p)[::-1, ::-1]) for n, p in zip("lr", pair, strict=True)]
    result = invoke("calibrate", turned[1], turned[0], "--model", onnx_model, "--json", "--rotate", "180")
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    assert report["rotate_deg"] == 180 and not report["warnings"]
    assert report["left"]["roll_deg"] == pytest.approx(upright["right"]["roll_deg"] + 180, abs=1e-6)
    assert report["left"]["pitch_deg"] == pytest.approx(upright["right"]["pitch_deg"], abs=1e-6)


def test_baseline_that_is_not_a_number(pair, onnx_model):
    result = invoke("calibrate", *pair, "--model", onnx_model, "--baseline", "ten")
    assert result.exit_code == 2 and "Traceback" not in result.output  # Click's usage error
    assert "--baseline" in result.stderr


# ------------------------------------------------------------------------------------------------- outputs
def test_json_is_one_object_on_stdout_and_nothing_else(pair, onnx_model):
    result = invoke("calibrate", *pair, "--model", onnx_model, "--json", "--baseline", "0.2")
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)  # raises if anything else is on stdout
    assert isinstance(report, dict)
    for key in ("left", "right", "R", "T", "baseline_m", "scale_source", "matches", "timing_ms", "model"):
        assert key in report
    for side in ("left", "right"):
        cam = report[side]
        for key in ("width", "height", "K", "focal_px", "vfov_deg", "roll_deg", "pitch_deg", "gravity_up"):
            assert key in cam
        assert set(cam["sigma"]) >= {"focal_px", "vfov_deg", "roll_deg", "pitch_deg"}
    assert np.array(report["R"]).shape == (3, 3) and len(report["T"]) == 3
    assert report["scale_source"] == "baseline" and report["baseline_m"] == pytest.approx(0.2)
    assert set(report["matches"]) == {"found", "inliers"} and report["timing_ms"]["total"] > 0
    assert set(report["model"]) == {"file", "sha256"}


def test_a_learned_baseline_carries_the_models_sigma_and_a_given_one_none(pair, onnx_model):
    from stereogeo_cli.network.runtime import FieldNetwork

    metadata = FieldNetwork(onnx_model).metadata
    learned = invoke("calibrate", *pair, "--model", onnx_model, "--json")
    given = invoke("calibrate", *pair, "--model", onnx_model, "--json", "--baseline", "0.2")
    assert learned.exit_code == 0 and given.exit_code == 0, learned.output + given.output
    learned, given = json.loads(learned.stdout), json.loads(given.stdout)
    assert given["pose"]["sigma_baseline_rel"] is None
    expected = float(metadata["pose_sigma_scale_rel"]) if "pose_sigma_scale_rel" in metadata else None
    assert learned["scale_source"] == "learned" and learned["pose"]["sigma_baseline_rel"] == expected
    # a model without a depth head: the length is the pose head's, which the report also gives on its own
    assert learned["pose"]["baseline_source"] == "pose_head" and given["pose"]["baseline_source"] is None
    assert learned["baseline_m"] == pytest.approx(learned["pose"]["head_baseline_m"], rel=1e-6)
    assert given["pose"]["head_baseline_m"] == pytest.approx(learned["pose"]["head_baseline_m"], rel=1e-6)


def test_no_lines_leaves_the_gravity_and_focal_length_to_the_fields(pair, onnx_model):
    """--no-lines: no segments used (neither vertical ones nor vanishing points), and each camera's gravity
    is exactly what the fields alone give."""
    from stereogeo_cli.pipeline import Calibrator

    runs = {
        flag: invoke("calibrate", *pair, "--model", onnx_model, "--json", flag)
        for flag in ("--lines", "--no-lines")
    }
    assert all(run.exit_code == 0 for run in runs.values()), [run.output for run in runs.values()]
    with_lines, without = (json.loads(run.stdout) for run in runs.values())
    assert without["vertical_segments"] == [0, 0] and without["focal_prior"] == [None, None]
    assert len(with_lines["vertical_segments"]) == 2 and min(with_lines["vertical_segments"]) >= 0
    reference = Calibrator(
        onnx_model, conf={"lines": {"enabled": False}, "manhattan": {"enabled": False}}
    ).calibrate(*(rgb(p) for p in pair))
    for side, fit in (("left", reference.left), ("right", reference.right)):
        np.testing.assert_allclose(without[side]["gravity_up"], fit.gravity_up, atol=1e-9)


def test_output_folder_gets_the_default_formats(pair, onnx_model, tmp_path):
    out = tmp_path / "calib"
    result = invoke("calibrate", *pair, "--model", onnx_model, "-o", out)
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in out.iterdir()) == [
        "camchain.yaml", "cameras.txt", "extrinsics.yml", "intrinsics.yml", "left.yaml", "report.html",
        "report.json", "right.yaml",
    ]  # fmt: skip
    for name in ("intrinsics.yml", "left.yaml", "camchain.yaml", "cameras.txt", "report.json", "report.html"):
        assert name in result.output  # the summary lists every file written
    intrinsics = cv2.FileStorage(str(out / "intrinsics.yml"), cv2.FILE_STORAGE_READ)
    extrinsics = cv2.FileStorage(str(out / "extrinsics.yml"), cv2.FILE_STORAGE_READ)
    M1 = intrinsics.getNode("M1").mat()
    assert M1.shape == (3, 3) and M1[2, 2] == 1.0 and intrinsics.getNode("D2").mat().shape == (1, 5)
    R, T = extrinsics.getNode("R").mat(), extrinsics.getNode("T").mat()
    assert R.shape == (3, 3) and T.shape == (3, 1) and extrinsics.getNode("Q").mat().shape == (4, 4)
    report = json.loads((out / "report.json").read_text())
    np.testing.assert_allclose(R, report["R"], atol=1e-9)
    np.testing.assert_allclose(M1, report["left"]["K"], rtol=1e-9)


def test_preview_is_a_png(pair, onnx_model, tmp_path):
    preview = tmp_path / "views" / "preview.png"
    result = invoke("calibrate", *pair, "--model", onnx_model, "--preview", preview)
    assert result.exit_code == 0, result.output
    image = cv2.imread(str(preview))
    assert preview.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and image is not None and image.shape[0] > 0


def test_left_and_right_of_different_sizes(pair, onnx_model, tmp_path):
    right = write_rgb(tmp_path / "right.png", cv2.resize(rgb(pair[1]), (400, 300)))
    result = invoke("calibrate", pair[0], right, "--model", onnx_model, "--json")
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    assert (report["left"]["width"], report["left"]["height"]) == (320, 240)
    assert (report["right"]["width"], report["right"]["height"]) == (400, 300)
    assert report["right"]["K"][0][2] == 200.0 and report["right"]["K"][1][2] == 150.0


# -------------------------------------------------------------------------------------------- no torch
def test_calibrate_does_not_import_torch(pair, onnx_model, tmp_path):
    """In a fresh interpreter (this test session may well have imported torch)."""
    code = f"""
import sys
from typer.testing import CliRunner
from stereogeo_cli.cli import app
runner = CliRunner()
result = runner.invoke(app, ["calibrate", {str(pair[0])!r}, {str(pair[1])!r}, "--model", {str(onnx_model)!r},
                             "-o", {str(tmp_path / "out")!r}, "--format", "opencv,ros,kalibr,colmap,json"])
assert result.exit_code == 0, result.output
folder = {str(tmp_path / "batch")!r}
import shutil, os
os.makedirs(folder + "/left"); os.makedirs(folder + "/right")
shutil.copy({str(pair[0])!r}, folder + "/left/a.png"); shutil.copy({str(pair[1])!r}, folder + "/right/a.png")
args = ["batch-calibrate", folder, "-o", folder + "-out", "--model", {str(onnx_model)!r}]
result = runner.invoke(app, args)
assert result.exit_code == 0, result.output
heavy = sorted(m for m in sys.modules if m.split(".")[0] in ("torch", "torchvision", "moderngl", "skimage"))
assert not heavy, heavy
print("no torch")
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "no torch"


def test_a_lens_is_fitted_where_the_matches_show_it_and_never_with_pinhole(
    example_pair, onnx_model, tmp_path
):
    """The example pair seen through a barrel lens (division model, k = -0.25 at f = 512 px): the default
    fits a barrel per camera and writes it; ``--pinhole`` writes none. The undistorted pair gets none. The
    report carries the lens the straight edges show."""
    from stereogeo_cli.geometry import intrinsic_matrix, rotation_error, undistort_division

    images = [rgb(p) for p in example_pair]
    h, w = images[0].shape[:2]
    grid = np.stack(np.meshgrid(np.arange(w), np.arange(h)), -1).reshape(-1, 2).astype(float)
    where = undistort_division(grid, intrinsic_matrix(512.0, w, h), -0.25).reshape(h, w, 2).astype(np.float32)
    seen = [write_rgb(tmp_path / f"{i}.png", cv2.remap(im, where[..., 0], where[..., 1], cv2.INTER_LINEAR))
            for i, im in enumerate(images)]  # fmt: skip
    truth = json.loads((ROOT / "examples" / "ground_truth.json").read_text())
    runs = {
        name: invoke("calibrate", *files, "--model", onnx_model, "--json", *flags)
        for name, files, flags in (
            ("lens", seen, []), ("lens_pinhole", seen, ["--pinhole"]), ("plain", example_pair, []),
        )
    }  # fmt: skip
    for name, run in runs.items():
        assert run.exit_code == 0, (name, run.output)
    reports = {name: json.loads(run.stdout) for name, run in runs.items()}
    from stereogeo_cli.network.runtime import FieldNetwork

    if FieldNetwork(onnx_model).metadata.get("model_version") == "untrained-test":
        pytest.skip("the untrained test network's focal lengths make the lens test meaningless")
    lens = reports["lens"]
    for side in ("left", "right"):
        assert len(lens[side]["dist"]) == 5 and lens[side]["dist"][0] < -0.03  # barrel, k1 k2 0 0 k3
        assert reports["lens_pinhole"][side]["dist"] == [] and reports["plain"][side]["dist"] == []
    assert lens["pose"]["distortion_k"][0] < 0 and lens["pose"]["sigma_distortion_k"][0] > 0
    assert reports["plain"]["pose"]["distortion_k"] == [0.0, 0.0]
    # the straight edges see the lens too (refine/plumb.py), and none in the plain pair
    assert all(k is not None and k < -0.03 for k in lens["pose"]["edge_distortion_k"])
    assert all(k is None or abs(k) < 0.03 for k in reports["plain"]["pose"]["edge_distortion_k"])
    errors = {
        name: np.degrees(rotation_error(np.array(r["R"]), np.array(truth["R"])))
        for name, r in reports.items()
    }
    assert errors["lens"] < errors["lens_pinhole"], errors
    # the lens reaches the files: OpenCV's D1 is the report's left dist
    written = invoke("calibrate", *seen, "--model", onnx_model, "-o", tmp_path / "out", "--format", "opencv")
    assert written.exit_code == 0, written.output
    fs = cv2.FileStorage(str(tmp_path / "out" / "intrinsics.yml"), cv2.FILE_STORAGE_READ)
    np.testing.assert_allclose(fs.getNode("D1").mat().ravel(), lens["left"]["dist"], rtol=1e-6)


def test_known_focal_lengths_are_never_held_equal(pair, onnx_model):
    """``pose.equal_focals`` is in the report; with the focal lengths given (here 5 % apart) the fusion has no
    ratio to hold, and each camera keeps its own."""
    result = invoke(
        "calibrate", *pair, "--model", onnx_model, "--json", "--focal-left", "300", "--focal-right", "315"
    )
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    assert report["pose"]["equal_focals"] is False
    assert report["left"]["focal_px"] == pytest.approx(300) and report["right"]["focal_px"] == pytest.approx(
        315
    )


def test_focal_sigma_makes_given_focal_lengths_priors(pair, onnx_model):
    """``--focal-sigma``: the given focal lengths are combined with the fields' reading (between the two,
    with a sigma under both), the report names them ``given``; bad values are one-line usage errors."""
    args = ("calibrate", *pair, "--model", onnx_model, "--json")
    args += ("--focal-left", "300", "--focal-right", "300")
    result = invoke(*args, "--focal-sigma", "0.05")
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    for side, prior in zip(("left", "right"), report["focal_prior"], strict=True):
        assert prior["source"] == "given" and prior["focal_px"] == 300.0
        low, high = sorted((prior["fields_focal_px"], 300.0))
        assert low < prior["combined_focal_px"] < high
        assert report[side]["sigma"]["focal_px"] < min(prior["sigma_px"], prior["fields_sigma_px"])
    for value in ("0", "1.5", "-0.1"):
        assert_error(invoke(*args, "--focal-sigma", value), 2, "--focal-sigma")
    assert_error(invoke("calibrate", *pair, "--model", onnx_model, "--focal-sigma", "0.1"), 2, "--focal-left")


def test_the_summary_names_where_each_focal_length_came_from(example_pair, onnx_model):
    """The human summary: a focal length combined with the vanishing points says so (not "given"), and one the
    user gave with a sigma says "given"."""
    left, right = example_pair
    result = invoke("calibrate", left, right, "--model", onnx_model)
    assert result.exit_code == 0, result.output
    lines = [line for line in result.stdout.splitlines() if " focal: " in line]
    assert len(lines) == 2 and all("with the vanishing points'" in line for line in lines), lines
    given = invoke(
        "calibrate", left, right, "--model", onnx_model, "--focal-left", 340, "--focal-sigma", 0.05
    )
    assert given.exit_code == 0, given.output
    assert any(line.startswith("left focal: given 340") for line in given.stdout.splitlines()), given.stdout
