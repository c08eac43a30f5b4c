"""Frame sources of ``calibrate-sequence``: timestamped left/right image pairs from a folder, videos or a bag.

Every source yields :class:`FramePair` objects — an index, a time in seconds, a short name and the two
images as H x W x 3 uint8 RGB — one pair in memory at a time, and can be iterated more than once.
:func:`open_source` picks the kind from its arguments and checks what it can before returning (the path
exists, a video opens and has a first frame, a bag has the topics and matching stamps, the first pair
decodes), so that a bad input fails at once rather than after a long run.

- **Folder**: the layouts of ``batch-calibrate`` (:func:`~stereogeo_cli.io.pairs.discover_pairs`:
  ``left/`` + ``right/``, ``cam0/`` + ``cam1/``, ``*_left``/``*_right``, ``*_L``/``*_R``), in natural sort
  order. Images are read with :func:`~stereogeo_cli.io.images.load_image`, exactly as ``calibrate`` reads
  them (EXIF orientation, 16-bit, grey). Names without a partner are left out (listed in ``warnings``).
  The time of the pair at position k of the folder (counted before subsampling) is k / ``fps`` seconds
  when ``fps`` is given — for a folder ``fps`` is its frame rate and drops no frame — else k.
- **Two videos** (``video=(LEFT, RIGHT)``): read with OpenCV, paired by frame number, ending with the
  shorter video. The time is the left video's frame time (``CAP_PROP_POS_MSEC`` where it increases, else
  frame number / the video's frame rate; the frame number itself when the video has no frame rate).
- **Side-by-side video** (``sbs=VIDEO``): the left half of each frame is the left image, the right half the
  right image; the width must be even.
- **ROS bag**: a ROS 1 ``.bag`` file, or a ROS 2 bag — its folder (with ``metadata.yaml``) or an ``.mcap`` /
  ``.db3`` file (the whole bag is read when the file lies in a bag folder) — read with ``rosbags``, no ROS
  install needed. ``left_topic`` and ``right_topic`` carry ``sensor_msgs/Image`` (encodings
  :data:`RAW_ENCODINGS`) or ``sensor_msgs/CompressedImage`` (any format ``cv2.imdecode`` reads). Left and
  right messages are paired by header stamp: a left and a right message form a pair when each is the
  other's nearest in time and the stamps differ by at most ``tolerance_s``; other messages are dropped
  (counted in ``warnings``). When every stamp of a topic is zero (a driver that fills no header), the bag's
  recording times are used instead. The time is the left message's stamp (seconds since the epoch).

Subsampling, after pairing, in the source's order: ``every=N`` keeps frames 0, N, 2N, ... (numbered in the
video, the folder, or the bag's matched pairs); ``fps=F`` (videos and bags) keeps a frame when at least
0.95 / F seconds have passed since the last kept one (the 5 % absorbs a camera's timing jitter, so that
F = 15 keeps every other frame of a 30 Hz camera); ``max_frames=M`` stops after M pairs. ``every`` and
``fps`` cannot be combined for videos and bags.

Every frame of one camera must have the size of its first frame (the two cameras may differ). Frames must
be at least :data:`~stereogeo_cli.io.images.MIN_SIDE` pixels on a side. Every problem raises
:class:`~stereogeo_cli.errors.StereoGeoError` (exit code 2) with one line naming the file.
"""

from __future__ import annotations

import bisect
import math
import os
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.io.images import MIN_SIDE, _to_uint8, load_image
from stereogeo_cli.io.pairs import discover_pairs
from stereogeo_cli.io.text import plural

FPS_SLACK = 0.05  # share of 1/fps by which kept frames may come early (camera timing jitter)
STAMP_TOLERANCE_S = 0.01  # a bag's left and right stamps pair within this (cameras triggered together)
BAG_SUFFIXES = (".bag", ".mcap", ".db3")
IMAGE_MSGTYPE = "sensor_msgs/msg/Image"
COMPRESSED_MSGTYPE = "sensor_msgs/msg/CompressedImage"

