"""The Python front door: the same calibration as the CLI, and a swapped pair gives the mirrored rig."""

import json
import os
import sys
import threading
import time

import numpy as np
import pytest
from typer.testing import CliRunner

import stereogeo_cli
import stereogeo_cli.pipeline as pipeline
from stereogeo_cli.cli import app
from stereogeo_cli.geometry import gravity_angle, rotation_angle


def test_api_result_equals_the_cli_report(example_pair, onnx_model):
    result = stereogeo_cli.calibrate(*example_pair, model=onnx_model, threads=1)
    cli = CliRunner().invoke(
        app, ["calibrate", *map(str, example_pair), "--model", str(onnx_model), "--json"]
    )
    assert cli.exit_code == 0, cli.output
    report, api = json.loads(cli.stdout), result.report()
    for side in ("left", "right"):
        for key in ("focal_px", "roll_deg", "pitch_deg"):
            assert api[side][key] == pytest.approx(report[side][key], rel=1e-9, abs=1e-9)
    np.testing.assert_allclose(api["R"], report["R"], atol=1e-12)
    np.testing.assert_allclose(api["T"], report["T"], atol=1e-12)


def test_api_takes_arrays_and_rejects_bad_input(example_pair, onnx_model):
    images = [stereogeo_cli.load_image(p) for p in example_pair]
    calibrator = stereogeo_cli.Calibrator(onnx_model, threads=1)
    from_arrays = stereogeo_cli.calibrate(*images, calibrator=calibrator)
    from_files = stereogeo_cli.calibrate(*example_pair, calibrator=calibrator)  # no EXIF in these PNGs
    np.testing.assert_allclose(from_arrays.calibration.K_left, from_files.calibration.K_left)
    with pytest.raises(stereogeo_cli.StereoGeoError, match="baseline"):
        stereogeo_cli.calibrate(*images, baseline=-1.0, calibrator=calibrator)


def test_swapped_pair_gives_the_mirrored_rig(example_pair, onnx_model):
    calibrator = stereogeo_cli.Calibrator(onnx_model, threads=1)
    images = [stereogeo_cli.load_image(p) for p in example_pair]
    direct_result, swapped_result = calibrator.calibrate(*images), calibrator.calibrate(*images[::-1])
    direct, swapped = direct_result.calibration, swapped_result.calibration
    # a near scene: points in front of both cameras tell which way T points, and so the swap
    assert direct_result.report()["pose"]["sign_source"] == "matches"
    assert swapped_result.report()["pose"]["sign_source"] == "matches"
    # each camera's focal length within 1 %
    assert swapped.K_right[0, 0] == pytest.approx(direct.K_left[0, 0], rel=0.01)
    assert swapped.K_left[0, 0] == pytest.approx(direct.K_right[0, 0], rel=0.01)
    # the mirror of (R, T) is (Rᵀ, -Rᵀ T): R within 0.05°, |T| within 5 %
    assert np.degrees(rotation_angle(swapped.R @ direct.R)) < 0.05
    assert np.linalg.norm(swapped.T) == pytest.approx(np.linalg.norm(direct.T), rel=0.05)
    mirrored = -direct.R.T @ direct.T
    cos = mirrored @ swapped.T / (np.linalg.norm(mirrored) * np.linalg.norm(swapped.T))
    assert np.degrees(np.arccos(min(1.0, cos))) < 1.0
    # the swapped files put the right camera to the left of the left one: the user is warned
    assert swapped.T[0] > 0 and any("swapped" in note for note in swapped.notes.split("; "))
    assert not any("swapped" in note for note in direct.notes.split("; "))


