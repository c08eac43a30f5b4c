"""stereogeo — stereo camera calibration from one image pair, with no calibration pattern."""

__version__ = "0.1.0"
