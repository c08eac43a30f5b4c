import numpy as np
import pytest
from synthetic_fields import noisy_fields, random_camera

from stereogeo_cli.geometry import (
    focal_from_vfov,
    gravity_angle,
    gravity_from_roll_pitch,
    latitude_at,
    latitude_field,
    up_at,
    up_field,
)
from stereogeo_cli.refine import refine_camera
from stereogeo_cli.refine.lm import _Problem


def angle_diff(a, b):
    return abs((a - b + 180) % 360 - 180)


@pytest.mark.parametrize("init", ["fields", "level"])
def test_exact_fields_are_recovered(init):
    rng = np.random.default_rng(10)
    for size in [(320, 240), (240, 320), (256, 256), (384, 216), (200, 200)]:
        for _ in range(6):
            width, height, f, g, roll, pitch, vfov = random_camera(rng, size)
            fit = refine_camera(
                up_field(g, f, width, height), latitude_field(g, f, width, height), conf={"init": init}
            )
            assert angle_diff(fit.roll_deg, roll) < 1e-4
            assert angle_diff(fit.pitch_deg, pitch) < 1e-4
            assert abs(fit.focal_px / f - 1) < 1e-5
            assert abs(fit.vfov_deg - vfov) < 1e-4
            assert fit.converged and fit.iterations <= 30
            # costs only ever go down: rejected steps are not taken
            assert all(b <= a for a, b in zip(fit.history, fit.history[1:], strict=False))


def test_extremes_of_the_range_are_recovered():
    for vfov in (20.0, 105.0):
        for roll, pitch in [(45, 45), (-45, -45), (45, -45), (0, 0)]:
            height, width = 240, 320
            f = float(focal_from_vfov(np.radians(vfov), height))
            g = gravity_from_roll_pitch(np.radians(roll), np.radians(pitch))
            fit = refine_camera(up_field(g, f, width, height), latitude_field(g, f, width, height))
            assert angle_diff(fit.roll_deg, roll) < 1e-4 and angle_diff(fit.pitch_deg, pitch) < 1e-4
            assert abs(fit.focal_px / f - 1) < 1e-5


def _noisy_errors(seed, count, **noise):
    rng = np.random.default_rng(seed)
    errors, sigmas = [], []
    for _ in range(count):
        width, height, f, g, roll, pitch, vfov = random_camera(rng)
        up, lat, conf = noisy_fields(rng, width, height, f, g, **noise)
        fit = refine_camera(up, lat, conf, conf)
        errors.append(
            [angle_diff(fit.roll_deg, roll), angle_diff(fit.pitch_deg, pitch), abs(fit.vfov_deg - vfov)]
        )
        sigmas.append([fit.sigma["roll_deg"], fit.sigma["pitch_deg"], fit.sigma["vfov_deg"]])
    return np.array(errors), np.array(sigmas)


def test_noisy_fields_with_outliers_medians():
    """2° noise on up, 1° on latitude, 20 % of pixels random at confidence 0.5: the issue's bar."""
    errors, _ = _noisy_errors(11, 200)
    median = np.median(errors, axis=0)
    assert median[0] < 0.1 and median[1] < 0.1 and median[2] < 0.5, median


def test_sigma_is_honest():
    """With zero-mean noise, about 68 % of the errors fall within 1 sigma and 95 % within 2 sigma.

    (Random outliers drawn independently of the truth are not zero-mean for the latitude, which
    biases pitch by a few hundredths of a degree; no variance figure covers a bias, so that case
    is measured in the issue note rather than held here.)
    """
    errors, sigmas = _noisy_errors(21, 200, outliers=0.0)
    one, two = np.mean(errors <= sigmas, axis=0), np.mean(errors <= 2 * sigmas, axis=0)
    # 200 samples: a share of 68 % has a standard error of 3.3 %; allow about 4 standard errors
    assert np.all(one > 0.55) and np.all(one < 0.82), one
    assert np.all(two > 0.88), two


