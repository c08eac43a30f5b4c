import json

import numpy as np
import pytest

from stereogeo_cli.geometry import (
    ImageTurn,
    apply_resize_crop,
    axis_angle_from_rotation,
    closest_rotation,
    couple_rotation_to_gravity,
    essential_matrix,
    fields_and_jacobians,
    focal_from_vfov,
    fundamental_matrix,
    gravity_angle,
    gravity_coupling_error,
    gravity_from_roll_pitch,
    intrinsic_matrix,
    latitude_field,
    quaternion_from_rotation,
    quaternion_to_rotation,
    resize_crop_for_network,
    retract_on_sphere,
    roll_pitch_from_gravity,
    rotation_angle,
    rotation_between_vectors,
    rotation_error,
    rotation_from_axis_angle,
    symmetric_epipolar_distance,
    tangent_basis,
    up_field,
    vfov_from_focal,
)
from stereogeo_cli.geometry.fields import up_and_sin_latitude


def random_rotation(rng, max_angle=np.pi):
    axis = rng.standard_normal(3)
    return rotation_from_axis_angle(axis / np.linalg.norm(axis) * rng.uniform(0, max_angle))


def test_golden_fields(shared_data):
    cases = json.loads((shared_data / "golden" / "golden_fields.json").read_text())
    assert len(cases) == 4
    for case in cases:
        g = gravity_from_roll_pitch(np.radians(case["roll_deg"]), np.radians(case["pitch_deg"]))
        np.testing.assert_allclose(g, case["gravity_up_vec3d"], atol=1e-9)
        f = float(focal_from_vfov(np.radians(case["vfov_deg"]), case["h"]))
        assert f == pytest.approx(case["f"], abs=1e-6)
        up = up_field(g, case["f"], case["w"], case["h"])
        lat = latitude_field(g, case["f"], case["w"], case["h"])
        np.testing.assert_allclose(up, case["up_field_HxWx2"], atol=1e-9, err_msg=case["name"])
        np.testing.assert_allclose(lat, case["latitude_rad_HxW"], atol=1e-9, err_msg=case["name"])


def test_gravity_conventions():
    np.testing.assert_allclose(gravity_from_roll_pitch(0.0, 0.0), [0, -1, 0])
    # looking up: up tilts towards +z (forward)
    assert gravity_from_roll_pitch(0.0, 0.3)[2] > 0
    # positive roll leans the image up-direction towards -x
    assert gravity_from_roll_pitch(0.3, 0.0)[0] < 0
    rng = np.random.default_rng(0)
    roll, pitch = rng.uniform(-3, 3, 100), rng.uniform(-1.5, 1.5, 100)
    r2, p2 = roll_pitch_from_gravity(gravity_from_roll_pitch(roll, pitch))
    np.testing.assert_allclose(r2, roll, atol=1e-12)
    np.testing.assert_allclose(p2, pitch, atol=1e-12)


def test_tangent_basis_is_pitch_and_roll_directions():
    rng = np.random.default_rng(1)
    for _ in range(20):
        roll, pitch = rng.uniform(-1.5, 1.5), rng.uniform(-1.4, 1.4)
        g = gravity_from_roll_pitch(roll, pitch)
        B = tangent_basis(g)
        np.testing.assert_allclose(B.T @ B, np.eye(2), atol=1e-12)
        np.testing.assert_allclose(B.T @ g, 0, atol=1e-12)
        eps = 1e-6
        d_pitch = (
            gravity_from_roll_pitch(roll, pitch + eps) - gravity_from_roll_pitch(roll, pitch - eps)
        ) / (2 * eps)
        d_roll = (gravity_from_roll_pitch(roll + eps, pitch) - gravity_from_roll_pitch(roll - eps, pitch)) / (
            2 * eps
        )
        np.testing.assert_allclose(B[:, 0], d_pitch, atol=1e-8)
        np.testing.assert_allclose(B[:, 1], d_roll / np.cos(pitch), atol=1e-8)
        g2 = retract_on_sphere(g, np.array([0.01, -0.02]))
        assert np.linalg.norm(g2) == pytest.approx(1.0)
        assert gravity_angle(g, g2) == pytest.approx(np.hypot(0.01, 0.02), rel=1e-9)


