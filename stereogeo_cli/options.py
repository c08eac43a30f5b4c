"""What a user chooses for the calibration of a pair, checked once where a command or the API starts.

``calibrate``, ``batch-calibrate`` (every pair of a pass) and the Python API make one :class:`PairOptions`
and pass it down; the stages' tuning settings are their ``default_conf`` dicts
(:func:`stereogeo_cli.settings.resolve`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.geometry import TURNS_DEG

# how an option is spelt in an error message: on the command line, or as the API's keyword
CLI_NAMES = {"baseline_m": "--baseline", "focal_left": "--focal-left", "focal_right": "--focal-right",
             "focal_sigma": "--focal-sigma", "rotate": "--rotate"}  # fmt: skip
API_NAMES = {"baseline_m": "baseline", "focal_left": "focal_left", "focal_right": "focal_right",
             "focal_sigma": "focal_sigma", "rotate": "rotate"}  # fmt: skip


def calibrator_conf(pinhole: bool, lines: bool = True) -> dict:
    """The Calibrator settings of ``--pinhole`` (no lens distortion fitted) and ``--no-lines`` (gravity and
    focal length from the fields alone: neither vertical segments nor vanishing points)."""
    conf: dict = {"fuse": {"distortion": False}} if pinhole else {}
    if not lines:
        conf["lines"] = {"enabled": False}
        conf["manhattan"] = {"enabled": False}
    return conf


@dataclass(frozen=True)
class PairOptions:
    """How each pair is calibrated.

    ``baseline_m``: the rig's baseline (metres), which sets |T|; ``focal_left``, ``focal_right``: known focal
    lengths (pixels), held fixed, or priors of relative 1-sigma ``focal_sigma``; ``pinhole``: fit no lens
    distortion; ``lines``: use the images' line segments (vertical ones for gravity, vanishing points for
    the focal length); ``exif``: take each photo's EXIF focal length as a prior; ``rotate``: degrees (0, 90,
    180 or 270) to turn both images clockwise before they are read (the results are for the images as
    given)."""

    baseline_m: float | None = None
    focal_left: float | None = None
    focal_right: float | None = None
    focal_sigma: float | None = None
    pinhole: bool = False
    lines: bool = True
    exif: bool = True
    rotate: int = 0

    def checked(self, names: dict[str, str] = CLI_NAMES) -> PairOptions:
        """These options, or a :class:`StereoGeoError` naming the first bad one as ``names`` spell it."""
        for key in ("baseline_m", "focal_left", "focal_right"):
            value = getattr(self, key)
            if value is not None and not (value > 0 and math.isfinite(value)):
                raise StereoGeoError(f"{names[key]} must be a positive number, got {value}")
        if self.focal_sigma is not None:
            if not 0 < self.focal_sigma < 1:
                raise StereoGeoError(
                    f"{names['focal_sigma']} must be a fraction between 0 and 1, got {self.focal_sigma}"
                )
            if self.focal_left is None and self.focal_right is None:
                raise StereoGeoError(
                    f"{names['focal_sigma']} needs {names['focal_left']} or {names['focal_right']}"
                )
        if self.rotate not in TURNS_DEG:
            raise StereoGeoError(f"{names['rotate']} must be 0, 90, 180 or 270, got {self.rotate}")
        return self

    def with_focals(self, left: float | None, right: float | None) -> PairOptions:
        """The same options with the focal lengths given (``batch-calibrate --same-rig``'s second pass)."""
        return replace(self, focal_left=left, focal_right=right)

    def calibrator_conf(self) -> dict:
        """The :class:`~stereogeo_cli.pipeline.Calibrator` settings these options ask for."""
        conf = calibrator_conf(self.pinhole, self.lines)
        if self.focal_sigma is not None:
            conf["known_focal_sigma"] = self.focal_sigma
        return conf