def test_sub_sampling_keeps_the_fit():
    """The sub-sampled fit explains the full fields as well as the full fit (to 0.5 % of the cost)."""
    rng = np.random.default_rng(12)
    for _ in range(5):
        width, height, f, g, *_ = random_camera(rng, (320, 240))
        up, lat, conf = noisy_fields(rng, width, height, f, g)
        fast = refine_camera(up, lat, conf, conf)
        full = refine_camera(up, lat, conf, conf, conf={"max_samples": None})
        xs, ys = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
        problem = _Problem(
            xs.ravel(), ys.ravel(), up.reshape(-1, 2), np.sin(lat.ravel()), conf.ravel(), conf.ravel(),
            width / 2, height / 2, 0.01, None, None,
        )  # fmt: skip
        cost_fast = problem.cost(fast.gravity_up, np.log(fast.focal_px))
        cost_full = problem.cost(full.gravity_up, np.log(full.focal_px))
        assert cost_full <= cost_fast <= cost_full * 1.005


def test_samples_taken_once_give_the_fit_taken_from_the_fields():
    """A camera fitted several times over (``samples`` from ``field_samples``) fits exactly as from its
    fields, with the network's float32 fields too (the samples are taken in float64 either way)."""
    from stereogeo_cli.refine.lm import default_conf, field_samples

    rng = np.random.default_rng(14)
    width, height, f, g, *_ = random_camera(rng, (320, 240))
    up, lat, conf = noisy_fields(rng, width, height, f, g)
    up, lat, conf = up.astype(np.float32), lat.astype(np.float32), conf.astype(np.float32)
    samples = field_samples(up, lat, conf, conf, None, default_conf)
    for focal_prior in (None, 1.1 * f):
        direct = refine_camera(up, lat, conf, conf, focal_prior=focal_prior)
        reused = refine_camera(up, lat, conf, conf, focal_prior=focal_prior, samples=samples)
        assert reused.focal_px == direct.focal_px
        assert np.array_equal(reused.gravity_up, direct.gravity_up)
        assert np.array_equal(reused.covariance, direct.covariance)