# sensor_msgs/Image encoding -> (channels, bytes per channel, OpenCV conversion to RGB; "": none)
_ENCODINGS = {
    "mono8": (1, 1, "GRAY2RGB"),
    "mono16": (1, 2, "GRAY2RGB"),
    "rgb8": (3, 1, ""),
    "bgr8": (3, 1, "BGR2RGB"),
    "rgba8": (4, 1, "RGBA2RGB"),
    "bgra8": (4, 1, "BGRA2RGB"),
    "rgb16": (3, 2, ""),
    "bgr16": (3, 2, "BGR2RGB"),
    "rgba16": (4, 2, "RGBA2RGB"),
    "bgra16": (4, 2, "BGRA2RGB"),
    **{
        f"bayer_{pattern}{bits}": (1, bits // 8, f"Bayer{pattern.upper()}2RGB")
        for pattern in ("rggb", "bggr", "gbrg", "grbg")
        for bits in (8, 16)
    },
    "yuv422": (2, 1, "YUV2RGB_UYVY"),
    "uyvy": (2, 1, "YUV2RGB_UYVY"),
    "yuv422_yuy2": (2, 1, "YUV2RGB_YUYV"),
    "yuyv": (2, 1, "YUV2RGB_YUYV"),
    "8UC1": (1, 1, "GRAY2RGB"),  # OpenCV's types, as cv_bridge writes them: colour in BGR order
    "8UC3": (3, 1, "BGR2RGB"),
    "8UC4": (4, 1, "BGRA2RGB"),
    "16UC1": (1, 2, "GRAY2RGB"),
}
RAW_ENCODINGS = tuple(_ENCODINGS)  # the sensor_msgs/Image encodings read (in any letter case)
_RAW = {name.lower(): value for name, value in _ENCODINGS.items()}
_RAW_LISTED = (
    "mono8/16, rgb8/16, bgr8/16, rgba8/16, bgra8/16, bayer_rggb/bggr/gbrg/grbg 8/16, yuv422, "
    "yuv422_yuy2, 8UC1/3/4, 16UC1"
)


# ---------------------------------------------------------------------------------------------- the API


@dataclass(frozen=True, eq=False)
class FramePair:
    """One stereo pair of a sequence.

    ``index``: 0, 1, 2, ... in the order yielded (after subsampling). ``time``: seconds (a video's frame
    time, a bag's left header stamp, a folder's position / fps or position). ``name``: a short name (a
    folder's pair name; ``frame_000123`` with the frame's number in the video or on the bag's left topic).
    ``left``, ``right``: [H x W x 3] uint8 RGB; the two may differ in size.
    """

    index: int
    time: float
    name: str
    left: np.ndarray
    right: np.ndarray


class FrameSource:
    """Base of the sources: iterate for :class:`FramePair` objects (re-iterable, one pair in memory).

    ``description``: one line for the user (``folder seq/ (50 pairs)``). ``warnings``: what was left out
    and why, one line each (unmatched names, unpaired bag messages, videos of different lengths).
    """

    description: str = ""

    def __init__(self) -> None:
        self.warnings: list[str] = []

    def count(self) -> int | None:
        """Pairs that iterating will yield (after subsampling and ``max_frames``), or None when unknown.

        Exact for folders and bags; for videos it relies on the frame count the container states.
        """
        return None

    def __iter__(self) -> Iterator[FramePair]:
        raise NotImplementedError


def open_source(
    path: str | os.PathLike | None = None,
    *,
    video: tuple[str | os.PathLike, str | os.PathLike] | None = None,
    sbs: str | os.PathLike | None = None,
    left_topic: str | None = None,
    right_topic: str | None = None,
    every: int = 1,
    fps: float | None = None,
    max_frames: int | None = None,
    tolerance_s: float | None = None,
) -> FrameSource:
    """The frames of a folder or bag (``path``), two videos (``video``) or a side-by-side video (``sbs``).

    ``left_topic``/``right_topic``: a bag's image topics (required for bags, refused otherwise).
    ``every``: keep every N-th frame; ``fps``: frames per second to keep at most (videos, bags) or the
    folder's frame rate (folders); ``max_frames``: at most this many pairs; ``tolerance_s``: largest stamp
    difference (s) of a bag's left and right messages that still pair (bags only; default
    :data:`STAMP_TOLERANCE_S`). Rules in the module docstring.

    Checks the input and reads the first pair before returning; raises :class:`StereoGeoError` (exit code 2).
    """
    given = [
        name for name, value in (("a path", path), ("--video", video), ("--sbs", sbs)) if value is not None
    ]
    if not given:
        raise StereoGeoError("no frames given: give a folder, a bag, --video LEFT RIGHT or --sbs VIDEO")
    if len(given) > 1:
        raise StereoGeoError(
            f"give only one of a folder or bag, --video and --sbs (got {' and '.join(given)})"
        )
    if not isinstance(every, int) or every < 1:
        raise StereoGeoError(f"--every must be a whole number of at least 1, got {every}")
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise StereoGeoError(f"--fps must be a positive number of frames per second, got {fps}")
    if max_frames is not None and max_frames < 1:
        raise StereoGeoError(f"--max-frames must be at least 1, got {max_frames}")
    if tolerance_s is not None and not (math.isfinite(tolerance_s) and tolerance_s >= 0):
        raise StereoGeoError(f"--stamp-tolerance must be 0 s or more, got {tolerance_s}")

    bag = None
    if path is not None:
        path = Path(path)
        if not path.exists():
            raise StereoGeoError(f"not found: {path}")
        bag = _bag_path(path)
        if bag is None and path.is_file():
            raise StereoGeoError(
                f"{path} is not a folder of image pairs or a bag ({', '.join(BAG_SUFFIXES)}); "
                "for videos give --video LEFT RIGHT or --sbs VIDEO"
            )
    if bag is None and (left_topic is not None or right_topic is not None):
        raise StereoGeoError("--left-topic and --right-topic are for bags only")
    if bag is None and tolerance_s is not None:
        raise StereoGeoError(
            "--stamp-tolerance is for bags only: folders and videos pair their frames by name or number"
        )
    if bag is None and path is not None:
        return FolderSource(path, every=every, fps=fps, max_frames=max_frames)
    if every > 1 and fps is not None:
        raise StereoGeoError("give --every or --fps, not both: both choose which frames to keep")
    if bag is not None:
        return BagSource(
            path,
            bag,
            left_topic,
            right_topic,
            every=every,
            fps=fps,
            max_frames=max_frames,
            tolerance_s=STAMP_TOLERANCE_S if tolerance_s is None else tolerance_s,
        )
    if video is not None:
        if isinstance(video, str | os.PathLike) or len(video) != 2:
            raise StereoGeoError("--video takes two files, the left and the right camera's video")
        return VideoSource((Path(video[0]), Path(video[1])), every=every, fps=fps, max_frames=max_frames)
    return VideoSource((Path(sbs),), every=every, fps=fps, max_frames=max_frames)


# --------------------------------------------------------------------------------------------- helpers


class _Selector:
    """Decides, frame by frame in source order, which frames subsampling keeps."""

    def __init__(self, every: int, min_gap_s: float | None, max_frames: int | None):
        self.every, self.min_gap_s, self.max_frames = every, min_gap_s, max_frames
        self.kept = 0
        self.last_time: float | None = None

    @property
    def full(self) -> bool:
        return self.max_frames is not None and self.kept >= self.max_frames

    def keep(self, number: int, time: float) -> bool:
        if self.full or number % self.every:
            return False
        if (
            self.min_gap_s is not None
            and self.last_time is not None
            and time - self.last_time < self.min_gap_s
        ):
            return False
        self.kept += 1
        self.last_time = time
        return True


def _min_gap(fps: float | None) -> float | None:
    return None if fps is None else (1.0 - FPS_SLACK) / fps


class _SizeCheck:
    """Holds a camera's frames to the size of its first frame; ``what`` names the camera in messages."""

    def __init__(self, what: str):
        self.what = what
        self.size: tuple[int, int] | None = None
        self.first: str | None = None

    def __call__(self, width: int, height: int, frame: str) -> None:
        if self.size is None:
            if min(width, height) < MIN_SIDE:
                raise StereoGeoError(
                    f"{self.what}: {frame} is too small ({width}x{height} pixels); each side needs at least "
                    f"{MIN_SIDE}"
                )
            self.size, self.first = (width, height), frame
        elif (width, height) != self.size:
            w0, h0 = self.size
            raise StereoGeoError(
                f"{self.what}: {frame} is {width}x{height} pixels but {self.first} is {w0}x{h0}; every frame "
                "of a camera must have the same size"
            )


def _to_rgb(image: np.ndarray, what: str) -> np.ndarray:
    """A decoded OpenCV image (grey, BGR or BGRA; 8 or 16 bit) as [H x W x 3] uint8 RGB, like load_image."""
    import cv2

    image = _to_uint8(image, what)
    if image.ndim == 2 or image.shape[2] == 1:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2RGB)
    if image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2RGB)
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


