"""The focal length from a Manhattan frame of line segments (stereogeo_cli/refine/manhattan.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stereogeo_cli.geometry import gravity_from_roll_pitch
from stereogeo_cli.io.images import load_image
from stereogeo_cli.pipeline import Calibrator
from stereogeo_cli.pipeline import default_conf as pipeline_conf
from stereogeo_cli.refine.manhattan import default_conf, manhattan_focal, stable_manhattan_focal
from stereogeo_cli.refine.plumb import PlumbLens
from stereogeo_cli.rig.evidence import PairEvidence

WIDTH, HEIGHT, FOCAL = 640, 480, 500.0


@pytest.fixture(scope="module")
def bundled(example_pair) -> tuple[np.ndarray, np.ndarray]:
    """The bundled pair's images (a rendered room: straight edges along a Manhattan frame)."""
    return tuple(load_image(path) for path in example_pair)


def _frame(gravity: np.ndarray, yaw_deg: float) -> np.ndarray:
    """Three orthogonal world directions in camera coordinates: two horizontal ones, ``yaw_deg`` from the
    camera's horizontal forward direction, and up."""
    up = gravity / np.linalg.norm(gravity)
    forward = np.array([0.0, 0.0, 1.0]) - up[2] * up
    forward /= np.linalg.norm(forward)
    side = np.cross(up, forward)
    yaw = math.radians(yaw_deg)
    a = math.cos(yaw) * forward + math.sin(yaw) * side
    return np.stack([a, np.cross(up, a), up])


def _segments(directions, focal=FOCAL, count=300, noise_px=0.3, clutter=0.2, seed=0) -> np.ndarray:
    """Projected 3-D segments along ``directions`` (and a share of random ones), endpoints with noise."""
    rng = np.random.default_rng(seed)
    K = np.array([[focal, 0, WIDTH / 2], [0, focal, HEIGHT / 2], [0, 0, 1.0]])
    out = []
    while len(out) < count:
        start = rng.uniform([-4, -3, 3], [4, 3, 12])
        if rng.random() < clutter:
            along = rng.normal(size=3)
            along /= np.linalg.norm(along)
        else:
            along = directions[rng.integers(3)]
        end = start + along * rng.uniform(0.5, 2.5)
        if end[2] < 0.5:
            continue
        p = (K @ np.stack([start, end]).T).T
        p = p[:, :2] / p[:, 2:]
        inside = np.all((p >= 0) & (p <= [WIDTH - 1, HEIGHT - 1]))
        if inside and np.linalg.norm(p[1] - p[0]) > 0.05 * math.hypot(WIDTH, HEIGHT):
            out.append((p + rng.normal(0, noise_px, p.shape)).ravel())
    return np.array(out)


def test_an_oblique_view_of_a_manhattan_scene_gives_the_focal_length():
    gravity = gravity_from_roll_pitch(math.radians(4.0), math.radians(-12.0))
    segments = _segments(_frame(gravity, 35.0))
    # started 30 % off, with a gravity 2° off: the fit finds both
    tilted = gravity_from_roll_pitch(math.radians(5.5), math.radians(-10.5))
    found = manhattan_focal(segments, (WIDTH, HEIGHT), tilted, 1.3 * FOCAL)
    assert found is not None
    assert found.focal_px == pytest.approx(FOCAL, rel=0.02)
    assert found.sigma_rel >= default_conf["sigma_floor"]
    assert min(found.families) > 20  # every direction is seen


def test_a_camera_square_to_the_walls_learns_nothing_of_the_focal_length():
    # level and looking along one of the frame's directions: one vanishing point at the centre, two at
    # infinity, whatever f is
    gravity = gravity_from_roll_pitch(0.0, 0.0)
    segments = _segments(_frame(gravity, 0.0), noise_px=0.3, clutter=0.0)
    found = manhattan_focal(segments, (WIDTH, HEIGHT), gravity, FOCAL)
    assert found is None or found.sigma_rel > 1.0


def test_too_few_segments_give_nothing():
    gravity = gravity_from_roll_pitch(0.0, math.radians(-10.0))
    segments = _segments(_frame(gravity, 30.0), count=5)
    assert manhattan_focal(segments, (WIDTH, HEIGHT), gravity, FOCAL) is None
    assert manhattan_focal(np.zeros((0, 4)), (WIDTH, HEIGHT), gravity, FOCAL) is None


def test_a_frame_the_coarser_edges_move_is_read_with_the_move_in_its_sigma():
    """The frame fitted to the edges found at a coarser resolution: where it lands where the fine one does,
    the read keeps its own sigma; where it lands elsewhere (the fine frame was not the scene's), the read's
    sigma takes in the distance; where it finds no frame, there is no read."""
    gravity = gravity_from_roll_pitch(math.radians(2.0), math.radians(-8.0))
    frame = _frame(gravity, 30.0)
    fine = _segments(frame)
    alone = manhattan_focal(fine, (WIDTH, HEIGHT), gravity, FOCAL)
    same = stable_manhattan_focal(fine, _segments(frame, seed=1), (WIDTH, HEIGHT), gravity, FOCAL)
    assert same.focal_px == alone.focal_px and same.families == alone.families
    assert same.sigma_rel == pytest.approx(alone.sigma_rel, rel=0.05)
    elsewhere = _segments(frame, focal=1.4 * FOCAL, seed=2)
    moved = stable_manhattan_focal(fine, elsewhere, (WIDTH, HEIGHT), gravity, FOCAL)
    assert moved.focal_px == alone.focal_px
    assert moved.sigma_rel == pytest.approx(math.hypot(alone.sigma_rel, math.log(1.4)), rel=0.05)
    assert stable_manhattan_focal(fine, fine[:5], (WIDTH, HEIGHT), gravity, FOCAL) is None


