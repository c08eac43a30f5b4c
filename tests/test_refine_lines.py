"""Vertical line segments in the refiner (stereogeo_cli/refine/lines.py)."""

import numpy as np
import pytest
from synthetic_fields import noisy_fields, random_camera

from stereogeo_cli.geometry import gravity_angle, gravity_from_roll_pitch, latitude_field, up_at
from stereogeo_cli.geometry.camera import principal_point
from stereogeo_cli.refine import refine_camera
from stereogeo_cli.refine.lines import (
    camera_sampler,
    detect_segments,
    field_sampler,
    gravity_with_lines,
    vertical_segments,
)


def true_vertical_segments(rng, width, height, focal, gravity, count=40, length=30.0):
    """Segments along the camera's true up field (images of vertical lines), plus as many at random angles."""
    cx, cy = principal_point(width, height)
    x, y = rng.uniform(20, width - 20, count), rng.uniform(20, height - 20, count)
    up = up_at(gravity, focal, x, y, cx, cy)
    half = 0.5 * length * up
    vertical = np.column_stack([x - half[:, 0], y - half[:, 1], x + half[:, 0], y + half[:, 1]])
    angle = rng.uniform(0, np.pi, count)
    x, y = rng.uniform(20, width - 20, count), rng.uniform(20, height - 20, count)
    half = 0.5 * length * np.column_stack([np.cos(angle), np.sin(angle)])
    others = np.column_stack([x - half[:, 0], y - half[:, 1], x + half[:, 0], y + half[:, 1]])
    return np.concatenate([vertical, others])


def test_vertical_segments_are_chosen_by_angle_length_and_place_and_point_up():
    up = lambda x, y: np.tile([0.0, -1.0], (len(x), 1))  # noqa: E731  (a level camera: up is -y)
    segments = np.array(
        [
            [50, 80, 50, 40],  # vertical, drawn upwards
            [60, 40, 61, 80],  # 1.4° off vertical, drawn downwards
            [70, 40, 75, 80],  # 7.1° off
            [80, 40, 80, 45],  # vertical but short
            [10, 10, 60, 10],  # horizontal
            [300, 40, 300, 80],  # vertical, outside a 200 x 100 image
        ],
        dtype=float,
    )
    found = vertical_segments(segments, up, (200, 100), min_length=10, angle_deg=5)
    np.testing.assert_allclose(found.x, [50, 60.5])
    np.testing.assert_allclose(found.y, [60, 60])
    np.testing.assert_allclose(found.length, [40, np.hypot(1, 40)])
    assert np.all(found.direction[:, 1] < 0)  # both point up the image, whichever way they were drawn
    np.testing.assert_allclose(np.linalg.norm(found.direction, axis=1), 1.0)
    x, y, direction, weight = found.observations(2.0)
    np.testing.assert_allclose(weight, 2.0 * found.length)


def test_detected_segments_are_in_image_pixels():
    """A vertical edge between columns 250 and 251 of a 600 x 400 image, found at full size and on a copy
    reduced for speed."""
    image = np.zeros((400, 600, 3), np.uint8)
    image[:, 251:] = 200
    for max_short_side in (448, 200):
        segments = detect_segments(image, max_short_side)
        long = segments[np.hypot(*(segments[:, 2:] - segments[:, :2]).T) > 100]
        assert len(long) >= 1
        np.testing.assert_allclose(long[:, [0, 2]], 250.5, atol=1.0)
        assert np.abs(long[:, 1] - long[:, 3]).max() > 0.8 * 400
    assert detect_segments(np.full((100, 100, 3), 90, np.uint8)).shape == (0, 4)


def test_field_sampler_reads_the_nearest_cell():
    h, w, stride = 6, 8, 4
    xs, ys = np.meshgrid(np.arange(w) * stride + 1.5, np.arange(h) * stride + 1.5)
    field = np.stack([xs, ys], axis=-1)
    sample = field_sampler(field, (xs, ys))
    np.testing.assert_allclose(sample(np.array([1.5, 13.0, 100.0]), np.array([1.5, 9.9, -5.0])),
                               [[1.5, 1.5], [13.5, 9.5], [29.5, 1.5]])  # fmt: skip


def test_segments_correct_a_biased_up_field():
    """Fields whose up vectors are all tilted by 2° give a roll 2° off; exact vertical segments (with as
    many segments at random angles) bring it back."""
    rng = np.random.default_rng(3)
    for _ in range(8):
        width, height, f, g, roll, pitch, vfov = random_camera(rng, (320, 240))
        biased = gravity_from_roll_pitch(np.radians(roll + 2.0), np.radians(pitch))
        up, _, conf = noisy_fields(rng, width, height, f, biased, up_noise_deg=2, outliers=0.1)
        lat = latitude_field(g, f, width, height)
        segments = true_vertical_segments(rng, width, height, f, g)
        plain = refine_camera(up, lat, conf, conf)
        found = gravity_with_lines(up, lat, conf, conf, segments, image_size=(width, height), pixel_xy=None)
        assert np.degrees(gravity_angle(plain.gravity_up, g)) > 0.5
        assert np.degrees(gravity_angle(found.gravity_up, g)) < 0.3 * np.degrees(
            gravity_angle(plain.gravity_up, g)
        )
        assert 30 <= found.segments <= 45  # the true ones, and at most a few random ones that happen to fit
        assert found.covariance.shape == (2, 2) and np.all(np.linalg.eigvalsh(found.covariance) > 0)
        # a known focal is held while the gravity is fitted
        known = gravity_with_lines(
            up, lat, conf, conf, segments, image_size=(width, height), pixel_xy=None, focal_prior=f
        )
        assert np.degrees(gravity_angle(known.gravity_up, g)) < 0.5


