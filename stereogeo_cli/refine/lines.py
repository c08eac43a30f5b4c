"""Vertical line segments as up-direction measurements for the refiner.

The network's up field is blurred by its stride and its training; a straight vertical edge in the image
(a door frame, a pole, a shelf's side) gives the up direction at its location to a fraction of a degree.
A segment found by OpenCV's line segment detector counts as vertical when it lies within ``angle_deg`` of
the network's up field where it is; the camera is fitted to the fields and these segments together, the
segments are chosen again against the fitted camera (``refit_angle_deg``) and the camera fitted again.

The segments set the gravity only. Where verticals converge tells the focal length only together with the
pitch, and a lens's distortion bends them the same way, so the focal length stays the fields' (refined by
the matches). The pipeline takes the distortion the matches show out of the segments first
(``stereogeo_cli/pipeline.py``; docs/refine.md, "Vertical lines").
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from stereogeo_cli.geometry.camera import principal_point
from stereogeo_cli.geometry.fields import up_at
from stereogeo_cli.refine.lm import CameraFit, FieldSamples, refine_camera
from stereogeo_cli.settings import resolve

default_conf = {
    "enabled": True,
    # the detector runs on the image reduced to at most this short side (the validation renders' 240 px;
    # 448 takes 20 ms more per image; EuRoC's roll / pitch read 1.60° / 0.85° at 448, 1.75° / 1.05° at 320
    # and 2.31° / 0.99° at 256, within the noise of its 8 views: docs/refine.md, "What was tried and
    # measured")
    "max_short_side": 256,
    "min_length_px": 10.0,  # shortest segment used, in network-input pixels
    "angle_deg": 5.0,  # a segment this close to the network's up field counts as vertical
    "refit_angle_deg": 3.0,  # ... and this close to the up field of the camera fitted with them
    # weight per network-input pixel of segment length (a field sample of full confidence weighs 1)
    "weight": 7.5,
    # (roll, pitch): multiply the 1-sigma figures of a gravity fitted with segments, which the refiner's
    # sigma_inflation (the fields' own) overstates: the factors that put 68 % of the validation set's errors
    # within 1 sigma after calibrate shares gravity between the cameras (docs/refine.md, "Uncertainty")
    "sigma_scale": (0.12, 0.33),
    # degrees: how far one segment taken as vertical may stand from the true vertical (a slanted edge, the
    # detector's angle), independently of the others; added in quadrature to the gravity's 1 sigma divided
    # by √(segments used), so that a few segments cannot pin the gravity however long they are
    # (docs/refine.md, "Uncertainty")
    "segment_sigma_deg": 3.0,
}


@dataclass(frozen=True)
class VerticalSegments:
    """Segments taken as vertical: midpoints, unit directions pointing up, lengths (network-input px)."""

    x: np.ndarray
    y: np.ndarray
    direction: np.ndarray  # [N x 2], image axes (x right, y down), oriented along the up field
    length: np.ndarray

    def __len__(self) -> int:
        return len(self.x)

    def observations(self, weight: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``refine_camera``'s ``line_up``: (x, y, up direction, weight) per segment."""
        return self.x, self.y, self.direction, weight * self.length


def detect_segments(
    image_rgb: np.ndarray, max_short_side: int = default_conf["max_short_side"]
) -> np.ndarray:
    """Line segments [N x 4] (x1, y1, x2, y2) of an RGB image, in its pixels.

    The detector runs on a copy resized down to at most ``max_short_side`` (its time grows with the pixels).
    """
    image = np.asarray(image_rgb)
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    height, width = grey.shape[:2]
    scale = min(1.0, max_short_side / min(width, height))
    if scale < 1.0:
        size = (max(1, round(width * scale)), max(1, round(height * scale)))
        grey = cv2.resize(grey, size, interpolation=cv2.INTER_AREA)
        sx, sy = size[0] / width, size[1] / height
    else:
        sx = sy = 1.0
    found = cv2.createLineSegmentDetector().detect(grey)[0]
    if found is None:
        return np.zeros((0, 4))
    ends = found.reshape(-1, 2, 2).astype(float)
    return ((ends + 0.5) / np.array([sx, sy]) - 0.5).reshape(-1, 4)  # detector pixels → image pixels


def detector_pixel(width: int, height: int, max_short_side: int) -> float:
    """The size, in image pixels, of a pixel of the image ``detect_segments`` runs the detector on."""
    return max(1.0, min(width, height) / max_short_side)