# ---------------------------------------------------------------------------------------------- folders


class FolderSource(FrameSource):
    """The pairs of a folder in ``batch-calibrate``'s layouts, read one pair at a time with load_image."""

    def __init__(
        self, folder: Path, *, every: int = 1, fps: float | None = None, max_frames: int | None = None
    ):
        super().__init__()
        self.folder = folder
        entries = discover_pairs(folder)
        self.warnings += [f"{folder}: {e.problem}; left out" for e in entries if e.problem is not None]
        pairs = [e for e in entries if e.problem is None]
        self.description = f"folder {folder} ({plural(len(pairs), 'pair')})"
        selector = _Selector(every, None, max_frames)
        # (ordinal in the folder, entry): the ordinal gives the time, so that subsampling keeps times true
        self._pairs = [(k, e) for k, e in enumerate(pairs) if selector.keep(k, k)]
        self._fps = fps
        for path in (self._pairs[0][1].left, self._pairs[0][1].right):
            load_image(path)  # read now: an unreadable first pair fails before a long run

    def count(self) -> int:
        return len(self._pairs)

    def __iter__(self) -> Iterator[FramePair]:
        checks = _SizeCheck(f"{self.folder} (left images)"), _SizeCheck(f"{self.folder} (right images)")
        for index, (k, entry) in enumerate(self._pairs):
            images = []
            for path, check in zip((entry.left, entry.right), checks, strict=True):
                image = load_image(path)
                check(image.shape[1], image.shape[0], path.name)
                images.append(image)
            time = k / self._fps if self._fps else float(k)
            yield FramePair(index, time, entry.name, images[0], images[1])