def _line_gravity_with(*confs: dict):
    """The line gravity of one camera with true vertical segments, once per ``conf`` of gravity_with_lines."""
    rng = np.random.default_rng(6)
    width, height, f, g, *_ = random_camera(rng, (320, 240))
    up, lat, conf = noisy_fields(rng, width, height, f, g)
    segments = true_vertical_segments(rng, width, height, f, g)
    size = (width, height)
    return [
        gravity_with_lines(up, lat, conf, conf, segments, image_size=size, pixel_xy=None, conf=c)
        for c in confs
    ]


def test_sigma_scale_scales_the_gravity_covariance():
    one, scaled = _line_gravity_with(
        {"sigma_scale": 1.0, "segment_sigma_deg": 0.0}, {"sigma_scale": (2.0, 3.0), "segment_sigma_deg": 0.0}
    )
    # (roll, pitch) factors; the covariance is of (pitch, roll·cos(pitch))
    np.testing.assert_allclose(scaled.covariance, one.covariance * np.outer([3.0, 2.0], [3.0, 2.0]))
    np.testing.assert_array_equal(scaled.gravity_up, one.gravity_up)


def test_few_segments_cannot_pin_the_gravity_however_long():
    """Each segment taken as vertical may stand off the vertical by segment_sigma_deg on its own: n of them
    leave at least that over √n on the gravity's 1 sigma, in both directions; the fit itself is the same."""
    bare, spread = _line_gravity_with({"segment_sigma_deg": 0.0}, {"segment_sigma_deg": 3.0})
    floor = np.radians(3.0) ** 2 / spread.segments
    np.testing.assert_allclose(spread.covariance, bare.covariance + floor * np.eye(2), rtol=1e-12)
    assert np.all(np.diag(spread.covariance) >= floor) and np.all(np.diag(bare.covariance) < floor)
    np.testing.assert_array_equal(spread.gravity_up, bare.gravity_up)


def test_without_vertical_segments_there_is_no_line_gravity():
    rng = np.random.default_rng(4)
    width, height, f, g, *_ = random_camera(rng, (320, 240))
    up, lat, conf = noisy_fields(rng, width, height, f, g)
    across = up[120, 160, ::-1] * np.array([1.0, -1.0])  # perpendicular to the up field at the centre
    segment = np.concatenate([[160, 120] - 20 * across, [160, 120] + 20 * across])[None]
    for segments in (np.zeros((0, 4)), segment):
        assert (
            gravity_with_lines(up, lat, conf, conf, segments, image_size=(width, height), pixel_xy=None)
            is None
        )


def test_camera_sampler_is_the_fitted_cameras_up_field():
    rng = np.random.default_rng(5)
    width, height, f, g, *_ = random_camera(rng, (320, 240))
    up, lat, conf = noisy_fields(rng, width, height, f, g, up_noise_deg=0, lat_noise_deg=0, outliers=0)
    fit = refine_camera(up, lat, conf, conf)
    x, y = np.array([3.0, 160.0, 300.0]), np.array([7.0, 120.0, 230.0])
    np.testing.assert_allclose(camera_sampler(fit)(x, y), up[y.astype(int), x.astype(int)], atol=1e-5)


def test_calibrate_fits_gravity_to_vertical_lines_with_the_lens_taken_out(
    example_pair, onnx_model, monkeypatch
):
    """On the example pair (a street, ground truth known) the segments bring each camera's gravity within
    0.5°, closer than the fields alone; through a barrel lens the fusion's distortion is taken out of the
    segments first, which beats using them as they are."""
    import json
    from pathlib import Path

    import cv2

    import stereogeo_cli.pipeline as pipeline
    from stereogeo_cli.geometry import intrinsic_matrix, undistort_division
    from stereogeo_cli.io import load_image
    from stereogeo_cli.network.runtime import FieldNetwork

    if FieldNetwork(onnx_model).metadata.get("model_version") == "untrained-test":
        pytest.skip("the untrained test network's fields choose no segments worth testing")
    truth = json.loads((Path(__file__).parent.parent / "examples" / "ground_truth.json").read_text())
    images = [load_image(path) for path in example_pair]

    def errors(pair, conf=None):
        result = pipeline.Calibrator(onnx_model, conf=conf).calibrate(*pair)
        found = result.calibration.extra_report["vertical_segments"]
        fits = (result.left, result.right)
        return [np.degrees(gravity_angle(f.gravity_up, np.array(truth[s]["gravity_up"]))) for s, f in
                zip(("left", "right"), fits, strict=True)], found  # fmt: skip

    with_lines, found = errors(images)
    alone, none = errors(images, {"lines": {"enabled": False}})
    assert min(found) > 20 and none == [0, 0]
    assert max(with_lines) < 0.5 and max(with_lines) < min(alone)

    h, w = images[0].shape[:2]
    grid = np.stack(np.meshgrid(np.arange(w), np.arange(h)), -1).reshape(-1, 2).astype(float)
    where = undistort_division(grid, intrinsic_matrix(512.0, w, h), -0.25).reshape(h, w, 2).astype(np.float32)
    seen = [cv2.remap(im, where[..., 0], where[..., 1], cv2.INTER_LINEAR) for im in images]
    lens_out, _ = errors(seen)
    monkeypatch.setattr(pipeline, "undistort_division", lambda points, K, k: np.asarray(points, dtype=float))
    lens_in, _ = errors(seen)
    assert max(lens_out) < min(lens_in)
