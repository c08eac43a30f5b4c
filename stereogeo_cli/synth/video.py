"""The H.264 round trip of a sequence's frames: encode one camera's frames to an MP4 file, decode it back.

OpenCV's VideoWriter has no software H.264 encoder in the opencv-python wheels (only MPEG-4 part 2,
``mp4v``), so the encoder is libx264 through PyAV (``av``, part of the training extra; its wheels ship
FFmpeg with libx264). Settings: yuv420p (4:2:0 chroma, as every camera and phone records), x264's
"medium" preset, average bitrate ``kbps``, a key frame every two seconds, and one encoder thread, so the
same frames give the same bytes on any machine. An image with an odd width or height is padded by its last
column or row (4:2:0 needs even sizes) and cropped back after decoding. OpenCV's VideoCapture reads the
files (``calibrate-sequence --video left.mp4 right.mp4``).
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np

from stereogeo_cli.errors import StereoGeoError

PRESET = "medium"
KEYFRAME_S = 2.0


def _require_av():
    try:
        import av
    except ImportError as error:  # pragma: no cover - depends on the installation
        raise StereoGeoError(
            "--h264 needs PyAV (libx264): pip install av, or the training extra: "
            "pip install 'stereogeo[train]'"
        ) from error
    return av


def bits_per_pixel_kbps(bits_per_pixel: float, width: int, height: int, rate_hz: float) -> float:
    """The bitrate in kbit/s that spends ``bits_per_pixel`` bits on each pixel of each frame (≈ 0.1–0.2 for
    dash cams and phones: 8–16 Mbit/s at 1920 × 1080 and 30 Hz)."""
    return bits_per_pixel * width * height * rate_hz / 1000.0


class H264Writer:
    """One camera's frames, in order, into an H.264 MP4 file at an average bitrate (kbit/s)."""

    def __init__(self, path: Path, width: int, height: int, rate_hz: float, kbps: float):
        av = _require_av()
        self.av = av
        self.size = (width, height)
        self.container = av.open(str(path), mode="w", format="mp4")
        rate = Fraction(rate_hz if rate_hz > 0 else 10.0).limit_denominator(1000)
        stream = self.container.add_stream("libx264", rate=rate)
        stream.width, stream.height = width + width % 2, height + height % 2
        stream.pix_fmt = "yuv420p"
        stream.bit_rate = int(round(kbps * 1000))
        stream.codec_context.gop_size = max(1, int(round(KEYFRAME_S * float(rate))))
        stream.codec_context.thread_count = 1
        stream.options = {"preset": PRESET}
        self.stream = stream

    def add(self, image: np.ndarray) -> None:
        """Encode the next frame, an [H x W x 3] uint8 RGB image."""
        w, h = self.size
        if image.shape[:2] != (h, w):
            raise StereoGeoError(f"internal: a {image.shape[1]}×{image.shape[0]} frame in a {w}×{h} video")
        padded = np.pad(image, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
        frame = self.av.VideoFrame.from_ndarray(np.ascontiguousarray(padded), format="rgb24")
        for packet in self.stream.encode(frame):
            self.container.mux(packet)

    def close(self) -> None:
        for packet in self.stream.encode():  # flush the frames the encoder still holds
            self.container.mux(packet)
        self.container.close()


def read_h264(path: Path, width: int, height: int):
    """The frames of a video written by :class:`H264Writer`, in order: [H x W x 3] uint8 RGB arrays."""
    av = _require_av()
    with av.open(str(path)) as container:
        for frame in container.decode(video=0):
            yield np.ascontiguousarray(frame.to_ndarray(format="rgb24")[:height, :width])