# ----------------------------------------------------------------------------------------------- videos


def _open_capture(path: Path):
    import cv2

    if not path.exists():
        raise StereoGeoError(f"video not found: {path}")
    if not path.is_file():
        raise StereoGeoError(f"{path} is a folder, not a video")
    # FFmpeg prints its own complaints about a broken file on stderr; the error raised below says it in
    # one line. Read when OpenCV first opens a video; a value the user set is kept.
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    try:
        capture = cv2.VideoCapture(str(path))
    finally:
        cv2.utils.logging.setLogLevel(level)
    if not capture.isOpened():
        if path.stat().st_size == 0:
            raise StereoGeoError(f"cannot read video {path}: it is empty (0 bytes)")
        raise StereoGeoError(f"cannot read video {path}: not a video, or a format OpenCV cannot decode")
    return capture


def _nominal_fps(capture) -> float | None:
    import cv2

    fps = capture.get(cv2.CAP_PROP_FPS)
    return fps if math.isfinite(fps) and 0 < fps < 10_000 else None


class _Clock:
    """A video's frame times (s): the container's where they increase, else from the frame rate."""

    def __init__(self, fps: float | None):
        self.fps = fps
        self.previous: float | None = None

    def __call__(self, capture, number: int) -> float:
        import cv2

        ms = capture.get(cv2.CAP_PROP_POS_MSEC)
        if math.isfinite(ms) and ms >= 0 and (self.previous is None or ms / 1000 > self.previous):
            time = ms / 1000
        else:
            step = 1 / self.fps if self.fps else 1.0
            time = number * step if self.fps else float(number)
            if self.previous is not None and time <= self.previous:
                time = self.previous + step
        self.previous = time
        return time


