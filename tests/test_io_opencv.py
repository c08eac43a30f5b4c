"""OpenCV intrinsics.yml / extrinsics.yml: number format, layout, read-back, and rectification with them."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from stereogeo_cli.geometry import intrinsic_matrix, rotation_from_axis_angle
from stereogeo_cli.io import StereoCalibration, write_calibration
from stereogeo_cli.io.opencv_yaml import format_opencv_double, opencv_matrix_yaml

GOLDEN = Path(__file__).parent / "golden"


class OpenCVLoader(yaml.SafeLoader):
    """PyYAML with the ``!!opencv-matrix`` tag as a NumPy array."""


def _opencv_matrix(loader: yaml.SafeLoader, node: yaml.Node) -> np.ndarray:
    m = loader.construct_mapping(node, deep=True)
    return np.array(m["data"], dtype=np.float64).reshape(m["rows"], m["cols"])


OpenCVLoader.add_constructor("tag:yaml.org,2002:opencv-matrix", _opencv_matrix)


def load_with_pyyaml(path: Path) -> dict:
    # PyYAML rejects the "%YAML:1.0" directive (not valid YAML 1.1 syntax), so skip the first line, as
    # ROS and other OpenCV-file readers do.
    return yaml.load(path.read_text().split("\n", 1)[1], Loader=OpenCVLoader)


def load_with_opencv(path: Path, names: list[str]) -> dict[str, np.ndarray]:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    assert fs.isOpened()
    try:
        return {n: fs.getNode(n).mat() for n in names}
    finally:
        fs.release()


def known_rig(D_left=(), T=(-0.12, 0.0, 0.0)) -> StereoCalibration:
    """f = 500 px, 640 x 480, a small relative rotation, baseline 0.12 m (plus a bit of y/z)."""
    return StereoCalibration(
        K_left=intrinsic_matrix(500.0, 640, 480),
        K_right=intrinsic_matrix(500.0, 640, 480),
        image_size_left=(640, 480),
        image_size_right=(640, 480),
        R=rotation_from_axis_angle([0.01, -0.02, 0.005]),
        T=np.array(T),
        D_left=np.array(D_left),
    )


@pytest.mark.parametrize(
    ("value", "text"),
    [
        (500.0, "500."),
        (0.0, "0."),
        (-0.0, "0."),
        (-3.0, "-3."),
        (-0.12, "-1.2000000000000000e-01"),
        (0.1, "1.0000000000000001e-01"),
        (1e20, "1.0000000000000000e+20"),
        (float("nan"), ".Nan"),
        (float("-inf"), "-.Inf"),
    ],
)
def test_number_format_is_filestorage(value, text):
    assert format_opencv_double(value) == text


def test_numbers_round_trip_exactly():
    values = np.random.default_rng(1).normal(scale=1000.0, size=2000) * np.logspace(-12, 6, 2000)
    assert all(float(format_opencv_double(v)) == v for v in values)


def _opencv5_number(value: float) -> str:
    # OpenCV 5's FileStorage: integers as "500.", others with 17 significant digits (%.17g)
    value = float(value)
    return f"{int(value)}." if value == round(value) and abs(value) < 2**31 else f"{value:.17g}"


@pytest.mark.parametrize("shape", [(3, 3), (1, 5), (1, 8), (3, 1), (3, 4), (4, 4), (2, 9)])
def test_layout_matches_filestorage(tmp_path, shape):
    """Same lines and wrapping as cv2.FileStorage (with the installed version's number format)."""
    rng = np.random.default_rng(sum(shape))
    M = rng.normal(size=shape) * 10.0 ** rng.integers(-4, 4, size=shape)
    M.flat[::3] = np.round(M.flat[::3])
    path = tmp_path / "m.yml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("M", M)
    fs.release()
    header, body = path.read_text().split("---\n", 1)
    number = format_opencv_double if header.startswith("%YAML:1.0") else _opencv5_number
    assert opencv_matrix_yaml("M", M, number=number) == body


@pytest.mark.parametrize("name", ["intrinsics.yml", "extrinsics.yml"])
def test_golden_read_back_opencv_and_pyyaml_agree_exactly(name):
    names = ["M1", "D1", "M2", "D2"] if name == "intrinsics.yml" else ["R", "T", "R1", "R2", "P1", "P2", "Q"]
    with_opencv = load_with_opencv(GOLDEN / name, names)
    with_pyyaml = load_with_pyyaml(GOLDEN / name)
    assert list(with_pyyaml) == names
    for n in names:
        assert with_opencv[n].dtype == np.float64
        np.testing.assert_array_equal(with_opencv[n], with_pyyaml[n])


def test_values_and_shapes_read_back_exactly(tmp_path):
    rig = json.loads((GOLDEN / "report.json").read_text())
    calib = StereoCalibration.from_report(rig)
    write_calibration(tmp_path, calib, formats=("opencv",))
    intr = load_with_opencv(tmp_path / "intrinsics.yml", ["M1", "D1", "M2", "D2"])
    extr = load_with_opencv(tmp_path / "extrinsics.yml", ["R", "T", "R1", "R2", "P1", "P2", "Q"])
    np.testing.assert_array_equal(intr["M1"], calib.K_left)
    np.testing.assert_array_equal(intr["M2"], calib.K_right)
    np.testing.assert_array_equal(intr["D1"], [[-0.05, 0.012, 0.0004, -0.0003, 0.0]])  # 4 → 5 values
    np.testing.assert_array_equal(intr["D2"], [[0.02, -0.01, 0.0, 0.0, 0.001]])
    np.testing.assert_array_equal(extr["R"], calib.R)
    np.testing.assert_array_equal(extr["T"], calib.T.reshape(3, 1))
    shapes = {"R1": (3, 3), "R2": (3, 3), "P1": (3, 4), "P2": (3, 4), "Q": (4, 4)}
    assert {n: extr[n].shape for n in shapes} == shapes


def test_no_distortion_is_written_as_five_zeros(tmp_path):
    write_calibration(tmp_path, known_rig(), formats=("opencv",))
    D1 = load_with_opencv(tmp_path / "intrinsics.yml", ["D1"])["D1"]
    np.testing.assert_array_equal(D1, np.zeros((1, 5)))


def _project(X: np.ndarray, K: np.ndarray, D: np.ndarray) -> np.ndarray:
    pts, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, D)
    return pts.reshape(-1, 2)