@pytest.mark.parametrize("size", [(320, 240), (90, 160)])
def test_field_jacobians_match_central_differences(size):
    rng = np.random.default_rng(2)
    width, height = size
    x = rng.uniform(-0.5, width - 0.5, 200)
    y = rng.uniform(-0.5, height - 0.5, 200)
    cx, cy = width / 2, height / 2
    for _ in range(10):
        g = gravity_from_roll_pitch(*rng.uniform(-0.8, 0.8, 2))
        f = float(focal_from_vfov(np.radians(rng.uniform(20, 110)), height))
        up, sin_lat, J_up, J_lat = fields_and_jacobians(g, f, x, y, cx, cy)
        up_ref, sin_lat_ref = up_and_sin_latitude(g, f, x, y, cx, cy)
        np.testing.assert_allclose(up, up_ref, atol=1e-14)
        np.testing.assert_allclose(sin_lat, sin_lat_ref, atol=1e-14)
        B = tangent_basis(g)
        eps = 1e-6
        for i in range(3):
            step = np.zeros(3)
            step[i] = eps

            def at(s, g=g, f=f, B=B):
                return up_and_sin_latitude(retract_on_sphere(g, s[:2], B), f * np.exp(s[2]), x, y, cx, cy)

            (up_p, lat_p), (up_m, lat_m) = at(step), at(-step)
            num_up, num_lat = (up_p - up_m) / (2 * eps), (lat_p - lat_m) / (2 * eps)
            scale_up, scale_lat = np.abs(num_up).max(), np.abs(num_lat).max()
            np.testing.assert_allclose(J_up[:, :, i], num_up, atol=1e-5 * scale_up, rtol=1e-5)
            np.testing.assert_allclose(J_lat[:, i], num_lat, atol=1e-5 * scale_lat, rtol=1e-5)


def test_vfov_focal_round_trip():
    vfov = np.radians(np.linspace(5, 150, 30))
    np.testing.assert_allclose(vfov_from_focal(focal_from_vfov(vfov, 480), 480), vfov, atol=1e-13)
    assert float(focal_from_vfov(np.radians(90.0), 480)) == pytest.approx(240.0)
    K = intrinsic_matrix(500.0, 640, 480)
    np.testing.assert_allclose(K, [[500, 0, 320], [0, 500, 240], [0, 0, 1]])


@pytest.mark.parametrize("degrees", [0, 90, 180, 270])
def test_an_image_turn_maps_every_pixel_and_ray_back(degrees):
    """Each pixel of a turned image comes from the original pixel ``points_back`` names, and the ray through
    it is the original ray turned by ``rotation`` (about the images' centres)."""
    width, height, f = 7, 5, 3.0
    image = np.arange(width * height).reshape(height, width)
    turn = ImageTurn(degrees)
    turned = turn.image(image)
    h, w = turned.shape
    assert turn.size_back((w, h)) == (width, height)
    ys, xs = np.mgrid[0:h, 0:w]
    back = turn.points_back(np.stack([xs, ys], axis=-1), (width, height))
    x, y = back[..., 0].astype(int), back[..., 1].astype(int)
    np.testing.assert_array_equal(image[y, x], turned)
    rays = np.stack([back[..., 0] - (width - 1) / 2, back[..., 1] - (height - 1) / 2, np.full((h, w), f)], -1)
    turned_rays = np.stack([xs - (w - 1) / 2, ys - (h - 1) / 2, np.full((h, w), f)], -1)
    np.testing.assert_allclose(rays @ turn.rotation.T, turned_rays, atol=1e-12)
    with pytest.raises(ValueError, match="90"):
        ImageTurn(45)


