"""OpenCV ``intrinsics.yml`` (M1 D1 M2 D2) and ``extrinsics.yml`` (R T R1 R2 P1 P2 Q).

The text is what OpenCV 4's ``cv::FileStorage`` writes for the ``stereo_calib`` sample, byte for byte:
the ``%YAML:1.0`` header, ``!!opencv-matrix`` nodes, numbers as ``%.16e`` (integers as ``500.``) and the
flow list wrapped at column 71 with a 7-space continuation indent. It is emitted here rather than by
``cv2.FileStorage`` because OpenCV 5 changed the header (``%YAML 1.2``), the number format and the tag of
1-D arrays; this output reads back identically with both, to the exact float64 values.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from stereogeo_cli.io.calibration import Rectification, StereoCalibration

_WRAP_MARGIN = 71  # FileStorage's wrap column for flow sequences
_MATRIX_INDENT = 3  # indent of rows/cols/dt/data under the matrix key
_FLOW_INDENT = 7  # continuation indent of the data list: 3 + 3 + 1 in FileStorage's YAML emitter


def format_opencv_double(value: float) -> str:
    """One double as FileStorage's YAML writer prints it (OpenCV ≤ 4): ``500.``, ``-1.2000000000000000e-01``.

    17 significant digits, so the text parses back to the same float64.
    """
    value = float(value)
    if math.isnan(value):
        return ".Nan"
    if math.isinf(value):
        return ".Inf" if value > 0 else "-.Inf"
    if abs(value) < 2**31 and value == round(value):  # cvRound(value) == value
        return f"{int(value)}."
    return f"{value:.16e}"


def opencv_matrix_yaml(
    name: str, matrix: np.ndarray, number: Callable[[float], str] = format_opencv_double
) -> str:
    """One ``name: !!opencv-matrix`` node of a 2-D float64 matrix [rows x cols], with a trailing newline.

    ``number`` formats one value; the default is OpenCV 4's. (Tests pass OpenCV 5's to compare the layout
    with ``cv2.FileStorage``.)
    """
    matrix = np.asarray(matrix, dtype=np.float64)
    if matrix.ndim != 2:
        raise ValueError(f"{name}: expected a 2-D matrix, got shape {matrix.shape}")
    rows, cols = matrix.shape
    pad = " " * _MATRIX_INDENT
    lines = [f"{name}: !!opencv-matrix", f"{pad}rows: {rows}", f"{pad}cols: {cols}", f"{pad}dt: d"]
    line = f"{pad}data: ["
    first = True
    for value in matrix.ravel():
        text = number(value)
        if not first:
            line += ","
        # FileStorage breaks the line when the item would end past the margin (and the line is not short)
        end = len(line) + len(text)
        if end > _WRAP_MARGIN and end - _FLOW_INDENT > 10:
            lines.append(line)
            line = " " * _FLOW_INDENT + text
        else:
            line += " " + text
        first = False
    line += " ]" if not first else "]"
    lines.append(line)
    return "\n".join(lines) + "\n"


def opencv_document(matrices: dict[str, np.ndarray]) -> str:
    """A whole ``.yml`` file: header, then the matrices in the given order."""
    return "%YAML:1.0\n---\n" + "".join(opencv_matrix_yaml(k, v) for k, v in matrices.items())


def render_opencv(calibration: StereoCalibration, rect: Rectification) -> dict[str, str]:
    """``{"intrinsics.yml": text, "extrinsics.yml": text}`` as the ``stereo_calib`` sample writes them.

    M 3×3, D 1×N, R 3×3, T 3×1 (metres), R1/R2 3×3, P1/P2 3×4, Q 4×4.
    """
    c = calibration
    intrinsics = {
        "M1": c.K_left,
        "D1": c.dist_left.reshape(1, -1),
        "M2": c.K_right,
        "D2": c.dist_right.reshape(1, -1),
    }
    extrinsics = {
        "R": c.R,
        "T": c.T.reshape(3, 1),
        "R1": rect.R1,
        "R2": rect.R2,
        "P1": rect.P1,
        "P2": rect.P2,
        "Q": rect.Q,
    }
    return {"intrinsics.yml": opencv_document(intrinsics), "extrinsics.yml": opencv_document(extrinsics)}