def test_a_rig_mounted_upside_down_is_calibrated_with_rotate_180(example_pair, onnx_model):
    """The rig turned 180° about its view: the camera named left now sees what the right one saw, turned. The
    network knows views rolled by up to 45° and reads turned views as upright, so without ``rotate`` the
    gravity comes out reversed and nothing warns (in each camera's own frame the other still sits where it
    did). With ``rotate=180`` each camera gets the upright rig's reading, turned into its frame exactly."""
    calibrator = stereogeo_cli.Calibrator(onnx_model, threads=1)
    left, right = [stereogeo_cli.load_image(p) for p in example_pair]
    upright = calibrator.calibrate(left, right).calibration
    turned = [np.ascontiguousarray(image[::-1, ::-1]) for image in (right, left)]  # (named left, named right)
    turn = np.diag([-1.0, -1.0, 1.0])  # X_named_left = turn @ X_upright_right, and likewise for the other
    truth_up = (turn @ upright.gravity_right, turn @ upright.gravity_left)

    plain = calibrator.calibrate(*turned).calibration
    assert plain.T[0] < 0 and not plain.notes
    for got, up in zip((plain.gravity_left, plain.gravity_right), truth_up, strict=True):
        assert np.degrees(gravity_angle(got, up)) > 170.0

    # the same turned views named by where the cameras now sit: the right one left of the left (T_x > 0)
    by_place = calibrator.calibrate(*turned[::-1]).calibration
    assert any("swapped" in note and "--rotate 180" in note for note in by_place.notes.split("; "))

    rotated = calibrator.calibrate(*turned, rotate=180).calibration
    assert not rotated.notes
    assert rotated.K_left[0, 0] == pytest.approx(upright.K_right[0, 0], rel=1e-9)
    assert rotated.K_right[0, 0] == pytest.approx(upright.K_left[0, 0], rel=1e-9)
    for got, up in zip((rotated.gravity_left, rotated.gravity_right), truth_up, strict=True):
        assert np.degrees(gravity_angle(got, up)) < 1e-6
    assert np.degrees(rotation_angle(rotated.R.T @ (turn @ upright.R.T @ turn))) < 1e-6
    np.testing.assert_allclose(rotated.T, turn @ (-upright.R.T @ upright.T), atol=1e-9)
    assert rotated.to_report()["rotate_deg"] == 180
    assert rotated.to_report()["left"]["roll_deg"] == pytest.approx(
        upright.to_report()["right"]["roll_deg"] + 180.0, abs=1e-6
    )


def test_a_quarter_turn_swaps_the_image_sizes_and_turns_the_frames_back(example_pair, onnx_model):
    """Images turned a quarter counter-clockwise and read with ``rotate=90``: the network reads the upright
    pair, and the result is that pair's in the turned cameras' frames, sizes, K and vFoV sigma."""
    calibrator = stereogeo_cli.Calibrator(onnx_model, threads=1)
    images = [stereogeo_cli.load_image(p) for p in example_pair]
    upright = calibrator.calibrate(*images)
    got = calibrator.calibrate(*[np.ascontiguousarray(np.rot90(i)) for i in images], rotate=90)
    back = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # X_given = back @ X_upright
    c, u = got.calibration, upright.calibration
    assert c.image_size_left == (480, 640) and c.K_left[0, 2] == 240 and c.K_left[1, 2] == 320
    assert c.K_left[0, 0] == pytest.approx(u.K_left[0, 0], rel=1e-12)
    assert np.degrees(gravity_angle(c.gravity_left, back @ u.gravity_left)) < 1e-6
    assert np.degrees(rotation_angle(c.R.T @ (back @ u.R @ back.T))) < 1e-6
    np.testing.assert_allclose(c.T, back @ u.T, atol=1e-12)
    report = c.to_report()["left"]
    f, s = report["focal_px"], report["sigma"]["focal_px"]
    assert report["sigma"]["vfov_deg"] == pytest.approx(np.degrees(640 * f / (f * f + 640**2 / 4) * s / f))
    x, y = upright.matches.left.T  # upright pixel (x, y) is pixel (y, 639 - x) of the image turned back
    np.testing.assert_allclose(got.matches.left, np.column_stack([y, 639 - x]), atol=1e-9)


def test_rotate_takes_quarter_turns_only(example_pair, onnx_model):
    with pytest.raises(stereogeo_cli.StereoGeoError, match="rotate"):
        stereogeo_cli.calibrate(*example_pair, rotate=45, model=onnx_model)


def test_the_next_pairs_image_work_started_ahead_gives_the_same_calibration(example_pair, onnx_model):
    """``calibrate(..., upcoming=...)`` (how ``batch-calibrate`` runs its pairs) starts the next pair's
    features and line segments on the pool: that pair's calibration is the same bit for bit as without,
    and work started for a pair that is then not calibrated is dropped."""
    first = [stereogeo_cli.load_image(p) for p in example_pair]
    second = [
        np.ascontiguousarray(image[:, ::-1][:, :, ::-1]) for image in first[::-1]
    ]  # mirrored: another pair
    alone = stereogeo_cli.Calibrator(onnx_model, threads=1).calibrate(*second).report()

    calibrator = stereogeo_cli.Calibrator(onnx_model, threads=1)
    started = []
    start = calibrator._start_image_work
    calibrator._start_image_work = lambda *images: started.append(images) or start(*images)
    calibrator.calibrate(*first, upcoming=lambda: tuple(second))
    assert len(started) == 2 and started[1][0] is second[0]
    ahead = calibrator.calibrate(*second).report()
    assert len(started) == 2 and calibrator._ahead is None  # taken up, not started again
    for report in (alone, ahead):
        report.pop("timing_ms", None)
    assert ahead == alone

    calibrator.calibrate(*first, upcoming=lambda: tuple(second))
    assert calibrator._ahead is not None
    calibrator.calibrate(*first)  # not the pair started ahead: that work is dropped, this pair's started
    assert calibrator._ahead is None and len(started) == 5


