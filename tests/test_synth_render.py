"""The renderer's ground truth: projection convention, depth reprojection, horizon, panorama crops.

These tests need EGL (Mesa llvmpipe). CI installs it, so they fail rather than skip when it is broken.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stereogeo_cli.geometry import gravity_from_roll_pitch, latitude_field, roll_pitch_from_gravity
from stereogeo_cli.synth.check import depth_agreement
from stereogeo_cli.synth.config import SynthConfig
from stereogeo_cli.synth.rigs import Camera, RigSample, camera_rotation
from stereogeo_cli.synth.sample import get_renderer, sample_pair
from stereogeo_cli.synth.scenes import Lighting, MeshBuilder, Scene, build_scene
from stereogeo_cli.synth.textures import read_rgb

CONFIG = SynthConfig(depth=True, augment=0.0, texture_size=128, texture_layers=24)


@pytest.fixture(scope="module")
def renderer():
    return get_renderer(7, CONFIG)


def _scene(mesh: MeshBuilder, rig=None) -> Scene:
    surfaces, windows = mesh.arrays()
    return Scene(
        "test", surfaces, windows, Lighting(0.6, 0.4, (0.0, 0.0, 1.0), None, 1.0), 0.0, 0.05, 100.0, rig
    )


@pytest.mark.parametrize("edge", [100.3, 100.7])
def test_projection_follows_the_pixel_centre_convention(renderer, edge):
    # camera axes = world axes; a wall at Z = 5, left edge projecting to x = edge, top to y = edge - 40
    w, h, f, Z = 320, 240, 250.0, 5.0
    camera = Camera(w, h, f, np.eye(3), np.zeros(3))
    x0 = (edge - w / 2) * Z / f
    y0 = (edge - 40 - h / 2) * Z / f
    mesh = MeshBuilder()
    material = renderer.materials.pick(np.random.default_rng(0), "wall")
    mesh.quad((x0, y0, Z), (20.0, 0.0, 0.0), (0.0, 20.0, 0.0), material)
    scene = _scene(mesh)
    vaos = renderer.upload(scene)
    depth = renderer.render_depth(camera, scene, vaos)
    renderer.release(vaos)
    covered_cols = np.nonzero(depth[h - 1] > 0)[0]
    covered_rows = np.nonzero(depth[:, w - 1] > 0)[0]
    # pixel centres at integer coordinates: the first covered column is the first centre right of the edge
    assert covered_cols[0] == 101
    assert covered_rows[0] == 61
    np.testing.assert_allclose(depth[depth > 0], Z, rtol=1e-5)


def test_left_depth_reprojects_onto_right_depth(renderer):
    for index in range(10):
        kind = ("room", "corridor", "desk", "street", "open")[index % 5]
        sample = sample_pair(7, index, CONFIG, renderer, kind=kind)
        agreement = depth_agreement(sample.depth_left, sample.depth_right, sample.calib)
        assert agreement.fraction >= 0.95, (index, kind, agreement)
        if kind != "open":  # open scenes may look at the sky only
            assert agreement.agree > 1000, (index, kind, agreement)


def test_wrong_ground_truth_is_caught(renderer):
    from stereogeo_cli.geometry import rotation_from_axis_angle

    for index, kind in ((0, "room"), (2, "street")):
        sample = sample_pair(7, index, CONFIG, renderer, kind=kind)
        calib = dict(sample.calib)
        calib["R"] = (rotation_from_axis_angle(np.radians([0.0, 3.0, 0.0])) @ np.array(calib["R"])).tolist()
        assert depth_agreement(sample.depth_left, sample.depth_right, calib).fraction < 0.9


def test_calib_is_consistent(renderer):
    for index in range(12):
        sample = sample_pair(7, index, CONFIG, renderer)
        c = sample.calib
        R, T = np.array(c["R"]), np.array(c["T"])
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) > 0
        gl, gr = np.array(c["left"]["gravity_up"]), np.array(c["right"]["gravity_up"])
        np.testing.assert_allclose(R @ gl, gr, atol=1e-12)
        for side, image in (("left", sample.left), ("right", sample.right)):
            cam = c[side]
            assert image.shape == (cam["height"], cam["width"], 3) and image.dtype == np.uint8
            K = np.array(cam["K"])
            assert K[0, 2] == cam["width"] / 2 and K[1, 2] == cam["height"] / 2 and K[0, 0] == K[1, 1]
            vfov = np.degrees(2 * np.arctan(cam["height"] / (2 * K[1, 1])))
            assert 20 - 1e-9 <= vfov <= 105 + 1e-9
            assert cam["dist"] == []
        roll, pitch = np.degrees(roll_pitch_from_gravity(gl))
        assert abs(roll) <= 45 + 1e-9 and abs(pitch) <= 45 + 1e-9
        assert 0.05 - 1e-9 <= np.linalg.norm(T) <= 0.8 + 1e-9
        if c["scene"] == "desk":
            assert np.linalg.norm(T) <= 0.375 + 1e-9  # a quarter of the longest viewing distance
        # the right camera sits to the right of the left one: its centre -Rᵀ T has x > 0
        assert (-R.T @ T)[0] > 0


def test_desk_scenes_are_close_range_with_a_short_baseline(renderer):
    config = CONFIG.replace(baseline_m=(0.04, 0.5))
    medians = []
    for index in range(8):
        sample = sample_pair(11, index, config, renderer, kind="desk")
        c = sample.calib
        assert c["scene"] == "desk"
        depth = sample.depth_left[sample.depth_left > 0]
        assert depth.size > 0.9 * sample.depth_left.size  # a closed room: every pixel sees a surface
        median = float(np.median(depth))
        medians.append(median)
        baseline = c["baseline_m"]
        # within the sampler's range, and at most a quarter of the 0.35–1.5 m viewing distance
        assert 0.04 - 1e-9 <= baseline <= 0.375 + 1e-9
        assert baseline <= 0.6 * median, (index, baseline, median)
        # the cameras keep their 0.3 m clearance: z-depth times the ray length is the distance (1 cm slack)
        K = np.array(c["left"]["K"])
        ys, xs = np.nonzero(sample.depth_left > 0)
        ray = np.hypot(np.hypot((xs - K[0, 2]) / K[0, 0], (ys - K[1, 2]) / K[1, 1]), 1.0)
        assert np.min(sample.depth_left[ys, xs] * ray) > 0.29
    assert 0.3 < np.median(medians) < 1.8, medians


def test_close_share_only_changes_the_indoor_scenes_it_turns_into_desks(renderer):
    # datasets rendered before desks existed are reproduced with close_share = 0
    none, all_indoor = CONFIG.replace(close_share=0.0), CONFIG.replace(close_share=1.0)
    kinds = []
    for index in range(8):
        a, b = sample_pair(7, index, none, renderer), sample_pair(7, index, all_indoor, renderer)
        assert a.calib["scene"] != "desk"
        kinds.append((a.calib["scene"], b.calib["scene"]))
        if a.calib["scene"] in ("street", "open") or a.calib["kind"] == "panorama":
            assert b.calib == a.calib and np.array_equal(a.left, b.left)
        else:
            assert b.calib["scene"] == "desk"
    assert {"desk"} <= {k for _, k in kinds} and {"street", "open"} & {k for k, _ in kinds}


def test_outdoor_horizon_lies_on_the_rendered_horizon(renderer):
    rng = np.random.default_rng(3)
    for roll_deg, pitch_deg, vfov_deg in [(0, 0, 60), (20, -10, 40), (-35, 15, 90), (10, 5, 25)]:
        w, h = 320, 240
        rig = RigSample(
            w,
            h,
            np.radians(vfov_deg),
            np.radians(vfov_deg),
            np.radians(roll_deg),
            np.radians(pitch_deg),
            np.eye(3),
            np.array([0.3, 0.0, 0.0]),
        )
        scene = build_scene(rng, rig, renderer.materials, "open", objects=False)
        vaos = renderer.upload(scene)
        depth = renderer.render_depth(scene.rig.left, scene, vaos)
        color = renderer.render_color(scene.rig.left, renderer.sky_choices["outdoor"][0], 0.3, scene, vaos)
        renderer.release(vaos)
        cam = scene.rig.left
        np.testing.assert_allclose(
            cam.gravity_up, gravity_from_roll_pitch(np.radians(roll_deg), np.radians(pitch_deg))
        )
        lat = latitude_field(cam.gravity_up, cam.focal, w, h)
        margin = 1.5 / cam.focal  # 1.5 pixels, in radians
        assert np.all(depth[lat < -margin] > 0), "ground missing below the GT horizon"
        assert np.all(depth[lat > margin] == 0), "geometry above the GT horizon"
        assert color.shape == (h, w, 3)


def test_panorama_crops_have_exact_roll_pitch_and_fov(shared_data):
    panoramas = shared_data / "panoramas"
    config = CONFIG.replace(panoramas=panoramas.resolve(), panorama_share=1.0)
    renderer = get_renderer(7, config)
    for index in range(3):
        sample = sample_pair(7, index, config, renderer)
        c = sample.calib
        assert c["kind"] == "panorama" and c["T"] == [0.0, 0.0, 0.0]
        pano = read_rgb(panoramas / f"{c['scene']}.jpg").astype(np.float32)
        for side, image in (("left", sample.left), ("right", sample.right)):
            cam = c[side]
            K, g = np.array(cam["K"]), np.array(cam["gravity_up"])
            roll, pitch = roll_pitch_from_gravity(g)
            exact = _panorama_mismatch(pano, image, cam, K, roll, pitch)
            # the stated geometry must fit far better than one 1° off in pitch or 5 % off in focal length
            # (exact: 1.5-7 grey levels, the texture's resampling; off: 11-23 on these panoramas)
            off_pitch = _panorama_mismatch(pano, image, cam, K, roll, pitch + np.radians(1.0))
            off_focal = _panorama_mismatch(pano, image, cam, K @ np.diag([1.05, 1.05, 1.0]), roll, pitch)
            assert exact < 0.6 * min(off_pitch, off_focal), (index, side, exact, off_pitch, off_focal)


def _panorama_mismatch(pano, image, cam, K, roll, pitch) -> float:
    """Mean absolute grey-level difference between a crop and the panorama seen through K and gravity
    (roll, pitch), at the best yaw: the up direction and the panorama's north are unknown to calib, so the
    yaw is searched, with rays built only from K and gravity as the dataset states them."""
    R_level_to_cam = camera_rotation(0.0, float(roll), float(pitch))
    ys, xs = np.mgrid[8 : cam["height"] - 8 : 6, 8 : cam["width"] - 8 : 6]
    rays = np.linalg.inv(K) @ np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)])
    d = R_level_to_cam.T @ rays
    d /= np.linalg.norm(d, axis=0)
    lat = np.arcsin(d[2])
    lon0 = np.arctan2(d[1], d[0])
    rows = (0.5 - lat / np.pi) * pano.shape[0] - 0.5
    best = np.inf
    for shift in np.linspace(0, 1, 720, endpoint=False):
        cols = ((0.5 - lon0 / (2 * np.pi) + shift) % 1.0) * pano.shape[1] - 0.5
        ref = cv2.remap(
            pano,
            cols.astype(np.float32).reshape(1, -1),
            rows.astype(np.float32).reshape(1, -1),
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_WRAP,
        )[0]
        best = min(best, float(np.abs(ref - image[ys.ravel(), xs.ravel()]).mean()))
    return best
