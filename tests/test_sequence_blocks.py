"""The stretches of a sequence left out one at a time: the jackknife's sigma and the rectified rows of the
left-out frames, on synthetic rigs whose truth is exact."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stereogeo_cli.geometry import intrinsic_matrix, rotation_from_axis_angle
from stereogeo_cli.sequence.blocks import BlockFit, jackknife_sigma, row_errors, stretches, summarise


def test_the_jackknife_sigma_of_leave_one_out_means_is_the_standard_error_of_the_mean():
    rng = np.random.default_rng(3)
    data = rng.normal(0.0, 1.0, 40)
    leave_one_out = np.array([np.delete(data, i).mean() for i in range(len(data))])
    assert jackknife_sigma(leave_one_out) == pytest.approx(data.std(ddof=1) / math.sqrt(len(data)))
    assert jackknife_sigma(np.full(5, 2.0)) == 0.0


def test_stretches_cut_the_frames_in_time_order():
    names = [f"{i:06d}.png" for i in (4, 0, 3, 1, 2, 6, 5)]
    parts = stretches(names, 3)
    assert [len(p) for p in parts] == [3, 2, 2]
    assert sum(parts, []) == sorted(names)


def _rig(R: np.ndarray, T: np.ndarray, f: float = 500.0) -> BlockFit:
    K = intrinsic_matrix(f, 640, 480)
    return BlockFit((f, f), (K, K.copy()), (np.zeros(4), np.zeros(4)), R, T)


def _seen(R_true: np.ndarray, T_true: np.ndarray, f: float = 500.0, n: int = 400, seed: int = 0):
    """Points 3–20 m before the left camera, projected into both cameras of the true rig."""
    rng = np.random.default_rng(seed)
    X = np.column_stack([rng.uniform(-4, 4, n), rng.uniform(-3, 3, n), rng.uniform(3, 20, n)])
    K = intrinsic_matrix(f, 640, 480)

    def project(points):
        p = (K @ points.T).T
        return p[:, :2] / p[:, 2:]

    return project(X), project((R_true @ X.T).T + T_true)


def test_a_true_calibration_puts_the_left_out_rows_together_and_a_turned_one_does_not():
    R = rotation_from_axis_angle(np.radians([0.3, -0.5, 0.2]))
    T = np.array([-0.12, 0.001, 0.002])
    pairs = [_seen(R, T)]
    exact = row_errors(_rig(R, T), ((480, 640), (480, 640)), pairs)
    assert np.median(exact) < 1e-6
    tilted = R @ rotation_from_axis_angle(np.radians([0.2, 0.0, 0.0]))  # 0.2° about the rows' axis
    off = row_errors(_rig(tilted, T), ((480, 640), (480, 640)), pairs)
    assert np.median(off) == pytest.approx(500.0 * math.radians(0.2), rel=0.3)  # about 1.7 px


def test_summarise_reads_the_spread_of_the_fits():
    fits = [
        _rig(rotation_from_axis_angle(np.radians([0.0, 0.0, 0.1 * k])), np.array([-0.1, 0.0, 0.0]), 500.0 + k)
        for k in (-2, -1, 0, 1, 2)
    ]
    found = summarise(fits, np.array([0.1, 0.2, 0.3, 0.4]))
    logs = np.log([498.0, 499.0, 500.0, 501.0, 502.0])
    assert found.focal_sigma_rel == pytest.approx(math.sqrt(4 / 5 * np.sum((logs - logs.mean()) ** 2)))
    assert found.rotation_sigma_deg == pytest.approx(math.sqrt(4 / 5 * 0.1**2 * 10), rel=1e-3)
    assert found.direction_sigma_deg == pytest.approx(0.0, abs=1e-9)
    assert found.row_error_median_px == pytest.approx(0.25) and found.row_matches == 4