def test_the_fields_are_weighed_against_the_edges_with_the_camera_bias(bundled):
    """The fields' read can be off by a camera's bias that the edges do not share: with camera_bias_sigma
    the combination lies nearer the edges' read than without it; the two reads are the same either way."""
    left, right = bundled
    reports = [
        Calibrator(threads=2, conf={"camera_bias_sigma": bias}).calibrate(left, right).report()
        for bias in (0.0, pipeline_conf["camera_bias_sigma"])
    ]
    for side in (0, 1):
        plain, weighed = (report["focal_prior"][side] for report in reports)
        for read in ("focal_px", "fields_focal_px"):  # the two reads are the same either way
            assert plain[read] == weighed[read]
        apart = [abs(math.log(entry["combined_focal_px"] / entry["focal_px"])) for entry in (plain, weighed)]
        assert apart[1] < 0.9 * apart[0]


def test_calibrate_combines_the_fields_focal_length_with_the_edges_one(bundled):
    """On the bundled pair each camera's fields' focal length is combined with its edges' (the report says
    so, with both reads); a focal length given by the user is not, and with the step off neither is."""
    left, right = bundled
    calibrator = Calibrator(threads=2)
    report = calibrator.calibrate(left, right).report()
    for entry in report["focal_prior"]:
        assert entry["source"] == "lines"
        reads = sorted((entry["fields_focal_px"], entry["focal_px"]))
        assert reads[0] <= entry["combined_focal_px"] <= reads[1]
        assert entry["sigma_px"] > 0 and sum(entry["segments"]) > 0
    given = calibrator.calibrate(left, right, focal_left=340.0).report()
    assert given["focal_prior"][0] is None and given["focal_prior"][1]["source"] == "lines"
    off = Calibrator(threads=2, conf={"manhattan": {"enabled": False}}).calibrate(left, right).report()
    assert off["focal_prior"] == [None, None]
    assert "manhattan" not in off["timing_ms"]


def test_calibrate_leaves_the_edges_out_where_they_show_a_lens(bundled, monkeypatch):
    """Edges bent by a lens move their vanishing points: where the image's straight edges read a lens well
    away from none, the fields' focal length stays as it is (and where they are consistent with none, the
    edges are used)."""
    left, right = bundled
    calibrator = Calibrator(threads=2)
    for kappa, used in ((-2e-6, False), (-1e-8, True)):
        lens = PlumbLens(kappa=kappa, sigma_kappa=1e-7, corner_radius_px=400.0, chains=12)
        monkeypatch.setattr(Calibrator, "_edge_lens", lambda self, segments, fit, lens=lens: lens)
        result = calibrator.calibrate(left, right)
        assert list(result.pose.distortion) == [0.0, 0.0]  # the matches show no lens either way
        for entry in result.report()["focal_prior"]:
            assert (entry is not None and entry["source"] == "lines") == used


def test_the_reported_focal_sigma_takes_in_how_far_the_two_reads_are_apart(bundled):
    """The estimate does not change; the reported focal sigma is the photo-widened combined one and half the
    fields' and edges' distance in log f (and half the matches' move of the focal length), in quadrature."""
    left, right = bundled
    without = Calibrator(threads=2, conf={"read_spread": 0.0}).calibrate(left, right)
    spread = Calibrator(threads=2).calibrate(left, right)
    assert spread.left.focal_px == without.left.focal_px and spread.left.sigma == without.left.sigma
    for side in ("left", "right"):
        entry = spread.report()["focal_prior"][0 if side == "left" else 1]
        moved = spread.pose.focal_scale[0 if side == "left" else 1]
        apart = 0.5 * math.hypot(math.log(entry["focal_px"] / entry["fields_focal_px"]), math.log(moved))
        plain = getattr(without.calibration, f"sigma_{side}")
        widened = getattr(spread.calibration, f"sigma_{side}")
        f = getattr(spread.calibration, f"K_{side}")[0, 0]
        assert widened["focal_px"] / f == pytest.approx(math.hypot(plain["focal_px"] / f, apart), rel=1e-9)
        assert widened["vfov_deg"] / plain["vfov_deg"] == pytest.approx(
            widened["focal_px"] / plain["focal_px"]
        )


def test_same_rig_counts_an_edge_combined_focal_length_as_the_pairs_own_evidence(bundled):
    """batch-calibrate --same-rig: a focal length combined with the vanishing points is the pair's evidence
    (its calibrated value and sigma), not a prior shared by every pair, as an EXIF tag is."""
    left, right = bundled
    result = Calibrator(threads=2).calibrate(left, right)
    assert all(entry["source"] == "lines" for entry in result.report()["focal_prior"])
    evidence = PairEvidence.from_result(result)
    assert [c.focal_prior for c in evidence.cameras] == [None, None]
    assert [c.focal_px for c in evidence.cameras] == [result.left.focal_px, result.right.focal_px]
    fits = result.left, result.right
    assert [c.sigma["focal_px"] for c in evidence.cameras] == [f.sigma["focal_px"] for f in fits]
