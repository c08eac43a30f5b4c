"""The lens read from an image's straight edges (stereogeo_cli/refine/plumb.py)."""

import cv2
import numpy as np
import pytest

from stereogeo_cli.geometry import intrinsic_matrix, undistort_division
from stereogeo_cli.refine.lines import detect_segments
from stereogeo_cli.refine.plumb import default_conf, link_chains, plumb_line_distortion

SIZE = (640, 480)
FOCAL = 500.0


def _scene(rng, curves: bool = False, margin: int = 400) -> tuple[np.ndarray, int]:
    """A pinhole view of facades, each a grid of windows (rows and columns of them line up, so their edges
    are long straight lines cut into pieces), some turned; drawn on a canvas ``margin`` pixels wider on
    every side than the image; with ``curves`` discs and rings behind them."""
    w, h = SIZE[0] + 2 * margin, SIZE[1] + 2 * margin
    canvas = np.full((h, w), 90, np.uint8)
    if curves:  # behind the facades
        for _ in range(25):
            centre = (int(rng.uniform(0, w)), int(rng.uniform(0, h)))
            cv2.circle(canvas, centre, int(rng.uniform(40, 300)), int(rng.integers(20, 235)), -1, cv2.LINE_AA)
            cv2.circle(canvas, centre, int(rng.uniform(40, 300)), int(rng.integers(20, 235)), 6, cv2.LINE_AA)
    for _ in range(6):
        centre = np.array([rng.uniform(0.2, 0.8) * w, rng.uniform(0.2, 0.8) * h])
        size, gap = rng.uniform(25, 45, 2), rng.uniform(8, 14)
        turn = np.radians(0.0 if rng.random() < 0.6 else rng.uniform(-30, 30))
        axes = np.array([[np.cos(turn), np.sin(turn)], [-np.sin(turn), np.cos(turn)]])
        tone = int(rng.integers(20, 235))
        for i in range(-6, 7):
            for j in range(-5, 6):
                corner = np.array([i * (size[0] + gap), j * (size[1] + gap)])
                box = corner + np.array([[0, 0], [size[0], 0], [size[0], size[1]], [0, size[1]]])
                cv2.fillPoly(canvas, [np.round(centre + box @ axes).astype(np.int32)], tone, cv2.LINE_AA)
    return canvas, margin


def _through_lens(canvas: np.ndarray, margin: int, k: float) -> np.ndarray:
    """The pinhole canvas seen through a division-model lens k (normalised coordinates of FOCAL), as RGB."""
    K = intrinsic_matrix(FOCAL, *SIZE)
    grid = np.stack(np.meshgrid(np.arange(SIZE[0]), np.arange(SIZE[1])), -1).reshape(-1, 2).astype(float)
    where = (undistort_division(grid, K, k) + margin).reshape(SIZE[1], SIZE[0], 2).astype(np.float32)
    grey = cv2.remap(canvas, where[..., 0], where[..., 1], cv2.INTER_LINEAR)
    return cv2.cvtColor(grey, cv2.COLOR_GRAY2RGB)


def _estimate(image: np.ndarray, short_side: int = 256):
    scale = min(SIZE) / short_side
    centre = (SIZE[0] / 2, SIZE[1] / 2)
    return plumb_line_distortion(detect_segments(image, short_side), SIZE, centre, detector_scale=scale)


def _stretch(k: float) -> float:
    """A division k (normalised coordinates of FOCAL) as the stretch at the image's corner."""
    return k * (np.hypot(*SIZE) / 2 / FOCAL) ** 2


@pytest.mark.parametrize("k", [-0.3, -0.15])
def test_straight_edges_give_the_lens(k):
    """Boxes seen through a barrel lens: the estimate is within 0.03 of the true stretch at the corner (a
    few pixels there) on every scene, and the reported 1-sigma covers the error within 3 sigma; the
    k it gives for the camera's focal length is the lens's."""
    rng = np.random.default_rng(7)
    errors, z = [], []
    for _ in range(4):
        lens = _estimate(_through_lens(*_scene(rng), k))
        assert lens is not None and lens.chains >= default_conf["min_chains"]
        errors.append(lens.stretch - _stretch(k))
        z.append(errors[-1] / (lens.sigma_kappa * lens.corner_radius_px**2))
        k_fit, sigma_k = lens.division_k(FOCAL)
        assert k_fit == pytest.approx(lens.kappa * FOCAL**2) and sigma_k > 0
    assert np.max(np.abs(errors)) < 0.03, errors
    assert np.max(np.abs(z)) < 3.0, z


def test_a_pinhole_image_shows_no_lens():
    """Without a lens the estimate is 0 within 0.02 (or none is given), also with curved edges in view,
    which no distortion straightens (their misfit is clipped)."""
    rng = np.random.default_rng(8)
    for curves in (False, True, True):
        lens = _estimate(_through_lens(*_scene(rng, curves=curves), 0.0))
        assert lens is None or abs(lens.stretch) < 0.02, lens


def test_curved_edges_do_not_outvote_straight_ones():
    rng = np.random.default_rng(9)
    lens = _estimate(_through_lens(*_scene(rng, curves=True), -0.25))
    assert lens is not None and abs(lens.stretch - _stretch(-0.25)) < 0.03


def test_too_few_edges_give_no_estimate():
    """A blank image, or edges too short to show any bending: None, so the fusion goes by the matches."""
    blank = np.full((SIZE[1], SIZE[0], 3), 128, np.uint8)
    assert _estimate(blank) is None
    dots = blank.copy()
    for x in range(40, 600, 60):
        for y in range(40, 440, 60):
            cv2.rectangle(dots, (x, y), (x + 12, y + 12), (20, 20, 20), -1)
    assert _estimate(dots) is None


def test_pieces_of_one_edge_are_linked_and_parallel_neighbours_are_not():
    """Three collinear pieces with small gaps form one chain; a parallel edge 20 px away, and a piece at
    30° to the chain's end, stay out of it."""
    segments = np.array([
        [100, 200, 200, 200], [205, 200.5, 300, 201], [304, 201.2, 400, 202],  # one edge, slightly bent
        [100, 220, 200, 220],  # parallel, 20 px below
        [402, 202, 480, 247],  # 30° off the chain's end
    ], dtype=float)  # fmt: skip
    chains = link_chains(segments, float(np.hypot(*SIZE)), default_conf)
    assert [sorted(c.tolist()) for c in chains] == [[0, 1, 2]]
