"""``report.html`` as a reader meets it, read without a browser: every figure of its kind of calibration
there, every picture embedded and decodable, nothing fetched from anywhere, and every number the one
report.json holds. (tests/test_report_browser.py looks at it in a browser.)"""

from __future__ import annotations

import base64
import io
import json
import re
import shutil
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from stereogeo_cli.cli import app

ROOT = Path(__file__).resolve().parents[1]
PAIR_FIGURES = ["result", "gravity-fields", "rectified", "row-errors", "coverage", "focal-evidence"]
DATA_URI = re.compile(r"data:image/(png|jpeg);base64,([A-Za-z0-9+/=]+)")


class Page(HTMLParser):
    """What a report page holds: its figures (in order), images, numbers (``data-key`` spans with their
    shown text), captions, and anything that would reach outside the file."""

    def __init__(self, text: str):
        super().__init__()
        self.figures: list[str] = []
        self.images: list[dict] = []  # the <img> attributes, with the figure each is in
        self.numbers: list[dict] = []  # data-key, data-value, text
        self.captions: dict[str, str] = {}
        self.outside: list[str] = []  # scripts, links, remote sources
        self._open: list[str] = []  # the tags open now
        self._number: dict | None = None
        self._caption: str | None = None
        self.feed(text)
        self.close()

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag in ("script", "link", "iframe", "object", "embed"):
            self.outside.append(tag)
        for name in ("src", "href"):
            if attrs.get(name) and not attrs[name].startswith(("data:", "#")):
                self.outside.append(f"{tag} {name}={attrs[name][:60]}")
        if tag == "figure":
            self.figures.append(attrs["data-figure"])
        if tag == "img":
            self.images.append({**attrs, "figure": self.figures[-1] if self.figures else None})
        if tag == "span" and "data-key" in attrs:
            self._number = {"key": attrs["data-key"], "value": attrs["data-value"], "text": ""}
        if tag == "figcaption":
            self._caption = ""
        if tag not in ("img", "meta", "br"):
            self._open.append(tag)

    def handle_endtag(self, tag):
        if tag == "span" and self._number is not None:
            self.numbers.append(self._number)
            self._number = None
        if tag == "figcaption" and self._caption is not None:
            self.captions[self.figures[-1]] = self._caption
            self._caption = None
        if self._open and self._open[-1] == tag:
            self._open.pop()

    def handle_data(self, data):
        if self._number is not None:
            self._number["text"] += data
        if self._caption is not None:
            self._caption += data


def invoke(*args):
    result = CliRunner().invoke(app, [str(a) for a in args])
    assert result.exit_code == 0, result.output
    return result


def lookup(report: dict, key: str):
    value = report
    for part in key.split("."):
        value = value[int(part)] if isinstance(value, list) else value[part]
    return value


def assert_a_whole_page(folder: Path) -> Page:
    """The report of ``folder``: one file that needs nothing else, every image decodes at its stated
    size, every figure has its sentence, and every number is report.json's."""
    text = (folder / "report.html").read_text(encoding="utf-8")
    assert text.startswith("<!DOCTYPE html>") and text.rstrip().endswith("</html>")
    page = Page(text)
    assert page.outside == [], page.outside
    assert "http://" not in text and "https://" not in text
    assert page.figures and page.figures[0] == "result" and len(set(page.figures)) == len(page.figures)
    for image in page.images:
        found = DATA_URI.fullmatch(image["src"])
        assert found, image["src"][:40]
        picture = Image.open(io.BytesIO(base64.b64decode(found.group(2))))
        picture.load()  # decodes the whole image, not just its header
        assert picture.format.lower() == found.group(1)
        assert picture.size == (int(image["width"]), int(image["height"])), image["alt"]
        assert min(picture.size) >= 8 and image["alt"]
        assert np.asarray(picture.convert("L")).std() > 2, f"{image['alt']} is blank"
    for name in page.figures:
        caption = page.captions.get(name, "").strip()
        assert caption.endswith(".") and len(caption) > 40, (name, caption)
        if name not in ("result", "frame-counts"):
            assert any(i["figure"] == name for i in page.images), f"{name} has no picture"
    assert_numbers_are_the_reports(page, json.loads((folder / "report.json").read_text()))
    return page


