"""Kalibr camchain.yaml, read with PyYAML."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import yaml

from stereogeo_cli.io import StereoCalibration, write_calibration

GOLDEN = Path(__file__).parent / "golden"


def test_camchain_matches_the_calibration(tmp_path):
    calib = StereoCalibration.from_report(json.loads((GOLDEN / "report.json").read_text()))
    write_calibration(tmp_path, calib, formats=("kalibr",))
    chain = yaml.safe_load((tmp_path / "camchain.yaml").read_text())
    assert list(chain) == ["cam0", "cam1"]
    cams = [
        (chain["cam0"], calib.K_left, calib.dist_left, calib.image_size_left, 1),
        (chain["cam1"], calib.K_right, calib.dist_right, calib.image_size_right, 0),
    ]
    for cam, K, D, size, overlap in cams:
        assert cam["camera_model"] == "pinhole"
        assert cam["distortion_model"] == "radtan"
        assert cam["intrinsics"] == [K[0, 0], K[1, 1], K[0, 2], K[1, 2]]
        assert cam["distortion_coeffs"] == list(D[:4])
        assert cam["resolution"] == list(size)
        assert cam["cam_overlaps"] == [overlap]
        assert cam["rostopic"].startswith("/cam")
    assert "T_cn_cnm1" not in chain["cam0"]
    T = np.array(chain["cam1"]["T_cn_cnm1"])
    np.testing.assert_array_equal(T[:3, :3], calib.R)
    np.testing.assert_array_equal(T[:3, 3], calib.T)
    np.testing.assert_array_equal(T[3], [0, 0, 0, 1])
    # X_cam1 = T_cn_cnm1 @ X_cam0, the same as X_right = R @ X_left + T
    X = np.array([0.3, -0.2, 4.0])
    np.testing.assert_allclose((T @ np.append(X, 1.0))[:3], calib.R @ X + calib.T)


def test_dropped_coefficients_are_named_in_a_comment():
    text = (GOLDEN / "camchain.yaml").read_text()
    assert "# radtan keeps k1 k2 p1 p2; dropped: [0.001]" in text