@pytest.mark.parametrize(("width", "height"), [(640, 480), (480, 640), (752, 480), (1920, 1080), (333, 333)])
def test_resize_crop_round_trip(width, height):
    rc = resize_crop_for_network(width, height, short_side=320, multiple=32)
    ow, oh = rc.out_size
    assert ow % 32 == 0 and oh % 32 == 0
    assert min(rc.resized_size) == 320
    assert ow <= rc.resized_size[0] and oh <= rc.resized_size[1]
    pts = np.array([[0.0, 0.0], [width - 1.0, height - 1.0], [12.3, 45.6]])
    np.testing.assert_allclose(rc.points_to_input(rc.points_to_output(pts)), pts, atol=1e-12)
    # the principal point stays within one original pixel of the network input's centre
    centre_in = rc.points_to_input(np.array([ow / 2, oh / 2]))
    np.testing.assert_allclose(centre_in, [width / 2, height / 2], atol=1.0 / rc.scale + 1e-9)
    # a camera's fields agree before and after: the focal maps by the scale
    f = 400.0
    assert rc.focal_to_input(rc.focal_to_output(f)) == pytest.approx(f)
    image = np.zeros((height, width, 3), np.uint8)
    assert apply_resize_crop(image, rc).shape == (oh, ow, 3)


def test_fields_survive_resize_crop():
    """Latitude at a pixel of the original equals latitude at the mapped pixel of the network input."""
    width, height = 752, 480
    rc = resize_crop_for_network(width, height)
    g = gravity_from_roll_pitch(0.2, -0.3)
    f = 460.0
    lat_net = latitude_field(g, rc.focal_to_output(f), *rc.out_size)
    ys, xs = np.mgrid[0 : rc.out_size[1] : 17, 0 : rc.out_size[0] : 13]
    orig = rc.points_to_input(np.stack([xs, ys], -1).astype(float))
    from stereogeo_cli.geometry import latitude_at

    lat_orig = latitude_at(g, f, orig[..., 0], orig[..., 1], width / 2, height / 2)
    # the only difference is the half-pixel principal-point convention: < 0.5 px of angle
    np.testing.assert_allclose(lat_net[ys, xs], lat_orig, atol=0.6 / rc.focal_to_output(f))


