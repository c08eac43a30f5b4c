"""ROS camera_info left.yaml / right.yaml, read with PyYAML as camera_calibration_parsers reads them."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import yaml

from stereogeo_cli.io import StereoCalibration, write_calibration
from stereogeo_cli.io.calibration import rectify

GOLDEN = Path(__file__).parent / "golden"
KEYS = [
    "image_width",
    "image_height",
    "camera_name",
    "camera_matrix",
    "distortion_model",
    "distortion_coefficients",
    "rectification_matrix",
    "projection_matrix",
]


def _matrix(node: dict) -> np.ndarray:
    assert set(node) == {"rows", "cols", "data"}
    return np.array(node["data"], dtype=np.float64).reshape(node["rows"], node["cols"])


def test_camera_info_matches_the_calibration(tmp_path):
    calib = StereoCalibration.from_report(json.loads((GOLDEN / "report.json").read_text()))
    write_calibration(tmp_path, calib, formats=("ros",))
    rect = rectify(calib)
    sides = {
        "left": (calib.image_size_left, calib.K_left, calib.dist_left, rect.R1, rect.P1),
        "right": (calib.image_size_right, calib.K_right, calib.dist_right, rect.R2, rect.P2),
    }
    for side, (size, K, D, R, P) in sides.items():
        info = yaml.safe_load((tmp_path / f"{side}.yaml").read_text())
        assert list(info) == KEYS
        assert (info["image_width"], info["image_height"]) == size
        assert info["camera_name"] == side
        assert info["distortion_model"] == "plumb_bob"
        np.testing.assert_array_equal(_matrix(info["camera_matrix"]), K)
        np.testing.assert_array_equal(_matrix(info["distortion_coefficients"]), D.reshape(1, 5))
        np.testing.assert_array_equal(_matrix(info["rectification_matrix"]), R)
        np.testing.assert_array_equal(_matrix(info["projection_matrix"]), P)


def test_right_projection_carries_the_baseline():
    right = yaml.safe_load((GOLDEN / "right.yaml").read_text())
    left = yaml.safe_load((GOLDEN / "left.yaml").read_text())
    P2, P1 = _matrix(right["projection_matrix"]), _matrix(left["projection_matrix"])
    baseline = np.linalg.norm(json.loads((GOLDEN / "report.json").read_text())["T"])
    np.testing.assert_allclose(P2[0, 3], -P2[0, 0] * baseline, rtol=1e-12)
    assert P1[0, 3] == 0.0 and P2[1, 3] == 0.0


def test_eight_coefficients_use_the_rational_model(tmp_path):
    calib = StereoCalibration.from_report(json.loads((GOLDEN / "report.json").read_text()))
    calib = dataclasses.replace(calib, D_left=[0.01, -0.02, 0.0, 0.0, 0.003, 0.001, 0.0, 0.0])
    write_calibration(tmp_path, calib, formats=("ros",))
    info = yaml.safe_load((tmp_path / "left.yaml").read_text())
    assert info["distortion_model"] == "rational_polynomial"
    np.testing.assert_array_equal(_matrix(info["distortion_coefficients"]), calib.D_left.reshape(1, 8))


def test_small_numbers_stay_floats_for_pyyaml(tmp_path):
    calib = StereoCalibration.from_report(json.loads((GOLDEN / "report.json").read_text()))
    calib = dataclasses.replace(calib, D_left=[1e-5, -2e-7, 0.0, 0.0, 1e-20])
    write_calibration(tmp_path, calib, formats=("ros",))
    text = (tmp_path / "left.yaml").read_text()
    assert "1.0e-05" in text and "1.0e-20" in text
    info = yaml.safe_load(text)
    assert info["distortion_coefficients"]["data"] == [1e-5, -2e-7, 0.0, 0.0, 1e-20]
