"""What a user chooses for ``calibrate-sequence``, checked once where the command starts and passed down."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.options import PairOptions


@dataclass(frozen=True)
class SequenceOptions:
    """How a sequence's frames are read and chosen, and how its rig is calibrated.

    The source: ``video`` (the left and right videos), ``sbs`` (one side-by-side video), ``left_topic`` and
    ``right_topic`` (a bag's), ``stamp_tolerance_s`` (a bag's pairing); the frames: ``every`` (every Nth
    pair), ``fps`` (videos and bags: at most this many a second; a folder: its frame rate), ``max_frames``
    (the first N), each in place of ``keyframes`` (chosen by motion, at most ``max_keyframes``).
    The calibration: ``pair`` (the baseline, ``--pinhole``, ``--rotate``), ``workspace`` (a folder for
    COLMAP's work; None: a temporary one), ``conf`` (overrides of the stages' settings,
    :data:`stereogeo_cli.sequence.run.default_conf`).
    """

    video: tuple[Path, Path] | None = None
    sbs: Path | None = None
    left_topic: str | None = None
    right_topic: str | None = None
    stamp_tolerance_s: float | None = None
    every: int | None = None
    fps: float | None = None
    max_frames: int | None = None
    keyframes: bool = True
    max_keyframes: int = 150
    pair: PairOptions = PairOptions()
    workspace: Path | None = None
    conf: dict = field(default_factory=dict)

    def checked(self) -> SequenceOptions:
        """These options, or a :class:`StereoGeoError` naming the first bad one as the command spells it."""
        self.pair.checked()
        counts = (
            ("--every", self.every),
            ("--max-frames", self.max_frames),
            ("--max-keyframes", self.max_keyframes),
        )
        for name, value in counts:
            if value is not None and value < 1:
                raise StereoGeoError(f"{name} must be at least 1, got {value}")
        if self.fps is not None and not (math.isfinite(self.fps) and self.fps > 0):
            raise StereoGeoError(f"--fps must be a positive number of frames per second, got {self.fps}")
        if self.workspace is not None and self.workspace.exists() and not self.workspace.is_dir():
            raise StereoGeoError(f"--workspace {self.workspace} is a file, not a folder")
        return self

    def open(self, source: Path | None):
        """The :class:`~stereogeo_cli.sequence.sources.FrameSource` these options read from ``source``."""
        from stereogeo_cli.sequence.sources import open_source

        return open_source(
            source, video=self.video, sbs=self.sbs, left_topic=self.left_topic, right_topic=self.right_topic,
            every=1 if self.every is None else self.every, fps=self.fps, max_frames=self.max_frames,
            tolerance_s=self.stamp_tolerance_s,
        )  # fmt: skip

    def chooses_keyframes(self, frames) -> bool:
        """Whether keyframes choose among ``frames``: unless turned off, or --every, --max-frames or a video's
        or bag's --fps choose instead (a folder's --fps sets its frames' times and chooses none)."""
        from stereogeo_cli.sequence.sources import FolderSource

        chosen = self.every is not None or self.max_frames is not None
        return self.keyframes and not chosen and (self.fps is None or isinstance(frames, FolderSource))
