"""Every file ``calibrate -o`` writes, loaded by the reader its users load it with (OpenCV's FileStorage,
PyYAML for ROS and Kalibr, pycolmap for COLMAP's text model) and compared with the report written beside it.

Values the report states (K, distortion, R, T, sizes) must come back exactly: every writer promises text that
reads back to the same float64 (docs/io.md). The rectification, which the report does not state, is checked
by what a user does with it: points seen by both cameras land on the same rectified row, the disparity gives
their depth back through Q, and the right camera's P gives the report's baseline. ``batch-calibrate`` and
``--same-rig`` folders are checked with the same helper in tests/test_batch_pairs.py.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pycolmap
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples"
ALL_FILES = ["camchain.yaml", "cameras.txt", "extrinsics.yml", "intrinsics.yml", "left.yaml", "report.html",
             "report.json", "right.yaml"]  # fmt: skip


def written_files(folder: Path) -> list[str]:
    """The files of a calibration folder, sorted; hidden ones (batch-calibrate's own bookkeeping) left out."""
    return sorted(p.name for p in folder.iterdir() if not p.name.startswith("."))


def written_dist(dist: list[float]) -> np.ndarray:
    """The report's ``dist`` as the files hold it: five zeros for none, else padded to k1 k2 p1 p2 k3."""
    D = np.array(dist, dtype=float)
    return np.concatenate([D, np.zeros(5 - D.size)]) if D.size < 5 else D


def points_seen_by_both(report: dict, n: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """3-D points [n x 3] in the left camera's frame (metres) in front of both cameras and inside both images,
    and the same points in the right camera's frame, from the report's R and T."""
    rng = np.random.default_rng(0)
    R, T = np.array(report["R"]), np.array(report["T"])
    cams = [report[side] for side in ("left", "right")]
    depth = rng.uniform(2.0, 20.0, 4000) * max(float(np.linalg.norm(T)), 0.05) / 0.1
    K = np.array(cams[0]["K"])
    pixels = rng.uniform(0.2, 0.8, (4000, 2)) * [cams[0]["width"], cams[0]["height"]]
    X = np.column_stack([(pixels - K[:2, 2]) / K[0, 0], np.ones(4000)]) * depth[:, None]
    Xr = X @ R.T + T
    Kr = np.array(cams[1]["K"])
    seen = Xr[:, 2] > 0
    xr = Xr[:, :2] / Xr[:, 2:] * Kr[0, 0] + Kr[:2, 2]
    seen &= (xr > 0.1 * np.array([cams[1]["width"], cams[1]["height"]])).all(axis=1)
    seen &= (xr < 0.9 * np.array([cams[1]["width"], cams[1]["height"]])).all(axis=1)
    assert seen.sum() >= n, "the two cameras share too little of the view for this check"
    return X[seen][:n], Xr[seen][:n]


def project(X: np.ndarray, K: np.ndarray, D: np.ndarray) -> np.ndarray:
    return cv2.projectPoints(X.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, D)[0].reshape(-1, 2)


def rectified(pixels: np.ndarray, K, D, R_rect, P) -> np.ndarray:
    """Where OpenCV's rectification (initUndistortRectifyMap's mapping) puts these original pixels."""
    return cv2.undistortPoints(pixels.reshape(-1, 1, 2), K, D, R=R_rect, P=P).reshape(-1, 2)


# ------------------------------------------------------------------------------------------------ the readers
def check_opencv(folder: Path, report: dict) -> dict[str, np.ndarray]:
    """intrinsics.yml and extrinsics.yml through cv2.FileStorage (docs/io.md's snippet); returns them."""
    m = {}
    for name, keys in (("intrinsics.yml", ("M1", "D1", "M2", "D2")),
                       ("extrinsics.yml", ("R", "T", "R1", "R2", "P1", "P2", "Q"))):  # fmt: skip
        fs = cv2.FileStorage(str(folder / name), cv2.FILE_STORAGE_READ)
        assert fs.isOpened(), name
        for key in keys:
            m[key] = fs.getNode(key).mat()
            assert m[key] is not None, (name, key)
        fs.release()
    left, right = report["left"], report["right"]
    np.testing.assert_array_equal(m["M1"], left["K"])
    np.testing.assert_array_equal(m["M2"], right["K"])
    np.testing.assert_array_equal(m["D1"].ravel(), written_dist(left["dist"]))
    np.testing.assert_array_equal(m["D2"].ravel(), written_dist(right["dist"]))
    np.testing.assert_array_equal(m["R"], report["R"])
    np.testing.assert_array_equal(m["T"].ravel(), report["T"])
    assert m["T"].shape == (3, 1)

    # the rectification, as a user applies it: both rectified cameras look the same way
    R, baseline = np.array(report["R"]), report["baseline_m"]
    for key in ("R1", "R2"):
        np.testing.assert_allclose(m[key] @ m[key].T, np.eye(3), atol=1e-9)
        assert np.linalg.det(m[key]) == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(m["R2"] @ R @ m["R1"].T, np.eye(3), atol=1e-9)
    # the right P carries the baseline (README: baseline = -P[3] / P[0]), with the left P's intrinsics
    P1, P2 = m["P1"], m["P2"]
    np.testing.assert_array_equal(P1[:, :3], P2[:, :3])
    np.testing.assert_array_equal(P1[:, 3], 0.0)
    assert -P2[0, 3] / P2[0, 0] == pytest.approx(baseline, rel=1e-9) and baseline > 0
    np.testing.assert_array_equal(P2[1:, 3], 0.0)
    # points seen by both cameras: the same rectified row, and Q turns (x, y, disparity) into the point in the
    # rectified left camera's frame, in metres
    X, Xr = points_seen_by_both(report)
    D1, D2 = m["D1"].ravel(), m["D2"].ravel()
    at_left = rectified(project(X, m["M1"], D1), m["M1"], D1, m["R1"], P1)
    at_right = rectified(project(Xr, m["M2"], D2), m["M2"], D2, m["R2"], P2)
    np.testing.assert_allclose(at_left[:, 1], at_right[:, 1], atol=1e-3)  # px
    disparity = at_left[:, 0] - at_right[:, 0]
    homogeneous = np.column_stack([at_left, disparity, np.ones(len(X))]) @ m["Q"].T
    np.testing.assert_allclose(homogeneous[:, :3] / homogeneous[:, 3:], X @ m["R1"].T, rtol=1e-5, atol=1e-6)
    return m


def check_ros(folder: Path, report: dict, opencv: dict[str, np.ndarray]) -> None:
    """left.yaml and right.yaml through PyYAML, as camera_info: the report's K and D, the OpenCV file's
    rectification, and the baseline from the right P."""
    for side, n in (("left", 1), ("right", 2)):
        info = yaml.safe_load((folder / f"{side}.yaml").read_text())
        cam = report[side]
        assert (info["image_width"], info["image_height"]) == (cam["width"], cam["height"])
        assert info["camera_name"] == side and info["distortion_model"] == "plumb_bob"

        def matrix(key, rows, cols, info=info):
            entry = info[key]
            assert (entry["rows"], entry["cols"]) == (rows, cols), key
            return np.array(entry["data"], dtype=float).reshape(rows, cols)

        np.testing.assert_array_equal(matrix("camera_matrix", 3, 3), cam["K"])
        np.testing.assert_array_equal(
            matrix("distortion_coefficients", 1, 5).ravel(), written_dist(cam["dist"])
        )
        np.testing.assert_array_equal(matrix("rectification_matrix", 3, 3), opencv[f"R{n}"])
        P = matrix("projection_matrix", 3, 4)
        np.testing.assert_array_equal(P, opencv[f"P{n}"])
        if side == "right":
            assert -P[0, 3] / P[0, 0] == pytest.approx(report["baseline_m"], rel=1e-9)


def check_kalibr(folder: Path, report: dict) -> None:
    """camchain.yaml through PyYAML: cam0 left, cam1 right with T_cn_cnm1 = [R | T]; a k3, which radtan has no
    term for, folded into k1 k2 so that no pixel moves by half a pixel."""
    chain = yaml.safe_load((folder / "camchain.yaml").read_text())
    assert sorted(chain) == ["cam0", "cam1"]
    for key, side in (("cam0", "left"), ("cam1", "right")):
        cam, entry = report[side], chain[key]
        K = np.array(cam["K"])
        assert entry["camera_model"] == "pinhole" and entry["distortion_model"] == "radtan"
        assert entry["resolution"] == [cam["width"], cam["height"]]
        assert entry["intrinsics"] == [K[0, 0], K[1, 1], K[0, 2], K[1, 2]]
        D = written_dist(cam["dist"])
        radtan = np.array(entry["distortion_coeffs"], dtype=float)
        assert radtan.shape == (4,)
        if D[4] == 0.0:
            np.testing.assert_array_equal(radtan, D[:4])
        else:  # folded: the same pixels within half a pixel out to the corners (docs/io.md; here 0.19 px, and
            # 2.6 px with k3 dropped instead)
            w, h = cam["width"], cam["height"]
            grid = np.stack(np.meshgrid(np.linspace(0, w - 1, 15), np.linspace(0, h - 1, 15)), -1).reshape(
                -1, 2
            )
            rays = cv2.undistortPoints(grid.reshape(-1, 1, 2), K, D).reshape(-1, 2)
            X = np.column_stack([rays, np.ones(len(rays))])
            moved = np.abs(project(X, K, np.r_[radtan, 0.0]) - project(X, K, D)).max()
            assert moved < 0.5, moved
    T_cn_cnm1 = np.array(chain["cam1"]["T_cn_cnm1"], dtype=float)
    np.testing.assert_array_equal(T_cn_cnm1[:3, :3], report["R"])
    np.testing.assert_array_equal(T_cn_cnm1[:3, 3], report["T"])
    np.testing.assert_array_equal(T_cn_cnm1[3], [0.0, 0.0, 0.0, 1.0])


def check_colmap(folder: Path, report: dict, scratch: Path) -> None:
    """cameras.txt as pycolmap reads a text model (with empty images.txt and points3D.txt beside it): camera 1
    left, camera 2 right, and each projects a point where OpenCV's K and D do, plus COLMAP's half pixel."""
    model = scratch / "colmap-model"
    model.mkdir()
    shutil.copy(folder / "cameras.txt", model / "cameras.txt")
    (model / "images.txt").write_text("")
    (model / "points3D.txt").write_text("")
    cameras = pycolmap.Reconstruction(str(model)).cameras
    assert sorted(cameras) == [1, 2]
    X, Xr = points_seen_by_both(report)
    for camera_id, side, points in ((1, "left", X), (2, "right", Xr)):
        camera, cam = cameras[camera_id], report[side]
        K, D = np.array(cam["K"]), written_dist(cam["dist"])
        assert (camera.width, camera.height) == (cam["width"], cam["height"])
        expected_model = "PINHOLE" if not D.any() else "OPENCV" if not D[4:].any() else "FULL_OPENCV"
        assert camera.model.name == expected_model
        np.testing.assert_array_equal(camera.params[:4], [K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5])
        np.testing.assert_allclose(camera.img_from_cam(points), project(points, K, D) + 0.5, atol=1e-6)


def assert_folder_matches_report(folder: Path, report: dict, scratch: Path) -> None:
    """Every file of ``folder`` (all six formats) loaded by its reader agrees with ``report`` and with
    the report.json beside it."""
    assert written_files(folder) == ALL_FILES
    assert json.loads((folder / "report.json").read_text()) == report
    opencv = check_opencv(folder, report)
    check_ros(folder, report, opencv)
    check_kalibr(folder, report)
    check_colmap(folder, report, scratch)


# ------------------------------------------------------------------------------------------------- the tests
def test_calibrate_output_folder_reads_back_as_the_report(calibrate_cli, tmp_path):
    """The example pair: ``calibrate --json -o DIR`` prints the report DIR/report.json holds, and every file
    in DIR says the same."""
    report, folder = calibrate_cli(EXAMPLE / "left.png", EXAMPLE / "right.png")
    assert report["left"]["dist"] == [] and report["right"]["dist"] == []  # no lens on the example pair
    assert_folder_matches_report(folder, report, tmp_path)


def test_rendered_pair_of_another_shape_reads_back(rendered_pairs, calibrate_cli, tmp_path):
    """A portrait pair (240 x 360): no axis of the files is the example's."""
    pair = rendered_pairs["open-portrait"]
    report, folder = calibrate_cli(pair.left, pair.right)
    assert (report["left"]["width"], report["left"]["height"]) == (240, 360)
    assert_folder_matches_report(folder, report, tmp_path)


@pytest.fixture(scope="module")
def barrel_pair(tmp_path_factory) -> tuple[Path, Path]:
    """The example pair seen through a barrel lens (division model, k = -0.25 at f = 512 px), which the
    calibration finds and writes (tests/test_cli_calibrate.py checks the lens itself)."""
    from stereogeo_cli.geometry import intrinsic_matrix, undistort_division

    folder = tmp_path_factory.mktemp("barrel")
    paths = []
    for side in ("left", "right"):
        image = cv2.imread(str(EXAMPLE / f"{side}.png"))
        h, w = image.shape[:2]
        grid = np.stack(np.meshgrid(np.arange(w), np.arange(h)), -1).reshape(-1, 2).astype(float)
        where = undistort_division(grid, intrinsic_matrix(512.0, w, h), -0.25).reshape(h, w, 2)
        where = where.astype(np.float32)
        paths.append(folder / f"{side}.png")
        cv2.imwrite(str(paths[-1]), cv2.remap(image, where[..., 0], where[..., 1], cv2.INTER_LINEAR))
    return paths[0], paths[1]


def test_a_lens_reads_back_in_every_format(barrel_pair, calibrate_cli, tmp_path):
    """With distortion: OpenCV's and ROS's D, COLMAP's FULL_OPENCV, Kalibr's k3 folded into radtan."""
    report, folder = calibrate_cli(*barrel_pair)
    for side in ("left", "right"):
        assert len(report[side]["dist"]) == 5 and report[side]["dist"][4] != 0.0, report[side]["dist"]
    assert_folder_matches_report(folder, report, tmp_path)
