"""The model's photo_sigma_scale widens the sigmas calibrate reports and nothing else."""

import numpy as np
import pytest

from stereogeo_cli.io import load_image
from stereogeo_cli.pipeline import Calibrator


def test_the_photo_sigma_scale_widens_the_reported_sigmas_only(onnx_model, example_pair):
    left, right = (load_image(path) for path in example_pair)
    plain, photo = Calibrator(onnx_model, threads=1), Calibrator(onnx_model, threads=1)
    plain._photo_sigma_scale, photo._photo_sigma_scale = (1.0, 1.0, 1.0), (1.5, 1.2, 1.25)
    a, b = plain.calibrate(left, right), photo.calibrate(left, right)
    for fa, fb in ((a.left, b.left), (a.right, b.right)):
        # the estimates are the same: the scale is applied after every sigma has been used
        assert fb.focal_px == fa.focal_px and fb.roll_deg == fa.roll_deg and fb.pitch_deg == fa.pitch_deg
        assert fb.sigma["roll_deg"] == pytest.approx(1.5 * fa.sigma["roll_deg"], rel=1e-12)
        assert fb.sigma["pitch_deg"] == pytest.approx(1.2 * fa.sigma["pitch_deg"], rel=1e-12)
        assert fb.sigma["vfov_deg"] == pytest.approx(1.25 * fa.sigma["vfov_deg"], rel=1e-12)
        assert fb.sigma["focal_px"] == pytest.approx(1.25 * fa.sigma["focal_px"], rel=1e-12)
    np.testing.assert_array_equal(a.calibration.R, b.calibration.R)
    np.testing.assert_array_equal(a.calibration.T, b.calibration.T)
    # what the files and report.json carry
    assert b.calibration.sigma_left["roll_deg"] == pytest.approx(1.5 * a.calibration.sigma_left["roll_deg"])
    # a focal length the user gave keeps its own sigma; its camera's gravity sigmas still widen
    a = plain.calibrate(left, right, focal_left=400.0)
    b = photo.calibrate(left, right, focal_left=400.0)
    assert b.left.sigma["focal_px"] == a.left.sigma["focal_px"]
    assert b.left.sigma["roll_deg"] == pytest.approx(1.5 * a.left.sigma["roll_deg"], rel=1e-12)
    assert b.right.sigma["vfov_deg"] == pytest.approx(1.25 * a.right.sigma["vfov_deg"], rel=1e-12)
