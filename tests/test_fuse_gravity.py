"""Gravity shared by both cameras (fuse/gravity.py): each camera's gravity updated with the other's."""

import math

import numpy as np
import pytest

from stereogeo_cli.fuse import share_gravity
from stereogeo_cli.geometry import gravity_angle, rotation_from_axis_angle
from stereogeo_cli.geometry.gravity import (
    gravity_from_roll_pitch,
    retract_on_sphere,
    roll_pitch_from_gravity,
    tangent_basis,
)
from stereogeo_cli.refine import CameraFit


def _fit(gravity, cov2, cross=(0.0, 0.0)):
    """A CameraFit (f = 500 px, 5 % sigma) with this gravity and a covariance of θ = (δ_pitch, δ_roll·cos p,
    log f); ``cross`` is the covariance of log f with the two gravity coordinates."""
    cov = np.zeros((3, 3))
    cov[:2, :2] = cov2
    cov[2, 2] = 0.05**2
    cov[2, :2] = cov[:2, 2] = cross
    fit = CameraFit(width=640, height=480, focal_px=500.0, gravity_up=np.array([0.0, -1.0, 0.0]),
                    covariance=cov, cost=0.0, iterations=0, converged=True)  # fmt: skip
    return fit.with_gravity(gravity, cov)


def _rig(rng):
    R = rotation_from_axis_angle(rng.normal(0, 0.05, 3))
    g_left = gravity_from_roll_pitch(rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5))
    return R, g_left, R @ g_left


def test_two_equally_sure_cameras_meet_halfway_and_agree_with_r():
    rng = np.random.default_rng(0)
    R, g_left, g_right = _rig(rng)
    sigma = math.radians(2.0)
    noisy_left = retract_on_sphere(g_left, [0.03, -0.02])
    noisy_right = retract_on_sphere(g_right, [-0.01, 0.02])
    cov = np.diag([sigma**2, sigma**2])
    left, right = share_gravity(_fit(noisy_left, cov), _fit(noisy_right, cov), R, 0.0, 0.0)
    # the midpoint of the two estimates, on the sphere
    mid = noisy_left + R.T @ noisy_right
    assert gravity_angle(left.gravity_up, mid / np.linalg.norm(mid)) < 1e-4
    assert gravity_angle(R @ left.gravity_up, right.gravity_up) < 1e-4  # R·g_left = g_right
    # independent and equally sure: the variance halves; roll and pitch sigmas follow the covariance
    assert left.sigma["pitch_deg"] == pytest.approx(math.degrees(sigma) / math.sqrt(2), rel=1e-3)
    roll, pitch = roll_pitch_from_gravity(left.gravity_up)
    assert left.roll_deg == pytest.approx(math.degrees(roll)) and left.pitch_deg == pytest.approx(
        math.degrees(pitch)
    )


def test_the_surer_camera_weighs_more_and_the_result_stays_between_the_two():
    rng = np.random.default_rng(1)
    R, g_left, g_right = _rig(rng)
    noisy_left = retract_on_sphere(g_left, [0.05, 0.0])
    sure, unsure = np.diag([1e-4, 1e-4]), np.diag([16e-4, 16e-4])  # 0.57° and 2.3°
    left, right = share_gravity(_fit(noisy_left, unsure), _fit(g_right, sure), R, 0.0, 0.7)
    moved = gravity_angle(left.gravity_up, noisy_left)
    total = gravity_angle(noisy_left, g_left)
    # inverse-variance weights, ρ or not (to first order: the tangent planes differ by 3°)
    assert moved == pytest.approx(total * 16 / 17, rel=1e-2)
    assert gravity_angle(right.gravity_up, g_right) == pytest.approx(total / 17, rel=1e-2)
    assert left.focal_px == 500.0 and right.focal_px == 500.0  # the focal lengths stay


def test_correlated_cameras_shrink_the_reported_variance_by_one_plus_rho_over_two():
    g = gravity_from_roll_pitch(0.2, -0.3)
    cov = np.diag([4e-4, 9e-4])
    cross = np.array([2e-4, -1e-4])  # log f's covariance with pitch and roll
    for rho in (0.0, 0.5, 0.7):
        left, _ = share_gravity(_fit(g, cov, cross), _fit(g, cov, cross), np.eye(3), 0.0, rho)
        np.testing.assert_allclose(left.covariance[:2, :2], cov * (1 + rho) / 2, rtol=1e-9, atol=1e-12)
        # the focal's own variance stays; its covariance with the averaged gravity shrinks alike
        assert left.covariance[2, 2] == 0.05**2
        np.testing.assert_allclose(left.covariance[2, :2], cross * (1 + rho) / 2, rtol=1e-9)