class VideoSource(FrameSource):
    """Two videos paired by frame number (``paths`` = (left, right)), or a side-by-side video (``(sbs,)``)."""

    def __init__(
        self,
        paths: tuple[Path, ...],
        *,
        every: int = 1,
        fps: float | None = None,
        max_frames: int | None = None,
    ):
        import cv2

        super().__init__()
        self.paths = paths
        self.sbs = len(paths) == 1
        self.every, self.fps, self.max_frames = every, fps, max_frames
        if self.sbs:
            self.description = f"side-by-side video {paths[0]}"
        else:
            self.description = f"videos {paths[0]} + {paths[1]}"
        lengths, rates = [], []
        captures = [_open_capture(p) for p in paths]
        try:
            for path, capture in zip(paths, captures, strict=True):
                ok, frame = capture.read()
                if not ok or frame is None:
                    raise StereoGeoError(f"cannot read video {path}: OpenCV decodes no frame from it")
                n = capture.get(cv2.CAP_PROP_FRAME_COUNT)
                lengths.append(int(n) if math.isfinite(n) and n > 0 else None)
                rates.append(_nominal_fps(capture))
                height, width = frame.shape[:2]
                if self.sbs and width % 2:
                    raise StereoGeoError(
                        f"{path} is {width} pixels wide, an odd number: a side-by-side video holds two "
                        "halves of equal width"
                    )
                halves = (width // 2, width // 2) if self.sbs else (width,)
                for i, w in enumerate(halves):
                    side = f" ({('left', 'right')[i]} half)" if self.sbs else ""
                    _SizeCheck(f"{path}{side}")(w, height, "frame 0")
        finally:
            for capture in captures:
                capture.release()
        self._fps_nominal = rates[0]
        if not self.sbs:
            if all(lengths) and lengths[0] != lengths[1]:
                self.warnings.append(
                    f"{paths[0]} has {plural(lengths[0], 'frame')} and {paths[1]} {lengths[1]}: "
                    "the pairs end with the shorter video"
                )
            if all(rates) and abs(rates[0] - rates[1]) > 1e-3 * rates[0]:
                self.warnings.append(
                    f"{paths[0]} runs at {rates[0]:g} fps and {paths[1]} at {rates[1]:g} fps; frames are "
                    "paired by number all the same"
                )
        if self._fps_nominal is None:
            self.warnings.append(f"{paths[0]} states no frame rate; frame times are frame numbers")
        self._lengths = lengths
        self._length = None if None in lengths else min(lengths)

    def count(self) -> int | None:
        if self._length is None:
            return None
        if self.fps is None:
            n = -(-self._length // self.every)
            return n if self.max_frames is None else min(n, self.max_frames)
        if self._fps_nominal is None:
            return None
        selector = _Selector(self.every, _min_gap(self.fps), self.max_frames)
        return sum(selector.keep(k, k / self._fps_nominal) for k in range(self._length))

    def _note_short(self, frames: int, grabbed: list[bool]) -> None:
        """Warn where a video (one whose frame ``frames`` could not be ``grabbed``) ends before the frame
        count its header declares: a file cut short (a recording stopped uncleanly, a partial copy), so
        the sequence is shorter than the file says."""
        for path, declared, more in zip(self.paths, self._lengths, grabbed, strict=True):
            if not more and declared is not None and frames < declared:
                warning = (
                    f"{path} ends after {plural(frames, 'frame')} though its header declares {declared}: "
                    "the file may be truncated, and the sequence is that much shorter"
                )
                if warning not in self.warnings:
                    self.warnings.append(warning)

    def __iter__(self) -> Iterator[FramePair]:
        captures = [_open_capture(p) for p in self.paths]
        try:
            yield from self._frames(captures)
        finally:
            for capture in captures:
                capture.release()

    def _frames(self, captures) -> Iterator[FramePair]:
        selector = _Selector(self.every, _min_gap(self.fps), self.max_frames)
        clock = _Clock(self._fps_nominal)
        if self.sbs:
            checks = [_SizeCheck(f"{self.paths[0]} (left half)"), _SizeCheck(f"{self.paths[0]} (right half)")]
        else:
            checks = [_SizeCheck(str(p)) for p in self.paths]
        number = 0
        while not selector.full:
            # grab() without retrieve() skips the colour conversion of frames that are not kept
            grabbed = [capture.grab() for capture in captures]
            if not all(grabbed):
                self._note_short(number, grabbed)
                return
            time = clock(captures[0], number)
            if selector.keep(number, time):
                name = f"frame_{number:06d}"
                frames = []
                for path, capture in zip(self.paths, captures, strict=True):
                    ok, frame = capture.retrieve()
                    if not ok or frame is None:
                        raise StereoGeoError(f"cannot read video {path}: frame {number} does not decode")
                    frames.append(frame)
                if self.sbs:
                    half = frames[0].shape[1] // 2
                    frames = [frames[0][:, :half], frames[0][:, half:]]
                images = []
                for frame, check in zip(frames, checks, strict=True):
                    check(frame.shape[1], frame.shape[0], name)
                    images.append(_to_rgb(np.ascontiguousarray(frame), name))
                yield FramePair(selector.kept - 1, time, name, images[0], images[1])
            number += 1


# ------------------------------------------------------------------------------------------------- bags


def _bag_path(path: Path) -> Path | None:
    """What to hand rosbags for ``path``: a .bag file, a ROS 2 bag folder or lone storage file; else None."""
    if path.is_dir():
        return path if (path / "metadata.yaml").is_file() else None
    suffix = path.suffix.lower()
    if suffix == ".bag":
        return path
    if suffix in (".mcap", ".db3"):
        # a file of a bag folder: read the folder, so that every file of a split bag is read
        return path.parent if (path.parent / "metadata.yaml").is_file() else path
    return None


@dataclass(frozen=True)
class _Message:
    """What the first pass over a bag keeps of one image message."""

    number: int  # position on its topic, in the bag's order
    stamp_ns: int  # header stamp (or recording time when the topic has no stamps)
    log_ns: int
    width: int | None  # raw images only
    height: int | None
    encoding: str  # raw: the encoding; compressed: the format


class BagSource(FrameSource):
    """Left and right image topics of a ROS 1 or ROS 2 bag, paired by header stamp."""

    def __init__(
        self,
        given: Path,
        bag: Path,
        left_topic: str | None,
        right_topic: str | None,
        *,
        every: int = 1,
        fps: float | None = None,
        max_frames: int | None = None,
        tolerance_s: float = STAMP_TOLERANCE_S,
    ):
        super().__init__()
        self.given, self.bag = given, bag
        topics = self._image_topics()
        listed = ", ".join(f"{t} ({m.rsplit('/', 1)[-1]})" for t, m in sorted(topics.items())) or "none"
        if left_topic is None or right_topic is None:
            raise StereoGeoError(
                f"{given} is a bag: give --left-topic and --right-topic; its image topics: {listed}"
            )
        if left_topic == right_topic:
            raise StereoGeoError(f"--left-topic and --right-topic are the same topic ({left_topic})")
        for topic in (left_topic, right_topic):
            if topic not in self._all_topics:
                raise StereoGeoError(f"{given} has no topic {topic}; its image topics: {listed}")
            if topic not in topics:
                raise StereoGeoError(
                    f"{given}: topic {topic} carries {self._all_topics[topic]}, not images "
                    f"(sensor_msgs/Image or CompressedImage); its image topics: {listed}"
                )
        self.topics = (left_topic, right_topic)
        self.msgtypes = (topics[left_topic], topics[right_topic])
        self.description = f"bag {given} ({left_topic} + {right_topic})"

        messages = self._scan()
        for topic, found in zip(self.topics, messages, strict=True):
            if not found:
                raise StereoGeoError(f"{given}: topic {topic} has no messages")
        if any(all(m.stamp_ns == 0 for m in found) for found in messages):
            self.warnings.append(f"{given}: header stamps are zero; pairing by the bag's recording times")
            messages = [[replace(m, stamp_ns=m.log_ns) for m in found] for found in messages]
        pairs = _pair_by_stamp(messages[0], messages[1], round(tolerance_s * 1e9))
        if not pairs:
            raise StereoGeoError(
                f"{given}: no left message of {left_topic} has a right message of {right_topic} within "
                f"{tolerance_s:g} s ({_offset_hint(messages[0], messages[1])}); --stamp-tolerance widens it"
            )
        unpaired = len(messages[0]) - len(pairs), len(messages[1]) - len(pairs)
        if any(unpaired):
            self.warnings.append(
                f"{given}: {unpaired[0]} of {len(messages[0])} left and {unpaired[1]} of {len(messages[1])} "
                f"right messages have no partner within {tolerance_s:g} s; left out (--stamp-tolerance "
                "widens it)"
            )
        selector = _Selector(every, _min_gap(fps), max_frames)
        self._pairs = [p for k, p in enumerate(pairs) if selector.keep(k, p[0].stamp_ns / 1e9)]
        self.description += f", {plural(len(pairs), 'pair')}"
        self._check_frames()
        frames = iter(self)
        next(frames, None)  # decode the first pair now: a bad format fails before a long run
        frames.close()

    def count(self) -> int:
        return len(self._pairs)

    def _reader(self):
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore

        is_ros1 = self.bag.suffix.lower() == ".bag"
        # used only when the bag carries no message definitions (a lone .db3 file)
        store = get_typestore(Stores.ROS1_NOETIC if is_ros1 else Stores.LATEST)
        return AnyReader([self.bag], default_typestore=store)

    def _image_topics(self) -> dict[str, str]:
        try:
            with self._reader() as reader:
                self._all_topics = {
                    name: info.msgtype or "several types" for name, info in reader.topics.items()
                }
        except StereoGeoError:
            raise
        except Exception as exc:  # rosbags raises many kinds for a damaged bag
            raise StereoGeoError(f"cannot read bag {self.given}: {_one_line(exc)}") from None
        return {t: m for t, m in self._all_topics.items() if m in (IMAGE_MSGTYPE, COMPRESSED_MSGTYPE)}

    def _messages(self, reader) -> Iterator[tuple[int, int, str, int, bytes]]:
        """(side 0/1, number on its topic, message type, recording time (ns), data) in the bag's order."""
        connections = [c for c in reader.connections if c.topic in self.topics]
        counters = [0, 0]
        messages = reader.messages(connections=connections)
        while True:
            try:
                connection, log_ns, raw = next(messages)
            except StopIteration:
                return
            except Exception as exc:  # rosbags raises many kinds for a damaged bag
                raise StereoGeoError(f"cannot read bag {self.given}: {_one_line(exc)}") from None
            side = self.topics.index(connection.topic)
            counters[side] += 1
            yield side, counters[side] - 1, connection.msgtype, log_ns, raw

    def _deserialize(self, reader, raw: bytes, msgtype: str, side: int, number: int):
        try:
            return reader.deserialize(raw, msgtype)
        except Exception as exc:
            what = f"{self.topics[side]} frame {number}"
            raise StereoGeoError(f"cannot read bag {self.given}: {what}: {_one_line(exc)}") from None

    def _scan(self) -> list[list[_Message]]:
        """First pass: every message's stamp and size (raw images), without decoding any image."""
        found: list[list[_Message]] = [[], []]
        with self._reader() as reader:
            for side, number, msgtype, log_ns, raw in self._messages(reader):
                msg = self._deserialize(reader, raw, msgtype, side, number)
                stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                if msgtype == IMAGE_MSGTYPE:
                    size, encoding = (msg.width, msg.height), msg.encoding
                else:
                    size, encoding = (None, None), msg.format
                found[side].append(_Message(number, stamp, log_ns, *size, encoding))
        return found

    def _check_frames(self) -> None:
        """Encodings and sizes of the kept frames, known from the first pass for raw images."""
        for side, (topic, msgtype) in enumerate(zip(self.topics, self.msgtypes, strict=True)):
            check = _SizeCheck(f"{self.given}: {topic}")
            for pair in self._pairs:
                m = pair[side]
                if msgtype == IMAGE_MSGTYPE:
                    if m.encoding.lower() not in _RAW:
                        raise StereoGeoError(_encoding_message(self.given, topic, m))
                    check(m.width, m.height, f"frame {m.number}")
                elif "compresseddepth" in m.encoding.lower():
                    raise StereoGeoError(
                        f"{self.given}: {topic} carries depth images ({m.encoding!r}), not camera images"
                    )

    def __iter__(self) -> Iterator[FramePair]:
        # Second pass: the kept pairs' messages, held as bytes until both of a pair have been read (a
        # pair's left and right are usually recorded close together), yielded in stamp order.
        wanted = {(side, pair[side].number) for pair in self._pairs for side in (0, 1)}
        held: dict[tuple[int, int], tuple[str, bytes]] = {}
        checks = [_SizeCheck(f"{self.given}: {topic}") for topic in self.topics]
        following = 0
        with self._reader() as reader:
            for side, number, msgtype, _, raw in self._messages(reader):
                if (side, number) not in wanted:
                    continue
                held[side, number] = (msgtype, raw)
                while following < len(self._pairs):
                    keys = [(s, self._pairs[following][s].number) for s in (0, 1)]
                    if not all(k in held for k in keys):
                        break
                    images = []
                    for s, n in keys:
                        msgtype, data = held.pop((s, n))
                        msg = self._deserialize(reader, data, msgtype, s, n)
                        image = _decode_message(msg, msgtype, f"{self.given}: {self.topics[s]} frame {n}")
                        checks[s](image.shape[1], image.shape[0], f"frame {n}")
                        images.append(image)
                    left = self._pairs[following][0]
                    yield FramePair(following, left.stamp_ns / 1e9, f"frame_{left.number:06d}", *images)
                    following += 1
                if following == len(self._pairs):
                    return


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


def _pair_by_stamp(left: list[_Message], right: list[_Message], tolerance_ns: int) -> list[tuple]:
    """(left, right) messages that are each other's nearest in stamp, within the tolerance; by left stamp."""
    left = sorted(left, key=lambda m: m.stamp_ns)
    right = sorted(right, key=lambda m: m.stamp_ns)
    left_stamps = [m.stamp_ns for m in left]
    right_stamps = [m.stamp_ns for m in right]

    def nearest(stamps: list[int], t: int) -> int:
        i = bisect.bisect_left(stamps, t)
        if i == len(stamps) or (i > 0 and t - stamps[i - 1] <= stamps[i] - t):
            return i - 1
        return i

    pairs = []
    for i, m in enumerate(left):
        j = nearest(right_stamps, m.stamp_ns)
        if abs(right_stamps[j] - m.stamp_ns) <= tolerance_ns and nearest(left_stamps, right_stamps[j]) == i:
            pairs.append((m, right[j]))
    return pairs


def _offset_hint(left: list[_Message], right: list[_Message]) -> str:
    """Where the two topics' stamps lie, for the message of a bag without a single pair."""
    right_stamps = sorted(m.stamp_ns for m in right)
    gaps = []
    for m in left:
        i = bisect.bisect_left(right_stamps, m.stamp_ns)
        gaps += [abs(right_stamps[j] - m.stamp_ns) for j in (i - 1, i) if 0 <= j < len(right_stamps)]
    return f"the nearest stamps are {min(gaps) / 1e9:.3g} s apart"


def _encoding_message(given: Path, topic: str, m: _Message) -> str:
    return (
        f"{given}: {topic} frame {m.number} has image encoding {m.encoding!r}, which stereogeo does not read "
        f"(it reads {_RAW_LISTED})"
    )


def _decode_message(msg, msgtype: str, what: str) -> np.ndarray:
    """A sensor_msgs Image or CompressedImage as [H x W x 3] uint8 RGB; ``what`` names it in messages."""
    import cv2

    data = np.asarray(msg.data, dtype=np.uint8)
    if msgtype == COMPRESSED_MSGTYPE:
        image = cv2.imdecode(data, cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR) if data.size else None
        if image is None or image.size == 0:
            raise StereoGeoError(f"{what}: cannot decode its {msg.format!r} data")
        return _to_rgb(image, what)
    encoding = msg.encoding.lower()
    if encoding not in _RAW:
        raise StereoGeoError(f"{what} has image encoding {msg.encoding!r}, which stereogeo does not read")
    channels, depth, conversion = _RAW[encoding]
    height, width, step = msg.height, msg.width, msg.step
    row = width * channels * depth
    if step < row or data.size < height * step:
        raise StereoGeoError(
            f"{what}: {data.size} bytes of data (step {step}) cannot hold {width}x{height} {msg.encoding}"
        )
    image = np.ascontiguousarray(data[: height * step].reshape(height, step)[:, :row])
    if depth == 2:
        image = image.view(">u2" if msg.is_bigendian else "<u2").astype(np.uint16)
    image = image.reshape(height, width, channels) if channels > 1 else image.reshape(height, width)
    if conversion:
        image = cv2.cvtColor(image, getattr(cv2, f"COLOR_{conversion}"))
    return _to_uint8(image, what)
