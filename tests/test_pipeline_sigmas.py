"""The model's photo_sigma_scale widens the sigmas calibrate reports and nothing else."""

import numpy as np
import pytest

from stereogeo_cli.io import load_image
from stereogeo_cli.pipeline import Calibrator


def test_the_photo_sigma_scale_widens_the_reported_sigmas_only(onnx_model, example_pair):
    left, right = (load_image(path) for path in example_pair)
    # the straight edges' spread and the camera bias widen the reported focal sigma too: not here
    conf = {"read_spread": 0.0, "camera_bias_sigma": 0.0}
    plain, photo = Calibrator(onnx_model, threads=1, conf=conf), Calibrator(onnx_model, threads=1, conf=conf)
    plain.photo_sigma_scale, photo.photo_sigma_scale = (1.0, 1.0, 1.0), (1.5, 1.2, 1.25)
    factors = {"roll_deg": 1.5, "pitch_deg": 1.2, "vfov_deg": 1.25, "focal_px": 1.25}
    a, b = plain.calibrate(left, right), photo.calibrate(left, right)
    for fa, fb in ((a.left, b.left), (a.right, b.right)):
        # the estimates and the sigmas they were made with are the same
        assert fb.focal_px == fa.focal_px and fb.roll_deg == fa.roll_deg and fb.pitch_deg == fa.pitch_deg
        assert fb.sigma == fa.sigma
    np.testing.assert_array_equal(a.calibration.R, b.calibration.R)
    np.testing.assert_array_equal(a.calibration.T, b.calibration.T)
    # what the files and report.json carry is widened
    for sa, sb in (
        (a.calibration.sigma_left, b.calibration.sigma_left),
        (a.calibration.sigma_right, b.calibration.sigma_right),
    ):
        assert sa == a.left.sigma or sa == a.right.sigma
        for key, factor in factors.items():
            assert sb[key] == pytest.approx(factor * sa[key], rel=1e-12), key
    assert b.report()["left"]["sigma"]["roll_deg"] == pytest.approx(1.5 * a.left.sigma["roll_deg"], rel=1e-12)
    # a focal length the user gave keeps its own sigma; the camera's gravity sigmas still widen
    a = plain.calibrate(left, right, focal_left=400.0)
    b = photo.calibrate(left, right, focal_left=400.0)
    assert b.calibration.sigma_left["focal_px"] == a.calibration.sigma_left["focal_px"]
    assert b.calibration.sigma_left["roll_deg"] == pytest.approx(1.5 * a.calibration.sigma_left["roll_deg"])
    assert b.calibration.sigma_right["vfov_deg"] == pytest.approx(
        1.25 * a.calibration.sigma_right["vfov_deg"]
    )


def test_a_focal_length_read_from_the_images_reports_the_networks_camera_bias(onnx_model, example_pair):
    """The network's error on one kind of camera is common to its photos: the reported focal sigma of a
    focal length the images gave holds it in quadrature; a given one does not. Without the straight edges'
    vanishing points no estimate moves (with them, the bias also weighs the fields against the edges:
    tests/test_manhattan.py)."""
    left, right = (load_image(path) for path in example_pair)
    conf = {"read_spread": 0.0, "manhattan": {"enabled": False}}
    without = Calibrator(onnx_model, threads=1, conf={**conf, "camera_bias_sigma": 0.0})
    with_bias = Calibrator(onnx_model, threads=1, conf={**conf, "camera_bias_sigma": 0.25})
    a, b = without.calibrate(left, right), with_bias.calibrate(left, right)
    np.testing.assert_array_equal(a.calibration.K_left, b.calibration.K_left)
    ca, cb = a.calibration, b.calibration
    for sa, sb, K in (
        (ca.sigma_left, cb.sigma_left, ca.K_left),
        (ca.sigma_right, cb.sigma_right, ca.K_right),
    ):
        focal = K[0, 0]
        assert sb["focal_px"] / focal == pytest.approx(np.hypot(sa["focal_px"] / focal, 0.25), rel=1e-9)
        assert sb["vfov_deg"] / sa["vfov_deg"] == pytest.approx(sb["focal_px"] / sa["focal_px"], rel=1e-9)
        assert sb["roll_deg"] == sa["roll_deg"]
    given_a = without.calibrate(left, right, focal_left=400.0)
    given_b = with_bias.calibrate(left, right, focal_left=400.0)
    assert given_b.calibration.sigma_left["focal_px"] == given_a.calibration.sigma_left["focal_px"]


def test_a_focal_length_the_fusion_moved_reports_half_the_move(onnx_model, example_pair):
    """Where the matches move a focal length away from the images' read (their focal ratio, or the two held
    equal), the reported focal sigma takes in half that move in log f, in quadrature; no estimate moves."""
    left, right = (load_image(path) for path in example_pair)
    conf = {"camera_bias_sigma": 0.0, "manhattan": {"enabled": False}}
    a = Calibrator(onnx_model, threads=1, conf={**conf, "read_spread": 0.0}).calibrate(left, right)
    b = Calibrator(onnx_model, threads=1, conf={**conf, "read_spread": 0.5}).calibrate(left, right)
    np.testing.assert_array_equal(a.calibration.K_left, b.calibration.K_left)
    np.testing.assert_array_equal(a.calibration.K_right, b.calibration.K_right)
    assert a.pose.focal_scale == b.pose.focal_scale and a.pose.focal_scale != (1.0, 1.0)
    for sa, sb, K, scale in (
        (a.calibration.sigma_left, b.calibration.sigma_left, a.calibration.K_left, a.pose.focal_scale[0]),
        (a.calibration.sigma_right, b.calibration.sigma_right, a.calibration.K_right, a.pose.focal_scale[1]),
    ):
        focal = K[0, 0]
        expected = np.hypot(sa["focal_px"] / focal, 0.5 * np.log(scale))
        assert sb["focal_px"] / focal == pytest.approx(expected, rel=1e-9)
        assert sb["roll_deg"] == sa["roll_deg"] and sb["pitch_deg"] == sa["pitch_deg"]
