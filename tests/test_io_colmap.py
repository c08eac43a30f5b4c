"""COLMAP cameras.txt: models, parameters, the +0.5 pixel-centre shift."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from stereogeo_cli.geometry import intrinsic_matrix
from stereogeo_cli.io import StereoCalibration, write_calibration

GOLDEN = Path(__file__).parent / "golden"


def _read_cameras(path: Path) -> dict[int, tuple[str, int, int, list[float]]]:
    cameras = {}
    for line in path.read_text().splitlines():
        if line.startswith("#"):
            continue
        cam_id, model, w, h, *params = line.split()
        cameras[int(cam_id)] = (model, int(w), int(h), [float(p) for p in params])
    return cameras


def test_golden_cameras():
    text = (GOLDEN / "cameras.txt").read_text()
    assert text.startswith("# Camera list with one line of data per camera:\n")
    assert "# Number of cameras: 2\n" in text
    cams = _read_cameras(GOLDEN / "cameras.txt")
    assert cams[1] == ("OPENCV", 640, 480, [500.0, 500.0, 320.5, 240.5, -0.05, 0.012, 0.0004, -0.0003])
    model, w, h, params = cams[2]
    assert (model, w, h) == ("FULL_OPENCV", 800, 600)
    assert params == [620.5, 620.5, 401.75, 300.25, 0.02, -0.01, 0.0, 0.0, 0.001, 0.0, 0.0, 0.0]


def test_pinhole_without_distortion(tmp_path):
    calib = StereoCalibration.from_report(json.loads((GOLDEN / "report.json").read_text()))
    K_left = intrinsic_matrix(512.25, 640, 480)
    calib = dataclasses.replace(calib, K_left=K_left, D_left=np.zeros(0), D_right=np.zeros(5))
    write_calibration(tmp_path, calib, formats=("colmap",))
    cams = _read_cameras(tmp_path / "cameras.txt")
    assert cams[1] == ("PINHOLE", 640, 480, [512.25, 512.25, 320.5, 240.5])
    assert cams[2] == ("PINHOLE", 800, 600, [620.5, 620.5, 401.75, 300.25])