def test_shared_gravity_is_what_monte_carlo_says_with_anisotropic_errors_and_an_uncertain_r():
    """Independent anisotropic errors on both cameras and on R: the update lowers the mean squared error to
    what its covariance predicts, and 68 % of the errors fall within the reported 1-sigma ellipse."""
    rng = np.random.default_rng(3)
    R_true, g_left, g_right = _rig(rng)
    cov_left = np.array([[9e-4, 3e-4], [3e-4, 2e-4]])
    cov_right = np.array([[1e-4, 0.0], [0.0, 6e-4]])
    sigma_R = math.radians(0.5)
    before, after, inside = [], [], []
    for _ in range(2000):
        est_left = retract_on_sphere(g_left, rng.multivariate_normal([0, 0], cov_left))
        est_right = retract_on_sphere(g_right, rng.multivariate_normal([0, 0], cov_right))
        R = rotation_from_axis_angle(rng.normal(0, sigma_R, 3)) @ R_true
        left, _ = share_gravity(_fit(est_left, cov_left), _fit(est_right, cov_right), R, sigma_R, 0.0)
        B = tangent_basis(left.gravity_up)
        error = B.T @ (g_left - left.gravity_up)
        before.append(gravity_angle(est_left, g_left) ** 2)
        after.append(float(error @ error))
        inside.append(float(error @ np.linalg.solve(left.covariance[:2, :2], error)) <= 2.2789)  # χ²₂ at 68 %
    predicted = np.trace(left.covariance[:2, :2])
    assert np.mean(after) < 0.5 * np.mean(before)
    assert np.mean(after) == pytest.approx(predicted, rel=0.15)
    assert 0.62 < np.mean(inside) < 0.74


def test_nothing_to_weigh_by_leaves_the_fits_alone():
    rng = np.random.default_rng(4)
    R, g_left, g_right = _rig(rng)
    a, b = _fit(retract_on_sphere(g_left, [0.02, 0.0]), np.eye(2) * 1e-4), _fit(g_right, np.eye(2) * 1e-4)
    assert share_gravity(a, b, R, math.inf, 0.7) == (a, b)
    c = _fit(g_right, np.full((2, 2), np.inf))
    assert share_gravity(a, c, R, 0.01, 0.7) == (a, c)
    with pytest.raises(ValueError):
        share_gravity(a, b, R, 0.01, 1.0)


def test_calibrate_gives_gravities_that_agree_with_its_rotation(example_pair, onnx_model):
    from stereogeo_cli.io import load_image
    from stereogeo_cli.pipeline import Calibrator

    images = [load_image(path) for path in example_pair]
    coupling = {}
    for share in (False, True):
        result = Calibrator(onnx_model, conf={"share_gravity": share}).calibrate(*images)
        c = result.calibration
        coupling[share] = math.degrees(gravity_angle(c.R @ result.left.gravity_up, result.right.gravity_up))
    assert coupling[True] < 0.3 * coupling[False] + 0.05


def test_fields_only_is_what_calibrate_starts_from(example_pair, onnx_model):
    """Calibrator.fields_only (the network alone) gives the cameras calibrate starts from: without sharing,
    vertical lines and vanishing points, calibrate keeps their gravity and only rescales their focal lengths
    by the matches' ratio."""
    from stereogeo_cli.io import load_image
    from stereogeo_cli.pipeline import Calibrator

    images = [load_image(path) for path in example_pair]
    conf = {"share_gravity": False, "lines": {"enabled": False}, "manhattan": {"enabled": False}}
    calibrator = Calibrator(onnx_model, conf=conf)
    result = calibrator.calibrate(*images)
    for own, calibrated, scale in zip(calibrator.fields_only(*images), (result.left, result.right),
                                      result.pose.focal_scale, strict=True):  # fmt: skip
        np.testing.assert_allclose(own.gravity_up, calibrated.gravity_up, atol=1e-12)
        assert calibrated.focal_px == pytest.approx(own.focal_px * scale, rel=1e-9)