def test_confidence_zero_pixels_are_ignored():
    rng = np.random.default_rng(13)
    width, height, f, g, roll, pitch, vfov = random_camera(rng, (320, 240))
    up, lat = up_field(g, f, width, height), latitude_field(g, f, width, height)
    conf = np.ones((height, width))
    up[:, : width // 2] = [1.0, 0.0]  # garbage on the left half...
    lat[:, : width // 2] = 0.7
    conf[:, : width // 2] = 0.0  # ...that the network marks as unreliable
    fit = refine_camera(up, lat, conf, conf)
    assert angle_diff(fit.roll_deg, roll) < 1e-4 and abs(fit.focal_px / f - 1) < 1e-5


def test_known_focal_is_held_and_helps():
    rng = np.random.default_rng(14)
    width, height, f, g, roll, pitch, vfov = random_camera(rng, (320, 240))
    up, lat, conf = noisy_fields(rng, width, height, f, g, up_noise_deg=6, lat_noise_deg=4)
    fit = refine_camera(up, lat, conf, conf, focal_prior=f)
    assert fit.focal_px == pytest.approx(f, rel=1e-12)
    assert fit.sigma["focal_px"] == 0.0
    assert angle_diff(fit.roll_deg, roll) < 0.5 and angle_diff(fit.pitch_deg, pitch) < 0.5


def test_known_gravity_is_held():
    rng = np.random.default_rng(15)
    width, height, f, g, roll, pitch, vfov = random_camera(rng, (320, 240))
    up, lat, conf = noisy_fields(rng, width, height, f, g)
    fit = refine_camera(up, lat, conf, conf, gravity_prior=g)
    np.testing.assert_allclose(fit.gravity_up, g, atol=1e-12)
    assert fit.sigma["roll_deg"] == 0.0 and fit.sigma["pitch_deg"] == 0.0
    assert abs(fit.vfov_deg - vfov) < 0.5


def test_soft_priors_pull_towards_the_prior():
    rng = np.random.default_rng(16)
    width, height, f, g, *_ = random_camera(rng, (320, 240))
    up, lat, conf = noisy_fields(rng, width, height, f, g, up_noise_deg=10, lat_noise_deg=8)
    free = refine_camera(up, lat, conf, conf)
    wrong_f = f * 1.3
    pulled = refine_camera(up, lat, conf, conf, focal_prior=(wrong_f, 0.01 * wrong_f))
    assert abs(pulled.focal_px - wrong_f) < abs(free.focal_px - wrong_f)
    informed = refine_camera(up, lat, conf, conf, focal_prior=(f, 0.002 * f))
    assert informed.sigma["focal_px"] < free.sigma["focal_px"]
    g_prior = gravity_from_roll_pitch(0.3, 0.3)
    pulled_g = refine_camera(up, lat, conf, conf, gravity_prior=(g_prior, np.radians(0.1)))
    assert gravity_angle(pulled_g.gravity_up, g_prior) < gravity_angle(free.gravity_up, g_prior)


def test_strided_fields_with_pixel_coordinates():
    """Fields at a network's stride-4 cells, mapped to pixel centres, give the full-resolution camera."""
    rng = np.random.default_rng(17)
    width, height, f, g, roll, pitch, vfov = random_camera(rng, (320, 224))
    stride = 4
    ys, xs = np.mgrid[0 : height // stride, 0 : width // stride].astype(float)
    px, py = stride * xs + (stride - 1) / 2, stride * ys + (stride - 1) / 2
    cx, cy = width / 2, height / 2
    up, lat = up_at(g, f, px, py, cx, cy), latitude_at(g, f, px, py, cx, cy)
    fit = refine_camera(up, lat, image_size=(width, height), pixel_xy=(px, py))
    assert angle_diff(fit.roll_deg, roll) < 1e-4 and abs(fit.focal_px / f - 1) < 1e-5
    assert (fit.width, fit.height) == (width, height)


def test_no_usable_pixels_is_not_a_crash():
    up = np.zeros((60, 80, 2))
    lat = np.zeros((60, 80))
    fit = refine_camera(up, lat)
    assert not fit.converged
    assert np.isfinite(fit.focal_px)
    assert np.isinf(fit.sigma["focal_px"]) and np.isinf(fit.sigma["roll_deg"])


def test_shape_mismatch_is_an_error():
    with pytest.raises(ValueError, match="up field"):
        refine_camera(np.zeros((10, 12, 2)), np.zeros((10, 11)))


def test_sigma_inflation_per_parameter():
    """One factor widens every sigma; three widen roll, pitch and vFoV each by its own (as the model's
    metadata records them), keeping the estimate; bad metadata is an error."""
    from stereogeo_cli.refine import parse_sigma_inflation

    rng = np.random.default_rng(30)
    width, height, f, g, *_ = random_camera(rng, (320, 240))
    up, lat = up_field(g, f, width, height), latitude_field(g, f, width, height)
    up = up + rng.normal(0, 0.05, up.shape)
    fits = {s: refine_camera(up, lat, conf={"sigma_inflation": s}) for s in (1.0, 3.0, (2.0, 3.0, 4.0))}
    base = fits[1.0].sigma
    for key in ("roll_deg", "pitch_deg", "vfov_deg", "focal_px"):
        assert fits[3.0].sigma[key] == pytest.approx(3.0 * base[key], rel=1e-9)
    three = fits[(2.0, 3.0, 4.0)].sigma
    assert three["roll_deg"] == pytest.approx(2.0 * base["roll_deg"], rel=1e-9)
    assert three["pitch_deg"] == pytest.approx(3.0 * base["pitch_deg"], rel=1e-9)
    assert three["focal_px"] == pytest.approx(4.0 * base["focal_px"], rel=1e-9)
    assert three["vfov_deg"] == pytest.approx(4.0 * base["vfov_deg"], rel=1e-6)
    assert fits[(2.0, 3.0, 4.0)].focal_px == fits[1.0].focal_px
    assert parse_sigma_inflation("38") == 38.0
    assert parse_sigma_inflation("37.8,43.1,33.2") == (37.8, 43.1, 33.2)
    for bad in ("0", "-1", "1,2", "a", "nan", "1,2,3,4"):
        with pytest.raises(ValueError):
            parse_sigma_inflation(bad)


def test_a_fit_derives_its_angles_and_sigmas_from_focal_gravity_and_covariance():
    """Roll, pitch, vFoV and the sigmas are read off the fit's focal, gravity and covariance: a new focal
    sigma or a new gravity moves every figure that depends on it and leaves the others."""
    from stereogeo_cli.geometry import gravity_from_roll_pitch
    from stereogeo_cli.refine.lm import CameraFit

    cov = np.array([[4e-4, 1e-4, 2e-3], [1e-4, 9e-4, -1e-3], [2e-3, -1e-3, 0.01]])
    g = gravity_from_roll_pitch(np.radians(5.0), np.radians(-10.0))
    fit = CameraFit(640, 480, 500.0, g, cov, 0.0, 3, True)
    assert fit.roll_deg == pytest.approx(5.0) and fit.pitch_deg == pytest.approx(-10.0)
    assert fit.vfov_deg == pytest.approx(np.degrees(2 * np.arctan(240 / 500)))
    assert fit.sigma["focal_px"] == pytest.approx(500 * 0.1)
    assert fit.sigma["pitch_deg"] == pytest.approx(np.degrees(0.02))
    assert fit.sigma["roll_deg"] == pytest.approx(np.degrees(0.03) / np.cos(np.radians(10.0)))
    held = fit.with_focal_sigma(0.05)  # a focal length combined elsewhere: its own sigma, no cross terms
    assert held.sigma["focal_px"] == pytest.approx(25.0) and held.sigma["roll_deg"] == fit.sigma["roll_deg"]
    assert np.all(held.covariance[2, :2] == 0) and np.all(held.covariance[:2, 2] == 0)
    moved = held.with_new_gravity(gravity_from_roll_pitch(0.0, np.radians(3.0)), np.diag([1e-4, 4e-4]))
    assert moved.roll_deg == pytest.approx(0.0, abs=1e-9) and moved.pitch_deg == pytest.approx(3.0)
    assert moved.sigma["pitch_deg"] == pytest.approx(np.degrees(0.01))
    assert moved.sigma["focal_px"] == held.sigma["focal_px"] and moved.focal_px == 500.0
    wider = moved.with_focal(1000.0)  # the relative focal sigma stays, the vFoV and its sigma follow
    assert wider.sigma["focal_px"] == pytest.approx(50.0)
    assert wider.vfov_deg < moved.vfov_deg and wider.sigma["vfov_deg"] < moved.sigma["vfov_deg"]


def test_noisy_fields_reach_their_minimum_in_few_steps():
    """Most samples of real fields sit in the Huber loss's linear part: with its own curvature near the
    minimum the fit converges in a few steps and stops at the minimum itself (a fit started there stays)."""
    rng = np.random.default_rng(44)
    for _ in range(12):
        width, height, f, g, roll, pitch, vfov = random_camera(rng)
        up, lat, conf = noisy_fields(rng, width, height, f, g)
        fit = refine_camera(up, lat, conf, conf)
        assert fit.converged and fit.iterations <= 8
        again = refine_camera(
            up, lat, conf, conf, gravity_init=fit.gravity_up, focal_init=fit.focal_px,
            conf={"relative_tolerance": 0.0, "max_iterations": 10},
        )  # fmt: skip
        assert again.cost >= fit.cost * (1 - 1e-6)
        assert abs(again.focal_px / fit.focal_px - 1) < 1e-4
        assert gravity_angle(again.gravity_up, fit.gravity_up) < np.radians(0.005)
