"""The metric baseline from feature matches and a per-cell depth field (stereogeo_cli/fuse/scale.py)."""

import numpy as np
import pytest

from stereogeo_cli.fuse import Matches
from stereogeo_cli.fuse.scale import DepthField, baseline_from_depth, triangulate_unit
from stereogeo_cli.geometry import intrinsic_matrix, resize_crop_for_network, rotation_from_axis_angle

SIZE = (640, 480)
STRIDE = 8


def _plane_depth(points: np.ndarray, K: np.ndarray) -> np.ndarray:
    """z-depth [N] of the slanted plane z = 3 + 1.5·x/z (a wall turned away to the right) at pixels."""
    xn = (points[:, 0] - K[0, 2]) / K[0, 0]
    return 3.0 / (1.0 - 1.5 * xn * 0.5)


def _scene(rng, baseline=0.12, count=400, noise_px=0.3, far_share=0.0, rotation_deg=(0.5, -1.0, 0.3)):
    K = intrinsic_matrix(500.0, *SIZE)
    R = rotation_from_axis_angle(np.radians(rotation_deg))
    t = np.array([-1.0, 0.03, 0.02])
    T = baseline * t / np.linalg.norm(t)
    left = rng.uniform([20, 20], [SIZE[0] - 20, SIZE[1] - 20], size=(count, 2))
    z = _plane_depth(left, K)
    z[: int(far_share * count)] = 1e6  # sky and far hills: no parallax
    X = np.column_stack([left, np.ones(count)]) @ np.linalg.inv(K).T * z[:, None]
    Xr = X @ R.T + T
    right = Xr[:, :2] / Xr[:, 2:] * K[0, 0] + K[:2, 2] + rng.normal(0, noise_px, (count, 2))
    return K, R, T, Matches(left, right)


def _depth_field(K: np.ndarray, scale: float = 1.0) -> DepthField:
    """The depth head's output for the plane, exact at its cell centres (times ``scale``)."""
    rc = resize_crop_for_network(*SIZE, 224, 32)
    width, height = rc.out_size
    jj, ii = np.meshgrid(np.arange(width // STRIDE), np.arange(height // STRIDE))
    centres = np.stack([STRIDE * jj + (STRIDE - 1) / 2, STRIDE * ii + (STRIDE - 1) / 2], axis=-1)
    z = _plane_depth(rc.points_to_input(centres.reshape(-1, 2)), K).reshape(jj.shape) * scale
    focal_n = K[0, 0] * rc.scale / (min(width, height) / 2)
    return DepthField(np.log(z / focal_n), np.full(z.shape, np.log(0.2)), STRIDE, rc)


def test_triangulation_for_a_unit_baseline_is_the_depth_over_the_baseline():
    rng = np.random.default_rng(0)
    K, R, T, matches = _scene(rng, noise_px=0.0)
    z, angle, off = triangulate_unit(matches.left, matches.right, K, K, R, T)
    assert np.allclose(z * np.linalg.norm(T), _plane_depth(matches.left, K), rtol=1e-6)
    assert np.all(angle > 0) and np.max(off) < 1e-9


@pytest.mark.parametrize("baseline", [0.05, 0.12, 0.6])
def test_exact_depth_gives_the_baseline(baseline):
    rng = np.random.default_rng(1)
    K, R, T, matches = _scene(rng, baseline=baseline, far_share=0.3)
    found = baseline_from_depth(matches, _depth_field(K), K, K, R, T / baseline)
    assert found is not None and found.votes > 100
    # 0.3 px noise on 400 matches; the sampled field is bilinear between cell centres of a curved depth
    assert found.baseline_m == pytest.approx(baseline, rel=0.02)


def test_the_baseline_follows_the_depth_and_not_the_focal_length():
    rng = np.random.default_rng(2)
    # no rotation: a wrong focal length would also misplace the rotation's share of each displacement, which
    # the fusion estimates with that focal length (here R stays the true one)
    K, R, T, matches = _scene(rng, rotation_deg=(0.0, 0.0, 0.0))
    t = T / np.linalg.norm(T)
    exact = baseline_from_depth(matches, _depth_field(K), K, K, R, t).baseline_m
    deeper = baseline_from_depth(matches, _depth_field(K, scale=1.25), K, K, R, t).baseline_m
    assert deeper / exact == pytest.approx(1.25, rel=1e-3)
    # a focal length 10 % off (both cameras, as the fields would give it) moves the baseline far less
    K_off = intrinsic_matrix(550.0, *SIZE)
    off = baseline_from_depth(matches, _depth_field(K), K_off, K_off, R, t).baseline_m
    assert abs(off / exact - 1) < 0.03


def test_no_estimate_without_parallax_or_matches():
    rng = np.random.default_rng(3)
    K, R, T, matches = _scene(rng, far_share=1.0)  # everything at infinity
    t = T / np.linalg.norm(T)
    assert baseline_from_depth(matches, _depth_field(K), K, K, R, t) is None
    few = Matches(matches.left[:5], matches.right[:5])
    assert baseline_from_depth(few, _depth_field(K), K, K, R, t) is None
