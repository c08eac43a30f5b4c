"""What makes real recordings harder than clean renders, for sequences: each effect is off by default.

A rendered sequence with every effect off is an ideal camera: fx = fy, the principal point at the image
centre, lossless frames, constant exposure, no motion blur and a world that holds still. Real drives are
none of that, and a calibration that reads renders to 0.05 % may read them several per cent off. Each
effect below can be switched on alone (docs/synth.md, "Sequences: effects of real recordings"):

- ``principal_offset``: the principal point moved by (dx·w, dy·h) from (w/2, h/2), the same in both
  cameras (a rectified rig); ``"random"`` draws dx, dy uniform within ±3 % from the seed.
- ``focal_aspect``: fy = fx · aspect (non-square pixels, or a rectification that scaled one axis).
- ``h264_kbps``: the frames go through an H.264 encode and decode at this bitrate (libx264 through PyAV,
  :mod:`stereogeo_cli.synth.video`) before they are written as PNG; ``keep_video`` keeps the two videos.
- ``exposure_stops``: the gain drifts smoothly over the sequence by up to ± this many stops (auto-exposure
  passing from sun to shade), with the right camera's own drift of a tenth of that and a little flicker.
- ``motion_blur_ms``: each frame is the mean of sub-frame renders over an exposure of this many
  milliseconds centred on the frame's time (the ground-truth pose is the one at mid-exposure).
- ``moving_objects``: this many cars and people that move on their own between frames
  (:mod:`stereogeo_cli.synth.traffic`).

Every effect draws from its own random stream, so switching one on leaves every other draw of a seed
(scene, rig, path, photometry) as it was.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import cv2
import numpy as np

from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.synth.rigs import Rig

PRINCIPAL_LIMIT = 0.03  # largest principal-point offset, as a fraction of the image width or height
ASPECT_LIMITS = (0.95, 1.05)  # fy / fx accepted
BLUR_SUBFRAMES = 8  # renders averaged into one motion-blurred frame
MAX_MOVERS = 40
_STREAM = 0xEFF  # random streams of the effects: [seed, 0x5E9, motion, _STREAM, effect]


@dataclass(frozen=True)
class SequenceEffects:
    """The effects of real recordings on a sequence; the defaults switch all of them off."""

    principal_offset: tuple[float, float] | str | None = None  # (dx, dy) fractions of (w, h), or "random"
    focal_aspect: float = 1.0  # fy / fx
    h264_kbps: float | None = None  # H.264 round trip at this bitrate, kbit/s
    keep_video: bool = False  # keep left.mp4 and right.mp4 (needs h264_kbps)
    exposure_stops: float = 0.0  # peak gain drift, stops (0: constant exposure)
    motion_blur_ms: float = 0.0  # exposure time of the motion blur, milliseconds (0: sharp)
    moving_objects: int = 0  # cars and people moving on their own

    def __post_init__(self):
        offset = self.principal_offset
        checks = [
            (
                offset is None
                or offset == "random"
                or (len(offset) == 2 and all(abs(float(v)) <= PRINCIPAL_LIMIT + 1e-12 for v in offset)),
                f"--principal-offset: dx and dy must be within ±{PRINCIPAL_LIMIT:g} (fractions of the size)",
            ),
            (
                ASPECT_LIMITS[0] <= self.focal_aspect <= ASPECT_LIMITS[1],
                f"--focal-aspect must be within {ASPECT_LIMITS[0]:g}–{ASPECT_LIMITS[1]:g}",
            ),
            (self.h264_kbps is None or self.h264_kbps > 0, "--h264: the bitrate must be > 0 kbit/s"),
            (not self.keep_video or self.h264_kbps is not None, "--keep-video needs --h264 KBPS"),
            (0 <= self.exposure_stops <= 3, "--exposure-changes must be within 0–3 stops"),
            (0 <= self.motion_blur_ms <= 200, "--motion-blur must be within 0–200 ms"),
            (0 <= self.moving_objects <= MAX_MOVERS, f"--moving-objects must be within 0–{MAX_MOVERS}"),
        ]
        for ok, message in checks:
            if not ok:
                raise StereoGeoError(message)

    @property
    def active(self) -> bool:
        return self != SequenceEffects()

    def to_json(self, seed: int) -> dict:
        """The effects that are on, as calib.json's ``extra.effects`` (a random offset as drawn)."""
        out = {k: v for k, v in asdict(self).items() if v != getattr(SequenceEffects(), k)}
        if self.principal_offset is not None:
            out["principal_offset"] = list(self.offset(seed))  # fractions of (w, h), as drawn
            out["principal_offset_random"] = self.principal_offset == "random"
        return out

    def offset(self, seed: int) -> tuple[float, float]:
        """(dx, dy): the principal point's offset as fractions of (w, h); (0, 0) when off."""
        if self.principal_offset is None:
            return 0.0, 0.0
        if self.principal_offset == "random":
            rng = np.random.default_rng([seed, 0x5E9, _STREAM, 1])
            return tuple(float(v) for v in rng.uniform(-PRINCIPAL_LIMIT, PRINCIPAL_LIMIT, 2))
        return float(self.principal_offset[0]), float(self.principal_offset[1])

    def changes_intrinsics(self) -> bool:
        return self.principal_offset is not None or self.focal_aspect != 1.0