@pytest.mark.parametrize("D_left", [(), (-0.08, 0.02, 0.0005, -0.0004, 0.003)])
@pytest.mark.parametrize("T", [(-0.12, 0.0, 0.0), (-0.12, 0.004, -0.01)])
def test_points_rectified_with_written_files_share_rows(tmp_path, D_left, T):
    rig = known_rig(D_left, T)
    write_calibration(tmp_path, rig, formats=("opencv",))
    intr = load_with_opencv(tmp_path / "intrinsics.yml", ["M1", "D1", "M2", "D2"])
    extr = load_with_opencv(tmp_path / "extrinsics.yml", ["R", "T", "R1", "R2", "P1", "P2", "Q"])

    rng = np.random.default_rng(7)
    X_left = np.column_stack([rng.uniform(-1.5, 1.5, 200), rng.uniform(-1, 1, 200), rng.uniform(2, 10, 200)])
    X_right = X_left @ rig.R.T + rig.T
    x_left = _project(X_left, rig.K_left, rig.dist_left)
    x_right = _project(X_right, rig.K_right, rig.dist_right)

    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)

    def rectify(x, K, D, R, P):
        return cv2.undistortPoints(x.reshape(-1, 1, 2), K, D, R=R, P=P, criteria=criteria).reshape(-1, 2)

    r_left = rectify(x_left, intr["M1"], intr["D1"], extr["R1"], extr["P1"])
    r_right = rectify(x_right, intr["M2"], intr["D2"], extr["R2"], extr["P2"])
    assert np.abs(r_left[:, 1] - r_right[:, 1]).max() < 0.01

    # Q maps (x, y, disparity) to the point in the rectified left camera, so depth comes back
    disparity = r_left[:, 0] - r_right[:, 0]
    X_h = np.column_stack([r_left, disparity, np.ones(len(r_left))]) @ extr["Q"].T
    depth = X_h[:, 2] / X_h[:, 3]
    np.testing.assert_allclose(depth, (X_left @ extr["R1"].T)[:, 2], rtol=1e-6)

    # The remap tables of the written files send a rectified pixel back to its original pixel
    size = rig.image_size_left
    K, D, R1, P1 = intr["M1"], intr["D1"], extr["R1"], extr["P1"]
    map_x, map_y = cv2.initUndistortRectifyMap(K, D, R1, P1, size, cv2.CV_32FC1)
    u, v = np.round(r_left[:20]).astype(int).T
    inside = (u >= 0) & (u < size[0]) & (v >= 0) & (v < size[1])
    source = np.column_stack([map_x[v[inside], u[inside]], map_y[v[inside], u[inside]]]).astype(np.float64)
    back = rectify(source, K, D, R1, P1)
    np.testing.assert_allclose(back, np.column_stack([u[inside], v[inside]]), atol=2e-3)
    assert inside.sum() > 10
