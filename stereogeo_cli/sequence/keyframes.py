"""Keyframes of a sequence: the frames whose motion tells the adjustment something, chosen by optical flow.

A first pass over the source tracks a few hundred corners of the left image, at reduced resolution, from
the last kept frame to each new frame (:func:`cv2.calcOpticalFlowPyrLK`, checked forward and back). The
median flow of the tracked corners, as a share of the image's larger side, is the motion since that
frame. A frame is kept when:

- the flow reaches ``parallax_rel`` (the views differ enough to triangulate from); or
- it reaches ``rotation_rel`` and a homography explains the flow (at least ``homography_share`` of the
  tracks within ``homography_rel`` of the median flow): the rig turned, or looks at a far scene, and such
  views are what fix the focal length (a turn's views are related by K R K⁻¹), so they are kept densely; or
- fewer than ``min_tracked_share`` of the corners could be followed, or too few corners were found to
  measure (the view changed too much to tell: keep it, so that the frames stay connected).

A frame whose flow stays under ``still_rel`` is a near-duplicate of the last kept frame (the rig stood
still); one between that and the thresholds moved too little yet. The first frame is always kept, and
where nothing else was, the last too (a sequence needs two frames). Where more than ``max_kept`` frames
qualify, ``max_kept`` of them are kept, evenly spread over the recording.

The pass streams: it holds the last kept frame's small grey image and its corners, and the numbers of the
frames kept; :class:`KeyframeSource` then yields the kept frames in a second pass over the source.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from stereogeo_cli.io.text import plural
from stereogeo_cli.sequence.sources import FramePair, FrameSource
from stereogeo_cli.settings import resolve

default_conf = {
    "larger_side": 480,  # the left image is tracked at this larger side (never enlarged)
    "corners": 300,  # corners tracked from the last kept frame
    "still_rel": 0.001,  # median flow under this share of the larger side: the rig stood still
    "parallax_rel": 0.005,  # a frame is kept at this flow
    "rotation_rel": 0.0025,  # ... or at this one where a homography explains the flow (a turn)
    # a track fits the homography within this share of the median flow, and at least homography_min_px
    # (pixels at the tracked size: the tracking's own noise)
    "homography_rel": 0.1,
    "homography_min_px": 0.2,
    "homography_share": 0.8,  # share of the tracks that must fit for the flow to count as a turn
    "min_tracked_share": 0.5,  # fewer corners followed than this share: the frame is kept
    "min_corners": 20,  # fewer corners than this to follow: the frame is kept (nothing to measure)
    "max_kept": 150,  # at most this many frames kept, evenly spread
}

# why a frame was left out, the report's keys
LEFT_OUT = ("still", "little_motion", "cap")


@dataclass(frozen=True)
class Motion:
    """The flow from the last kept frame to one frame: median as a share of the larger side, whether a
    homography explains it, and the share of the corners followed (None: too few corners to measure)."""

    flow_rel: float
    rotational: bool
    tracked_share: float | None


@dataclass
class KeyframeChoice:
    """The outcome of the first pass: the numbers (0, 1, ... in the source's order) of the kept frames,
    the frames read, and how many were left out for each reason of :data:`LEFT_OUT`."""

    kept: list[int]
    read: int
    left_out: dict[str, int] = field(default_factory=lambda: dict.fromkeys(LEFT_OUT, 0))
    conf: dict = field(default_factory=dict)

    def notes(self) -> list[str]:
        """The report's warnings about the frames left out (the rig standing still, the cap)."""
        notes = []
        if self.left_out["still"]:
            notes.append(f"{plural(self.left_out['still'], 'frame')} left out: the rig stood still")
        if self.left_out["cap"]:
            notes.append(
                f"{plural(self.left_out['cap'], 'frame')} left out to keep at most {self.conf['max_kept']} "
                "keyframes, evenly spread"
            )
        return notes

    def to_report(self) -> dict:
        """The report's ``sequence.keyframes`` block (docs/sequence.md, "Outputs")."""
        keys = ("still_rel", "parallax_rel", "rotation_rel", "homography_rel", "homography_share", "max_kept")
        return {
            "rule": "motion",
            **{key: self.conf[key] for key in keys},
            "left_out": dict(self.left_out),
        }


class _Tracker:
    """The last kept frame's corners, and the flow from it to a new frame."""

    def __init__(self, conf: dict):
        self.conf = conf
        self.grey: np.ndarray | None = None
        self.corners: np.ndarray | None = None
        self.scale = 1.0

    def small(self, image: np.ndarray) -> np.ndarray:
        """The left image, grey, at the tracked size."""
        grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
        self.scale = min(1.0, self.conf["larger_side"] / max(grey.shape[:2]))
        if self.scale < 1.0:
            size = (round(grey.shape[1] * self.scale), round(grey.shape[0] * self.scale))
            grey = cv2.resize(grey, size, interpolation=cv2.INTER_AREA)
        return grey

    def keep(self, grey: np.ndarray) -> None:
        """``grey`` (from :meth:`small`) is the new reference: its corners are found."""
        self.grey = grey
        side = max(grey.shape[:2])
        corners = cv2.goodFeaturesToTrack(
            grey, self.conf["corners"], qualityLevel=0.01, minDistance=max(3, side // 80), blockSize=7
        )
        self.corners = None if corners is None else corners.astype(np.float32)

    def motion(self, grey: np.ndarray) -> Motion:
        """The flow from the reference to ``grey`` (same size)."""
        corners = self.corners
        if corners is None or len(corners) < self.conf["min_corners"]:
            return Motion(0.0, False, None)
        lk = {"winSize": (21, 21), "maxLevel": 3}
        moved, status, _ = cv2.calcOpticalFlowPyrLK(self.grey, grey, corners, None, **lk)
        back, status_back, _ = cv2.calcOpticalFlowPyrLK(grey, self.grey, moved, None, **lk)
        # a track counts where it was found both ways and comes back to within half a pixel
        good = (status.ravel() == 1) & (status_back.ravel() == 1)
        good &= np.linalg.norm((back - corners).reshape(-1, 2), axis=1) < 0.5
        share = float(good.mean())
        if good.sum() < self.conf["min_corners"]:
            return Motion(0.0, False, share)
        start, end = corners.reshape(-1, 2)[good], moved.reshape(-1, 2)[good]
        flow = float(np.median(np.linalg.norm(end - start, axis=1))) / max(grey.shape[:2])
        median_px = flow * max(grey.shape[:2])
        tolerance = max(self.conf["homography_min_px"], self.conf["homography_rel"] * median_px)
        _, inliers = cv2.findHomography(start, end, cv2.RANSAC, tolerance)
        fits = 0.0 if inliers is None else float(inliers.mean())
        return Motion(flow, fits >= self.conf["homography_share"], share)


def decide(motion: Motion, conf: dict) -> str | None:
    """Why a frame with this ``motion`` is left out (a key of :data:`LEFT_OUT`), or None: it is kept."""
    if motion.tracked_share is None or motion.tracked_share < conf["min_tracked_share"]:
        return None
    if motion.flow_rel >= conf["parallax_rel"]:
        return None
    if motion.rotational and motion.flow_rel >= conf["rotation_rel"]:
        return None
    return "still" if motion.flow_rel < conf["still_rel"] else "little_motion"


def spread(kept: list[int], most: int) -> list[int]:
    """At most ``most`` of ``kept`` (sorted), evenly spread over them, the first and the last included."""
    if len(kept) <= most:
        return list(kept)
    if most == 1:
        return kept[:1]
    chosen = np.round(np.linspace(0, len(kept) - 1, most)).astype(int)
    return [kept[i] for i in chosen]


def choose_keyframes(
    source: FrameSource, conf: dict | None = None, progress=None, stop=None
) -> KeyframeChoice:
    """The first pass: every frame of ``source`` read once, its left image tracked from the last kept
    frame's (module docstring). ``progress(done, total)``: called per frame read; ``stop``: a
    :class:`~stereogeo_cli.jobs.interrupt.Stop`, once requested the pass ends where it is."""
    conf = resolve(default_conf, conf)
    tracker = _Tracker(conf)
    choice = KeyframeChoice([], 0, conf=conf)
    total = source.count()
    last_left_out: tuple[int, str] | None = None  # the last frame left out, and why
    for number, frame in enumerate(source):
        if stop is not None and stop.requested:
            break
        grey = tracker.small(frame.left)
        choice.read += 1
        reason = None if tracker.grey is None else decide(tracker.motion(grey), conf)
        if reason is None:
            choice.kept.append(number)
            tracker.keep(grey)
        else:
            choice.left_out[reason] += 1
            last_left_out = number, reason
        if progress is not None:
            progress(choice.read, total)
    if len(choice.kept) == 1 and last_left_out is not None:
        # a sequence needs two frames: the last stands for the rest of the recording
        number, reason = last_left_out
        choice.left_out[reason] -= 1
        choice.kept.append(number)
    capped = spread(choice.kept, conf["max_kept"])
    choice.left_out["cap"] = len(choice.kept) - len(capped)
    choice.kept = capped
    return choice


class KeyframeSource(FrameSource):
    """The kept frames of ``source`` (``choice.kept``), numbered 0, 1, ... again, in a second pass."""

    def __init__(self, source: FrameSource, choice: KeyframeChoice):
        super().__init__()
        self.source, self.choice = source, choice
        self.description = source.description
        self.warnings = [*source.warnings, *choice.notes()]

    def count(self) -> int:
        return len(self.choice.kept)

    def __iter__(self) -> Iterator[FramePair]:
        wanted = iter(self.choice.kept)
        following = next(wanted, None)
        index = 0
        frames = iter(self.source)
        try:
            for number, frame in enumerate(frames):
                if number == following:
                    yield replace(frame, index=index)
                    index += 1
                    following = next(wanted, None)
                    if following is None:  # the last kept frame: the rest is not decoded
                        return
        finally:
            close = getattr(frames, "close", None)
            if close is not None:
                close()


def with_frames_counted(calibration, source: FrameSource, kept: int):
    """The calibration with the report's ``sequence`` block opened by the frames read, kept and registered
    and the ``keyframes`` block: the rule that chose the ``kept`` frames of ``source`` and what it left
    out (``{"rule": "all"}`` where every frame the source yields was kept)."""
    sequence = calibration.extra_report.get("sequence")
    if sequence is None:
        return calibration
    if isinstance(source, KeyframeSource):
        read, keyframes = source.choice.read, source.choice.to_report()
    else:
        read, keyframes = kept, {"rule": "all"}
    opened = {
        "frames_read": read,
        "frames_kept": kept,
        "frames_registered": sequence["frames_registered"],
        "keyframes": keyframes,
    }
    sequence = {**opened, **{k: v for k, v in sequence.items() if k not in opened}}
    return replace(calibration, extra_report={**calibration.extra_report, "sequence": sequence})