def assert_numbers_are_the_reports(page: Page, report: dict) -> None:
    """Every number shown is report.json's value at its key, and shows it to its decimals."""
    assert len(page.numbers) > 20
    for number in page.numbers:
        value = lookup(report, number["key"])
        assert json.loads(number["value"]) == value, number
        shown = number["text"].replace("−", "-")
        if value is None:
            assert shown == "–", number
        elif isinstance(value, int | float) and not isinstance(value, bool):
            decimals = len(shown.split(".")[1]) if "." in shown else 0
            scale = 100.0 if number["key"].endswith("baseline_rel") else 1.0  # shown in per cent
            assert abs(float(shown) - value * scale) <= 0.5 * 10.0**-decimals + 1e-9, number


@pytest.fixture(scope="module")
def pair_folder(example_pair, onnx_model, tmp_path_factory) -> Path:
    """``stereogeo calibrate`` of the example pair with ``-o``: every default file."""
    out = tmp_path_factory.mktemp("report") / "out"
    invoke("calibrate", *example_pair, "--model", onnx_model, "-o", out)
    return out


def test_a_pair_s_report_shows_every_figure_of_a_pair(pair_folder):
    page = assert_a_whole_page(pair_folder)
    assert page.figures == PAIR_FIGURES
    # per camera: the image with its horizon, the up-vectors, the latitude and the two confidences
    assert sum(i["figure"] == "gravity-fields" for i in page.images) >= 10
    assert sum(i["figure"] == "coverage" for i in page.images) == 2


def test_the_table_holds_the_numbers_a_user_looks_for(pair_folder):
    page = Page((pair_folder / "report.html").read_text(encoding="utf-8"))
    keys = {n["key"] for n in page.numbers}
    for side in ("left", "right"):
        for key in ("focal_px", "vfov_deg", "roll_deg", "pitch_deg", "K.0.2", "K.1.2"):
            assert f"{side}.{key}" in keys
        for key in ("focal_px", "vfov_deg", "roll_deg", "pitch_deg"):
            assert f"{side}.sigma.{key}" in keys
    assert {"pose.rotation_deg", "pose.sigma_rotation_deg", "T.0", "T.1", "T.2", "baseline_m"} <= keys
    assert {"pose.sigma_direction_deg", "matches.found", "matches.inliers"} <= keys


def test_the_row_errors_are_those_of_the_written_calibration(pair_folder):
    """The histogram's median and 95th percentile, measured on the matches with the files' rectification,
    are small on the example pair, whose rig the calibration gets right."""
    text = (pair_folder / "report.html").read_text(encoding="utf-8")
    median = float(re.search(r'data-median-px="([0-9.e-]+)"', text).group(1))
    p95 = float(re.search(r'data-p95-px="([0-9.e-]+)"', text).group(1))
    assert 0 <= median < 0.5 and median <= p95 < 3.0


def test_format_leaves_the_report_out_or_writes_it_alone(example_pair, onnx_model, tmp_path):
    invoke("calibrate", *example_pair, "--model", onnx_model, "-o", tmp_path / "a", "--format", "opencv,json")
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == [
        "extrinsics.yml",
        "intrinsics.yml",
        "report.json",
    ]
    invoke("calibrate", *example_pair, "--model", onnx_model, "-o", tmp_path / "b", "--format", "html")
    assert [p.name for p in (tmp_path / "b").iterdir()] == ["report.html"]
    page = Page((tmp_path / "b" / "report.html").read_text(encoding="utf-8"))
    assert page.figures == PAIR_FIGURES


