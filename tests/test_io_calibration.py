"""StereoCalibration: the JSON report, its round trip, validation."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from stereogeo_cli.errors import EXIT_BAD_INPUT, EXIT_CALIBRATION_FAILED, StereoGeoError
from stereogeo_cli.io import StereoCalibration

GOLDEN = Path(__file__).parent / "golden"
CAMERA_KEYS = {"width", "height", "K", "focal_px", "vfov_deg", "roll_deg", "pitch_deg", "gravity_up", "sigma"}
SIGMA_KEYS = {"focal_px", "vfov_deg", "roll_deg", "pitch_deg"}
TOP_KEYS = {"left", "right", "R", "T", "baseline_m", "scale_source", "matches", "timing_ms", "model"}


def golden_report() -> dict:
    return json.loads((GOLDEN / "report.json").read_text())


def test_report_has_the_design_keys():
    report = golden_report()
    assert TOP_KEYS <= set(report)
    for side in ("left", "right"):
        assert CAMERA_KEYS <= set(report[side])
        assert set(report[side]["sigma"]) == SIGMA_KEYS
    assert set(report["matches"]) == {"found", "inliers"}
    assert "total" in report["timing_ms"]
    assert set(report["model"]) == {"file", "sha256"}
    assert report["scale_source"] in ("learned", "baseline")


def test_report_values():
    report = golden_report()
    left = report["left"]
    assert left["focal_px"] == 500.0
    assert left["vfov_deg"] == pytest.approx(math.degrees(2 * math.atan(240 / 500)), abs=1e-12)
    assert left["roll_deg"] == pytest.approx(2.0, abs=1e-12)
    assert left["pitch_deg"] == pytest.approx(-5.0, abs=1e-12)
    assert report["baseline_m"] == pytest.approx(np.linalg.norm(report["T"]), rel=1e-15)


def test_report_round_trip_is_exact():
    report = golden_report()
    assert StereoCalibration.from_report(report).to_report() == report


def test_minimal_report_round_trip():
    calib = StereoCalibration(
        K_left=np.diag([400.0, 400.0, 1.0]) + np.array([[0, 0, 160], [0, 0, 120], [0, 0, 0]]),
        K_right=np.diag([400.0, 400.0, 1.0]) + np.array([[0, 0, 160], [0, 0, 120], [0, 0, 0]]),
        image_size_left=(320, 240),
        image_size_right=(320, 240),
        R=np.eye(3),
        T=[-0.1, 0.0, 0.0],
    )
    report = json.loads(json.dumps(calib.to_report()))
    assert report["left"]["roll_deg"] is None and report["left"]["gravity_up"] is None
    assert report["left"]["sigma"] == dict.fromkeys(SIGMA_KEYS)
    assert report["timing_ms"] == {"total": None}
    assert StereoCalibration.from_report(report).to_report() == report


def test_non_finite_sigma_is_null():
    calib = StereoCalibration.from_report(golden_report())
    sigma = {"focal_px": float("inf"), "vfov_deg": float("nan"), "roll_deg": 0.1}
    calib = dataclasses.replace(calib, sigma_left=sigma)
    sigma = calib.to_report()["left"]["sigma"]
    assert sigma == {"focal_px": None, "vfov_deg": None, "roll_deg": 0.1, "pitch_deg": None}


def test_malformed_report_is_a_user_error():
    report = golden_report()
    del report["left"]["K"]
    with pytest.raises(StereoGeoError, match="invalid calibration report") as err:
        StereoCalibration.from_report(report)
    assert err.value.exit_code == EXIT_BAD_INPUT


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("R", np.diag([1.0, 1.0, -1.0]), "not a rotation"),
        ("T", np.zeros(3), "must not be zero"),
        ("K_left", np.eye(4), "shape"),
        ("D_left", np.zeros(6), "0, 4, 5 or 8"),
        ("scale_source", "guess", "scale_source"),
    ],
)
def test_invalid_calibrations_are_refused(field, value, message):
    report = golden_report()
    calib = StereoCalibration.from_report(report)
    required = ("K_left", "K_right", "image_size_left", "image_size_right", "R", "T")
    kwargs = {k: getattr(calib, k) for k in required}
    kwargs[field] = value
    with pytest.raises(ValueError, match=message):
        StereoCalibration(**kwargs)


def test_non_finite_calibration_failed():
    report = golden_report()
    report["T"][0] = float("nan")
    with pytest.raises(StereoGeoError) as err:
        StereoCalibration.from_report(report)
    assert err.value.exit_code == EXIT_CALIBRATION_FAILED


def test_frozen_and_checked_again_on_replace():
    calib = StereoCalibration.from_report(golden_report())
    with pytest.raises(dataclasses.FrozenInstanceError):
        calib.T = np.array([1.0, 0.0, 0.0])  # type: ignore[misc]
    with pytest.raises(ValueError, match="must not be zero"):
        dataclasses.replace(calib, T=[0.0, 0.0, 0.0])
    assert dataclasses.replace(calib, D_left=[0.1, 0.0, 0.0, 0.0]).dist_left.tolist() == [0.1, 0, 0, 0, 0]
