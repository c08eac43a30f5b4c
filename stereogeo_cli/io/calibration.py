"""The calibration of a stereo rig as the writers and the JSON report see it, and its rectification.

Conventions, the same in every output file (docs/io.md, "Output files"): OpenCV camera frame (x right,
y down, z forward), pixel (0, 0) at the centre of the top-left pixel, ``X_right = R @ X_left + T`` with T
in metres. Image sizes are (width, height) in pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from stereogeo_cli.errors import CalibrationFailed, StereoGeoError
from stereogeo_cli.geometry import roll_pitch_from_gravity, vfov_from_focal

SIGMA_KEYS = ("focal_px", "vfov_deg", "roll_deg", "pitch_deg")
_REPORT_KEYS = (
    "left",
    "right",
    "R",
    "T",
    "baseline_m",
    "scale_source",
    "matches",
    "timing_ms",
    "model",
    "notes",
)
_DIST_LENGTHS = (0, 4, 5, 8)  # OpenCV models we write: none, k1 k2 p1 p2 [k3 [k4 k5 k6]]


@dataclass(frozen=True, eq=False)  # eq on arrays would be ambiguous
class StereoCalibration:
    """A calibrated stereo pair.

    Required: ``K_left``, ``K_right`` [3 x 3] (pixels); ``image_size_left``, ``image_size_right``
    (width, height) in pixels; ``R`` [3 x 3] and ``T`` [3] (metres) with ``X_right = R @ X_left + T``.
    ``D_left``, ``D_right``: OpenCV distortion ``k1 k2 p1 p2 [k3 [k4 k5 k6]]`` (0, 4, 5 or 8 values); empty
    or None means none (written as five zeros). The rest feeds ``report.json`` only: ``gravity_*`` the up
    vector [3] in camera coordinates, ``sigma_*`` 1-sigma of ``focal_px``, ``vfov_deg``, ``roll_deg``,
    ``pitch_deg``. Array fields accept anything ``np.array`` takes (lists, 3x1 for T).

    Arrays are converted to float64 and checked on construction; the object is frozen (derive a changed
    one with ``dataclasses.replace``, which checks again).
    """

    K_left: np.ndarray
    K_right: np.ndarray
    image_size_left: tuple[int, int]
    image_size_right: tuple[int, int]
    R: np.ndarray
    T: np.ndarray
    D_left: np.ndarray = field(default_factory=lambda: np.zeros(0))
    D_right: np.ndarray = field(default_factory=lambda: np.zeros(0))
    gravity_left: np.ndarray | None = None
    gravity_right: np.ndarray | None = None
    sigma_left: dict[str, float | None] | None = None
    sigma_right: dict[str, float | None] | None = None
    scale_source: str = "learned"  # "learned" | "baseline"
    matches_found: int = 0
    matches_inliers: int = 0
    timing_ms: dict[str, float] = field(default_factory=dict)
    model_file: str | None = None
    model_sha256: str | None = None
    notes: str = ""
    extra_report: dict[str, Any] = field(default_factory=dict)  # more report keys (never overriding one)

    def __post_init__(self) -> None:
        def put(name: str, value: Any) -> None:
            object.__setattr__(self, name, value)

        for name, shape in (("K_left", (3, 3)), ("K_right", (3, 3)), ("R", (3, 3)), ("T", (3,))):
            put(name, _matrix(getattr(self, name), shape, name))
        for name in ("D_left", "D_right"):
            D = getattr(self, name)
            put(name, _matrix([] if D is None else D, None, name).ravel())
            n = getattr(self, name).size
            if n not in _DIST_LENGTHS:
                raise ValueError(f"{name} must have 0, 4, 5 or 8 coefficients, got {n}")
        for name in ("image_size_left", "image_size_right"):
            put(name, _size(getattr(self, name), name))
        for name in ("gravity_left", "gravity_right"):
            if getattr(self, name) is not None:
                put(name, _matrix(getattr(self, name), (3,), name))
        for name in ("K_left", "K_right"):
            K = getattr(self, name)
            if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.array_equal(K[2], [0.0, 0.0, 1.0]):
                raise ValueError(f"{name} is not a camera matrix: {K.tolist()}")
        if np.abs(self.R @ self.R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(self.R) < 0:
            raise ValueError(f"R is not a rotation matrix: {self.R.tolist()}")
        if np.linalg.norm(self.T) == 0:
            raise ValueError("T must not be zero: a stereo rig needs a baseline")
        if self.scale_source not in ("learned", "baseline"):
            raise ValueError(f"scale_source must be 'learned' or 'baseline', got {self.scale_source!r}")

    @property
    def dist_left(self) -> np.ndarray:
        """D_left as written to the files: 5 values (k1 k2 p1 p2 k3, zeros when there is none) or 8."""
        return _written_dist(self.D_left)

    @property
    def dist_right(self) -> np.ndarray:
        """D_right as written to the files, see :attr:`dist_left`."""
        return _written_dist(self.D_right)

    @property
    def baseline_m(self) -> float:
        """|T| in metres."""
        return float(np.linalg.norm(self.T))

    def to_report(self) -> dict[str, Any]:
        """The JSON report (docs/io.md, "report.json"): per camera its size, K, focal length, vFoV, roll,
        pitch, up vector, sigmas and ``dist``; then R, T, the baseline, the scale's source, the matches, the
        timings, the model and ``notes``; then the keys of ``extra_report`` that none of these take."""
        return {
            "left": _camera_report(
                self.K_left, self.D_left, self.image_size_left, self.gravity_left, self.sigma_left
            ),
            "right": _camera_report(
                self.K_right, self.D_right, self.image_size_right, self.gravity_right, self.sigma_right
            ),
            "R": self.R.tolist(),
            "T": self.T.tolist(),
            "baseline_m": self.baseline_m,
            "scale_source": self.scale_source,
            "matches": {"found": int(self.matches_found), "inliers": int(self.matches_inliers)},
            "timing_ms": {"total": None, **{k: _finite_or_none(v) for k, v in self.timing_ms.items()}},
            "model": {"file": self.model_file, "sha256": self.model_sha256},
            "notes": self.notes,
        } | {k: v for k, v in self.extra_report.items() if k not in _REPORT_KEYS}

    @classmethod
    def from_report(cls, report: dict[str, Any]) -> StereoCalibration:
        """Inverse of :meth:`to_report`. A malformed report raises :class:`StereoGeoError` (exit code 2)."""
        try:
            left, right = report["left"], report["right"]
            timing = {k: float(v) for k, v in report.get("timing_ms", {}).items() if v is not None}
            matches = report.get("matches") or {}
            model = report.get("model") or {}
            return cls(
                K_left=np.array(left["K"], dtype=float),
                K_right=np.array(right["K"], dtype=float),
                image_size_left=(left["width"], left["height"]),
                image_size_right=(right["width"], right["height"]),
                R=np.array(report["R"], dtype=float),
                T=np.array(report["T"], dtype=float),
                D_left=np.array(left.get("dist") or [], dtype=float),
                D_right=np.array(right.get("dist") or [], dtype=float),
                gravity_left=_optional_vector(left.get("gravity_up")),
                gravity_right=_optional_vector(right.get("gravity_up")),
                sigma_left=left.get("sigma"),
                sigma_right=right.get("sigma"),
                scale_source=report.get("scale_source", "learned"),
                matches_found=int(matches.get("found") or 0),
                matches_inliers=int(matches.get("inliers") or 0),
                timing_ms=timing,
                model_file=model.get("file"),
                model_sha256=model.get("sha256"),
                notes=report.get("notes") or "",
            )
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise StereoGeoError(f"invalid calibration report: {type(exc).__name__}: {exc}") from None


@dataclass(frozen=True)
class Rectification:
    """``cv2.stereoRectify`` output: R1, R2 [3 x 3], P1, P2 [3 x 4], Q [4 x 4], for images of ``size``."""

    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    Q: np.ndarray
    size: tuple[int, int]  # (width, height) of both rectified images


def rectify(calibration: StereoCalibration, alpha: float = 0.0) -> Rectification:
    """Rectification of the rig with ``cv2.stereoRectify(..., flags=CALIB_ZERO_DISPARITY, alpha)``.

    Both rectified images have the **left** image's size (OpenCV takes one size for both cameras). When the
    right image is larger or smaller, its rectified view is still exact — rows line up and Q holds — but
    ``alpha`` (0: only valid pixels, 1: all source pixels) is judged as if it had the left image's size.
    """
    import cv2

    c = calibration
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
        c.K_left,
        c.dist_left,
        c.K_right,
        c.dist_right,
        c.image_size_left,
        c.R,
        c.T.reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY,
        alpha=float(alpha),
        newImageSize=c.image_size_left,
    )
    rect = Rectification(R1, R2, P1, P2, Q, c.image_size_left)
    for name in ("R1", "R2", "P1", "P2", "Q"):
        if not np.isfinite(getattr(rect, name)).all():
            raise CalibrationFailed(f"stereo rectification failed: {name} is not finite")
    return rect


def _matrix(value: Any, shape: tuple[int, ...] | None, name: str) -> np.ndarray:
    array = np.array(value, dtype=np.float64)
    if shape is not None and array.shape != shape:
        try:
            array = array.reshape(shape)
        except ValueError:
            raise ValueError(f"{name} must have shape {shape}, got {array.shape}") from None
    if not np.isfinite(array).all():
        raise CalibrationFailed(f"the calibration is not finite: {name} = {array.tolist()}")
    return array


def _size(value: Any, name: str) -> tuple[int, int]:
    w, h = (int(v) for v in value)
    if w < 1 or h < 1:
        raise ValueError(f"{name} must be (width, height) > 0, got {value}")
    return w, h


def _written_dist(D: np.ndarray) -> np.ndarray:
    # Readers of OpenCV/ROS files expect at least k1 k2 p1 p2 k3; zeros mean no distortion.
    return np.concatenate([D, np.zeros(5 - D.size)]) if D.size < 5 else D.copy()


def _finite_or_none(value: Any) -> float | None:
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def _optional_vector(value: Any) -> np.ndarray | None:
    return None if value is None else np.array(value, dtype=float)


def _camera_report(
    K: np.ndarray,
    D: np.ndarray,
    size: tuple[int, int],
    gravity: np.ndarray | None,
    sigma: dict[str, float | None] | None,
) -> dict[str, Any]:
    width, height = size
    focal = 0.5 * (K[0, 0] + K[1, 1])
    if gravity is None:
        roll_deg = pitch_deg = None
    else:
        roll, pitch = roll_pitch_from_gravity(gravity)
        roll_deg, pitch_deg = math.degrees(float(roll)), math.degrees(float(pitch))
    sigma = sigma or {}
    return {
        "width": width,
        "height": height,
        "K": K.tolist(),
        "focal_px": float(focal),
        "vfov_deg": math.degrees(float(vfov_from_focal(K[1, 1], height))),
        "roll_deg": roll_deg,
        "pitch_deg": pitch_deg,
        "gravity_up": None if gravity is None else gravity.tolist(),
        "sigma": {k: _finite_or_none(sigma.get(k)) for k in SIGMA_KEYS},
        "dist": D.tolist(),
    }