def test_calibrate_without_an_output_folder_loads_no_plotting(example_pair, onnx_model, tmp_path):
    """``calibrate`` without ``-o`` pays nothing for the report: neither matplotlib nor the report's code
    is imported (with ``-o`` both are)."""
    code = (
        "import sys\nfrom stereogeo_cli.__main__ import run\nsys.argv = ['stereogeo', *sys.argv[1:]]\n"
        "try:\n    run()\nexcept SystemExit:\n    pass\n"
        "print('loaded:', 'matplotlib' in sys.modules, 'stereogeo_cli.report' in sys.modules,\n"
        "      file=sys.stderr)"
    )
    pair = [str(p) for p in example_pair]
    for extra, loaded in (([], "False False"), (["-o", str(tmp_path / "out")], "True True")):
        done = subprocess.run(
            [sys.executable, "-c", code, "calibrate", *pair, "--model", str(onnx_model), *extra],
            capture_output=True, text=True, timeout=300,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr
        assert f"loaded: {loaded}" in done.stderr, done.stderr


def test_images_read_turned_show_no_fields(example_pair, onnx_model, tmp_path):
    """``--rotate``: the network read turned images, whose fields are not those of the images as given:
    each image is shown with its calibrated horizon alone."""
    invoke("calibrate", *example_pair, "--model", onnx_model, "-o", tmp_path, "--rotate", "180", "--format",
           "json,html")  # fmt: skip
    page = assert_a_whole_page(tmp_path)
    assert "gravity-fields" in page.figures
    assert sum(i["figure"] == "gravity-fields" for i in page.images) == 2


def test_a_calibration_alone_gives_its_tables():
    """``write_calibration`` of a :class:`StereoCalibration` with nothing else: the result's tables, every
    number its report's, and no figure that would need data it has not."""
    from stereogeo_cli.io.calibration import StereoCalibration
    from stereogeo_cli.io.writers import render_calibration

    report = json.loads((ROOT / "tests" / "golden" / "report.json").read_text())
    calibration = StereoCalibration.from_report(report)
    page = Page(render_calibration(calibration, ("html",))["report.html"])
    assert page.figures == ["result"] and page.outside == []
    assert_numbers_are_the_reports(page, calibration.to_report())


def test_without_matplotlib_the_report_is_a_clear_error(monkeypatch):
    from stereogeo_cli.errors import StereoGeoError
    from stereogeo_cli.report import report_html

    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib raises ImportError
    report = json.loads((ROOT / "tests" / "golden" / "report.json").read_text())
    with pytest.raises(StereoGeoError, match="matplotlib") as error:
        report_html(report)
    assert error.value.exit_code == 2 and "\n" not in str(error.value)


# ------------------------------------------------------------------------------------ the figures' pieces
def test_a_level_camera_s_horizon_runs_through_its_centre_row():
    from stereogeo_cli.geometry import gravity_from_roll_pitch, intrinsic_matrix
    from stereogeo_cli.report.pictures import horizon_points

    K = intrinsic_matrix(500.0, 640, 480)
    level = horizon_points(K, np.array([0.0, -1.0, 0.0]), (640, 480))
    np.testing.assert_allclose(level[:, 1], 240.0)
    up = horizon_points(K, gravity_from_roll_pitch(0.0, np.radians(10.0)), (640, 480))
    np.testing.assert_allclose(up[:, 1], 240.0 + 500.0 * np.tan(np.radians(10.0)))  # looking up: lower
    assert len(horizon_points(K, gravity_from_roll_pitch(0.0, np.radians(80.0)), (640, 480))) == 0


def test_matches_of_a_rectified_rig_have_no_row_errors():
    from stereogeo_cli.geometry import intrinsic_matrix
    from stereogeo_cli.io.calibration import StereoCalibration
    from stereogeo_cli.report.measures import row_errors

    K = intrinsic_matrix(400.0, 640, 480)
    rig = StereoCalibration(K, K, (640, 480), (640, 480), np.eye(3), np.array([-0.1, 0.0, 0.0]))
    rng = np.random.default_rng(0)
    left = rng.uniform([0, 0], [640, 480], (50, 2))
    right = left - [20.0, 0.0]
    np.testing.assert_allclose(row_errors(rig, left, right), 0.0, atol=1e-9)
    np.testing.assert_allclose(row_errors(rig, left, right + [0.0, 1.5]), 1.5, atol=1e-6)


def test_coverage_counts_the_matches_per_cell():
    from stereogeo_cli.report.pictures import coverage

    counts = coverage(np.array([[0.0, 0.0], [639.0, 479.0], [639.4, 479.4], [320.0, 10.0]]), (640, 480))
    assert counts.shape == (6, 8) and counts.sum() == 4
    assert counts[0, 0] == 1 and counts[5, 7] == 2 and counts[0, 4] == 1


def test_a_number_carries_its_key_and_exact_value():
    from stereogeo_cli.report.tables import number, with_sigma

    report = {"left": {"focal_px": 612.345678, "roll_deg": -1.25, "sigma": {"focal_px": 0.0}}, "x": None}
    page = Page(
        number(report, "left.focal_px", 1) + with_sigma(report, "left.focal_px", "left.sigma.focal_px")
    )
    assert page.numbers[0] == {"key": "left.focal_px", "value": "612.345678", "text": "612.3"}
    assert len(page.numbers) == 2  # a held focal length shows no sigma
    assert Page(number(report, "left.roll_deg")).numbers[0]["text"] == "−1.25"
    assert Page(number(report, "x")).numbers[0]["text"] == "–"
    assert number(report, "not.there") == "–"


# ---------------------------------------------------------------------------------- sequences and rigs
@pytest.mark.slow
def test_a_sequence_s_report_shows_its_track_frames_and_blocks(shared_data, tmp_path):
    """``calibrate-sequence`` on 12 real frame pairs (EuRoC): the trajectory, each frame's attitude and
    reprojection error, the focal length per left-out stretch and the frame counts."""
    source = shared_data / "real-dev" / "sequences" / "euroc_mh01_excitation_stereo"
    out = tmp_path / "out"
    done = CliRunner().invoke(app, ["calibrate-sequence", str(source), "--max-frames", "12", "-o", str(out),
                                    "--no-progress"])  # fmt: skip
    assert done.exit_code == 0, done.output
    assert "report.html" in {p.name for p in out.iterdir()}
    page = assert_a_whole_page(out)
    report = json.loads((out / "report.json").read_text())
    expected = ["result", "focal-evidence", "trajectory", "frames"]
    expected += ["blocks"] if report["sequence"]["left_out"] else []
    assert page.figures == [*expected, "frame-counts"]
    keys = {n["key"] for n in page.numbers}
    assert {"sequence.frames_read", "sequence.frames_registered", "sequence.reprojection_error_px"} <= keys


@pytest.mark.slow
def test_a_rig_s_report_sets_each_pair_against_the_joint_calibration(shared_data, tmp_path):
    """``batch-calibrate --same-rig`` on three real pairs of one rig (EuRoC): each pair's folder has a pair's
    report, and rig/ one that sets each pair's focal lengths and R against the joint ones."""
    source = shared_data / "real-dev" / "euroc"
    records = [json.loads(line) for line in (source / "calib.jsonl").read_text().splitlines()][:3]
    folder = tmp_path / "pairs"
    for side in ("left", "right"):
        (folder / side).mkdir(parents=True)
        for record in records:
            shutil.copy(source / side / f"{record['id']}.png", folder / side)
    out = tmp_path / "out"
    invoke("batch-calibrate", folder, "-o", out, "--same-rig")
    rig = assert_a_whole_page(out / "rig")
    assert rig.figures == ["result", "same-rig"]
    for record in records:
        pair = assert_a_whole_page(out / record["id"])
        assert pair.figures == PAIR_FIGURES