def parse_principal_offset(text: str | None) -> tuple[float, float] | str | None:
    """ "0.02,-0.01" → (0.02, -0.01); "random" → "random"; None → None."""
    if text is None:
        return None
    if text.strip().lower() == "random":
        return "random"
    try:
        dx, dy = (float(v) for v in text.split(","))
    except ValueError:
        raise StereoGeoError(
            f"--principal-offset: cannot read {text!r}; write DX,DY (fractions of the width and height, "
            "e.g. 0.02,-0.01) or random"
        ) from None
    return dx, dy


def with_intrinsics(rig: Rig, effects: SequenceEffects, seed: int) -> Rig:
    """The rig with the effects' principal point and fy / fx in both cameras (a rig unchanged when off)."""
    if not effects.changes_intrinsics():
        return rig
    dx, dy = effects.offset(seed)

    def camera(cam):
        principal = (cam.width / 2.0 + dx * cam.width, cam.height / 2.0 + dy * cam.height)
        return replace(cam, aspect=float(effects.focal_aspect), principal=principal)

    return Rig(camera(rig.left), camera(rig.right))


def _drift(rng: np.random.Generator, t: np.ndarray, duration: float) -> np.ndarray:
    """A smooth curve over the times ``t`` [N] (seconds) of peak |value| 1: three sinusoids with periods
    from a fifth of the sequence to twice it (at least 0.5 s), so a short and a long sequence both drift."""
    span = max(duration, 0.5)
    periods = rng.uniform(span / 5, 2 * span, 3)
    phases, weights = rng.uniform(0, 2 * np.pi, 3), rng.uniform(0.4, 1.0, 3)

    def curve(x: np.ndarray) -> np.ndarray:
        return sum(
            w * np.sin(2 * np.pi * x / p + f) for p, f, w in zip(periods, phases, weights, strict=True)
        )

    return curve(t) / max(float(np.max(np.abs(curve(np.linspace(0.0, span, 512))))), 1e-9)


def exposure_gains(seed: int, motion_index: int, times: np.ndarray, stops: float) -> np.ndarray | None:
    """Per-frame gains [N x 2] (left, right) of the exposure drift, or None when it is off: the left gain
    drifts by up to ±``stops`` stops, the right one follows it with a drift of its own of up to a tenth of
    that, and each frame of each camera flickers by 1 % of ``stops`` (σ, in stops)."""
    if stops <= 0:
        return None
    rng = np.random.default_rng([seed, 0x5E9, motion_index, _STREAM, 2])
    times = np.asarray(times, dtype=float)
    duration = float(times.max()) if len(times) else 0.0
    left = stops * _drift(rng, times, duration)
    right = left + 0.1 * stops * _drift(rng, times, duration)
    flicker = rng.normal(0.0, 0.01 * stops, (len(times), 2))
    return np.exp2(np.stack([left, right], 1) + flicker)


def apply_gain(image: np.ndarray, gain: float) -> np.ndarray:
    """An [H x W x 3] uint8 image scaled by ``gain`` (saturating at 255, as a sensor does)."""
    lut = np.clip(np.arange(256, dtype=np.float64) * gain + 0.5, 0, 255).astype(np.uint8)
    return cv2.LUT(image, lut)


def subframe_times(t: float, blur_ms: float, count: int = BLUR_SUBFRAMES) -> np.ndarray:
    """The times [count] (seconds) of the sub-frames averaged into the frame at ``t``: the middles of
    ``count`` equal parts of an exposure of ``blur_ms`` milliseconds centred on ``t``."""
    tau = blur_ms / 1000.0
    return t + tau * ((np.arange(count) + 0.5) / count - 0.5)


def mean_image(images: list[np.ndarray]) -> np.ndarray:
    """The rounded mean of uint8 images [H x W x 3] (the exposure integrating over the sub-frames)."""
    total = np.zeros(images[0].shape, np.float32)
    for image in images:
        total += image
    return np.clip(total / len(images) + 0.5, 0, 255).astype(np.uint8)