def test_quaternion_round_trip_and_angles():
    rng = np.random.default_rng(3)
    for _ in range(50):
        R = random_rotation(rng)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        q = quaternion_from_rotation(R)
        assert q[0] >= 0 and np.linalg.norm(q) == pytest.approx(1)
        np.testing.assert_allclose(quaternion_to_rotation(q), R, atol=1e-12)
        np.testing.assert_allclose(quaternion_to_rotation(-q), R, atol=1e-12)
        np.testing.assert_allclose(rotation_from_axis_angle(axis_angle_from_rotation(R)), R, atol=1e-10)
    Rz = rotation_from_axis_angle([0, 0, 0.3])
    assert rotation_angle(Rz) == pytest.approx(0.3)
    assert rotation_error(Rz, np.eye(3)) == pytest.approx(0.3)
    assert rotation_angle(rotation_from_axis_angle([0, np.pi - 1e-9, 0])) == pytest.approx(np.pi, abs=1e-8)
    assert rotation_angle(rotation_from_axis_angle([1e-9, 0, 0])) == pytest.approx(1e-9, rel=1e-6)
    noisy = Rz + 1e-3 * rng.standard_normal((3, 3))
    Rc = closest_rotation(noisy)
    np.testing.assert_allclose(Rc @ Rc.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(Rc) == pytest.approx(1.0)


def test_rotation_between_vectors():
    rng = np.random.default_rng(4)
    for _ in range(20):
        a, b = rng.standard_normal(3), rng.standard_normal(3)
        R = rotation_between_vectors(a, b)
        np.testing.assert_allclose(R @ (a / np.linalg.norm(a)), b / np.linalg.norm(b), atol=1e-12)
        assert rotation_angle(R) == pytest.approx(float(gravity_angle(a, b)), abs=1e-12)
    a = np.array([0.0, 1.0, 0.0])
    np.testing.assert_allclose(rotation_between_vectors(a, -a) @ a, -a, atol=1e-12)
    np.testing.assert_allclose(rotation_between_vectors(a, a), np.eye(3))


def test_gravity_coupling():
    rng = np.random.default_rng(5)
    for _ in range(30):
        R_true = random_rotation(rng, 0.2)
        g_left = gravity_from_roll_pitch(*rng.uniform(-0.7, 0.7, 2))
        g_right = R_true @ g_left
        assert gravity_coupling_error(R_true, g_left, g_right) == pytest.approx(0.0, abs=1e-12)
        R_noisy = random_rotation(rng, 0.05) @ R_true
        error = gravity_coupling_error(R_noisy, g_left, g_right)
        R_coupled = couple_rotation_to_gravity(R_noisy, g_left, g_right)
        np.testing.assert_allclose(R_coupled @ g_left, g_right, atol=1e-12)
        np.testing.assert_allclose(R_coupled @ R_coupled.T, np.eye(3), atol=1e-12)
        # it moves R by exactly the coupling error, the least any gravity-consistent rotation can
        assert rotation_error(R_coupled, R_noisy) == pytest.approx(error, abs=1e-10)
        for angle in rng.uniform(-np.pi, np.pi, 5):
            other = R_coupled @ rotation_from_axis_angle(g_left * angle)  # also maps g_left onto g_right
            np.testing.assert_allclose(other @ g_left, g_right, atol=1e-12)
            assert rotation_error(other, R_noisy) >= error - 1e-10


def test_epipolar_constraint():
    rng = np.random.default_rng(6)
    K1, K2 = intrinsic_matrix(500, 640, 480), intrinsic_matrix(620, 752, 480)
    R = random_rotation(rng, 0.1)
    T = np.array([-0.12, 0.01, 0.003])
    X = np.column_stack([rng.uniform(-2, 2, 50), rng.uniform(-1, 1, 50), rng.uniform(2, 10, 50)])
    xl = (K1 @ X.T).T
    xr = (K2 @ (R @ X.T + T[:, None])).T
    xl, xr = xl[:, :2] / xl[:, 2:], xr[:, :2] / xr[:, 2:]
    F = fundamental_matrix(K1, K2, R, T)
    assert symmetric_epipolar_distance(F, xl, xr).max() < 1e-9
    nl, nr = (
        (np.linalg.inv(K1) @ np.c_[xl, np.ones(50)].T).T,
        (np.linalg.inv(K2) @ np.c_[xr, np.ones(50)].T).T,
    )
    assert np.abs(np.sum(nr * (nl @ essential_matrix(R, T).T), axis=1)).max() < 1e-12
    assert symmetric_epipolar_distance(F, xl, xr + [0, 3.0]).min() > 0.5


@pytest.mark.parametrize("k", [-0.35, -0.2, -0.05, 0.03])
def test_division_model_written_as_opencv_coefficients_maps_the_same_pixels(k):
    """What we fit (division model) and what we write (OpenCV k1 k2 k3) agree to a fraction of a pixel."""
    import cv2

    from stereogeo_cli.geometry import opencv_from_division, undistort_division

    K = intrinsic_matrix(500.0, 640, 480)
    corner = np.hypot(320, 240) / 500.0
    D = opencv_from_division(k, corner)
    assert D.shape == (5,) and D[2] == D[3] == 0.0
    grid = np.stack(np.meshgrid(np.linspace(0, 639, 33), np.linspace(0, 479, 25)), -1).reshape(-1, 2)
    pinhole = undistort_division(grid, K, k)  # the observed (distorted) grid, undone by the division model
    rays = np.column_stack([(pinhole - K[:2, 2]) / 500.0, np.ones(len(grid))])
    seen, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, D)  # and distorted again by OpenCV's
    assert np.abs(seen.reshape(-1, 2) - grid).max() < 0.5
    # barrel (k < 0) moves points outwards when undone; no distortion leaves them
    centre_dist = np.linalg.norm(grid - K[:2, 2], axis=1)
    moved = np.linalg.norm(pinhole - K[:2, 2], axis=1) - centre_dist
    assert (np.sign(moved[centre_dist > 100]) == -np.sign(k)).all()
    np.testing.assert_array_equal(undistort_division(grid, K, 0.0), grid)
    assert opencv_from_division(0.0, corner).size == 0  # none, as OpenCV and the dataset layout write it