def vertical_segments(
    segments: np.ndarray,
    reference_up: Callable[[np.ndarray, np.ndarray], np.ndarray],
    image_size: tuple[int, int],
    min_length: float,
    angle_deg: float,
) -> VerticalSegments:
    """The segments within ``angle_deg`` of ``reference_up(x, y)`` (unit up vectors [N x 2]) at their
    midpoints, at least ``min_length`` long and with the midpoint inside the image, oriented upwards."""
    seg = np.asarray(segments, dtype=float).reshape(-1, 4)
    d = seg[:, 2:] - seg[:, :2]
    length = np.linalg.norm(d, axis=1)
    mid = 0.5 * (seg[:, :2] + seg[:, 2:])
    width, height = image_size
    keep = (
        (length >= max(min_length, 1e-9))
        & (mid[:, 0] >= 0) & (mid[:, 0] <= width - 1) & (mid[:, 1] >= 0) & (mid[:, 1] <= height - 1)
    )  # fmt: skip
    d, length, mid = d[keep] / length[keep, None], length[keep], mid[keep]
    ref = np.asarray(reference_up(mid[:, 0], mid[:, 1]), dtype=float).reshape(-1, 2)
    ref = ref / np.maximum(np.linalg.norm(ref, axis=1, keepdims=True), 1e-12)
    cosine = np.sum(d * ref, axis=1)
    vertical = np.abs(cosine) >= np.cos(np.radians(angle_deg))
    direction = d[vertical] * np.sign(cosine[vertical])[:, None]
    return VerticalSegments(mid[vertical, 0], mid[vertical, 1], direction, length[vertical])


def field_sampler(up: np.ndarray, pixel_xy: tuple[np.ndarray, np.ndarray]) -> Callable:
    """reference_up(x, y) reading a field [h x w x 2] at the cell nearest to each point (regular grid)."""
    xs, ys = (np.asarray(a, dtype=float) for a in pixel_xy)
    h, w = xs.shape
    x0, y0 = xs[0, 0], ys[0, 0]
    step_x = (xs[0, -1] - x0) / max(w - 1, 1) or 1.0
    step_y = (ys[-1, 0] - y0) / max(h - 1, 1) or 1.0

    def sample(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        j = np.clip(np.round((x - x0) / step_x).astype(int), 0, w - 1)
        i = np.clip(np.round((y - y0) / step_y).astype(int), 0, h - 1)
        return up[i, j]

    return sample


def camera_sampler(fit: CameraFit) -> Callable:
    """reference_up(x, y): the up field of a fitted camera (pixels of the image it was fitted on)."""
    cx, cy = principal_point(fit.width, fit.height)

    def sample(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return up_at(fit.gravity_up, fit.focal_px, x, y, cx, cy)

    return sample


@dataclass(frozen=True)
class LineGravity:
    """The gravity a camera's fields and vertical segments give together."""

    gravity_up: np.ndarray  # [3] unit world-UP in camera coordinates
    covariance: np.ndarray  # [2 x 2] of (δ_pitch, δ_roll·cos(pitch)), the refiner's first two parameters
    segments: int  # vertical segments used


def gravity_with_lines(
    up: np.ndarray,
    latitude: np.ndarray,
    up_confidence: np.ndarray,
    latitude_confidence: np.ndarray,
    segments: np.ndarray,
    *,
    image_size: tuple[int, int],
    pixel_xy: tuple[np.ndarray, np.ndarray] | None,
    focal_prior=None,
    samples: FieldSamples | None = None,
    start: tuple[np.ndarray, float] | None = None,
    conf: dict | None = None,
    refine_conf: dict | None = None,
) -> LineGravity | None:
    """One camera's gravity from its fields and its vertical segments (module docstring); None when no
    segment is vertical.

    ``segments`` [N x 4] (pinhole: lens distortion taken out) and ``pixel_xy`` (None: one field cell per
    pixel) are in the pixels of ``image_size``. The focal length is fitted along (``focal_prior`` as in
    ``refine_camera``) but not returned: the segments' bend is no evidence of it (module docstring).
    ``samples``: the fields' samples, where the caller has them (``refine_camera``). ``start``: (up
    vector, focal length in the fields' pixels) of a fit the caller has (the fields' own): the first fit
    starts there instead of from the fields' rough read.
    """
    conf = resolve(default_conf, conf)
    if pixel_xy is None:
        h, w = np.shape(latitude)
        pixel_xy = tuple(np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float)))
    fields = (up, latitude, up_confidence, latitude_confidence)
    common = {
        "image_size": image_size, "pixel_xy": pixel_xy, "focal_prior": focal_prior, "samples": samples,
        "conf": refine_conf,
    }  # fmt: skip
    found = vertical_segments(
        segments, field_sampler(up, pixel_xy), image_size, conf["min_length_px"], conf["angle_deg"]
    )
    if len(found) == 0:
        return None
    gravity_init, focal_init = (None, None) if start is None else start
    first = refine_camera(
        *fields, line_up=found.observations(conf["weight"]), gravity_init=gravity_init, focal_init=focal_init,
        **common,
    )  # fmt: skip
    found = vertical_segments(
        segments, camera_sampler(first), image_size, conf["min_length_px"], conf["refit_angle_deg"]
    )
    if len(found) == 0:
        return None
    joint = refine_camera(
        *fields, line_up=found.observations(conf["weight"]), gravity_init=first.gravity_up,
        focal_init=first.focal_px, **common,
    )  # fmt: skip
    roll_scale, pitch_scale = np.broadcast_to(np.asarray(conf["sigma_scale"], dtype=float), (2,))
    scale = np.array([pitch_scale, roll_scale])  # in the order of the refiner's parameters
    spread = np.radians(conf["segment_sigma_deg"]) ** 2 / len(found)
    covariance = joint.covariance[:2, :2] * np.outer(scale, scale) + spread * np.eye(2)
    return LineGravity(joint.gravity_up, covariance, len(found))
