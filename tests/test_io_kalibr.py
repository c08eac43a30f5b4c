"""Kalibr camchain.yaml, read with PyYAML."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import yaml

from stereogeo_cli.geometry import fold_k3
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
        # radtan has four terms: a k3 is folded into k1 k2 over the image
        assert cam["distortion_coeffs"] == (list(D[:4]) if D[4] == 0 else list(fold_k3(D, K)))
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


def test_folded_k3_is_named_in_a_comment():
    text = (GOLDEN / "camchain.yaml").read_text()
    assert "# k3 = 0.001 folded into k1 k2 over the image (radtan has four terms)" in text


def test_folding_k3_keeps_the_lens_over_the_image():
    """A strong barrel written with k1 k2 k3, folded to k1 k2: the corners move by half a pixel (4 px when
    k3 is dropped)."""
    import cv2

    from stereogeo_cli.geometry import intrinsic_matrix

    K = intrinsic_matrix(500.0, 640, 480)
    D = np.array([-0.3, 0.15, 0.001, -0.002, -0.05])
    rays = np.stack(np.meshgrid(np.linspace(-0.64, 0.64, 21), np.linspace(-0.48, 0.48, 15), [1.0]), -1)
    rays = rays.reshape(-1, 3)

    def seen(coefficients):
        return cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, coefficients)[0].reshape(-1, 2)

    folded = fold_k3(D, K)
    assert folded.shape == (4,) and folded[2:].tolist() == [0.001, -0.002]
    assert np.abs(seen(folded) - seen(D)).max() < 0.6
    assert np.abs(seen(D[:4]) - seen(D)).max() > 4.0
    np.testing.assert_array_equal(fold_k3(D[:4], K), D[:4])