def test_one_images_features_at_a_time_this_pairs_and_the_next(example_pair, onnx_model, monkeypatch):
    """SIFT's scale space is the largest allocation of a calibration (about 70 MB at 640 x 480): the two
    images' features, and the next pair's started ahead, are built one image at a time, so the peak memory
    is one image's."""
    running, most, calls, lock = [0], [0], [0], threading.Lock()
    detect = pipeline.detect_features

    def counted(*args, **kwargs):
        with lock:
            running[0] += 1
            calls[0] += 1
            most[0] = max(most[0], running[0])
        try:
            time.sleep(0.05)  # long enough that two pool threads would overlap
            return detect(*args, **kwargs)
        finally:
            with lock:
                running[0] -= 1

    monkeypatch.setattr(pipeline, "detect_features", counted)
    images = [stereogeo_cli.load_image(p) for p in example_pair]
    calibrator = stereogeo_cli.Calibrator(onnx_model, threads=1, first_pair=(images[0], images[1]))
    calibrator.calibrate(*images, upcoming=lambda: (images[1], images[0]))
    calibrator.calibrate(images[1], images[0])
    assert calls[0] >= 4 and most[0] == 1


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread nice values are Linux's")
def test_the_edges_yield_the_cores_and_nothing_else_does(example_pair, onnx_model, monkeypatch):
    """The vanishing points' edges, needed only after the fusion, run at a lower priority than the features
    the fusion waits for; the user's own thread (and so the rest of their program) keeps its priority."""
    nice = {}
    detect_edges, detect_sift = pipeline.detect_segments, pipeline.detect_features

    def own_nice():
        return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())

    def segments(image, short, *args, **kwargs):
        nice.setdefault(f"segments {short}", own_nice())
        return detect_edges(image, short, *args, **kwargs)

    def features(*args, **kwargs):
        nice.setdefault("features", own_nice())
        return detect_sift(*args, **kwargs)

    monkeypatch.setattr(pipeline, "detect_segments", segments)
    monkeypatch.setattr(pipeline, "detect_features", features)
    before = own_nice()
    images = [stereogeo_cli.load_image(p) for p in example_pair]
    stereogeo_cli.Calibrator(onnx_model, threads=1).calibrate(*images)
    # the edges are found at the image's resolution up to max_short_side, and again at stability_scale of it
    fine = min(pipeline.manhattan_conf["max_short_side"], *images[0].shape[:2])
    coarse = round(fine * pipeline.manhattan_conf["stability_scale"])
    edges = [nice[f"segments {side}"] for side in (fine, coarse)]
    lines = nice[f"segments {pipeline.lines_conf['max_short_side']}"]
    assert own_nice() == before and nice["features"] == before and lines == before
    for priority in edges:
        assert priority == min(before + 10, 19) > before or before == 19


def test_the_first_pairs_image_work_started_with_the_session_gives_the_same_calibration(
    example_pair, onnx_model
):
    """``Calibrator(first_pair=...)`` (how ``calibrate`` and the CLI start) starts the pair's features and
    line segments on the pool before the network's session opens: the same calibration bit for bit, and
    the work is taken up by the first ``calibrate`` of those arrays, not started again; a bad pair fails
    as ``calibrate`` would fail on it."""
    images = [stereogeo_cli.load_image(p) for p in example_pair]
    alone = stereogeo_cli.Calibrator(onnx_model, threads=1).calibrate(*images).report()
    early = stereogeo_cli.Calibrator(onnx_model, threads=1, first_pair=(images[0], images[1]))
    assert early._ahead is not None and early._ahead[0] is images[0]
    report = early.calibrate(*images).report()
    assert early._ahead is None
    for each in (alone, report):
        each.pop("timing_ms", None)
    assert report == alone
    with pytest.raises(stereogeo_cli.StereoGeoError, match="same image"):
        stereogeo_cli.Calibrator(onnx_model, threads=1, first_pair=(images[0], images[0]))
