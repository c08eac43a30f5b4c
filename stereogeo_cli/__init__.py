"""stereogeo — stereo camera calibration from one image pair, with no calibration pattern.

from stereogeo_cli import calibrate, write_calibration
result = calibrate("left.png", "right.png")
write_calibration("calibration/", result.calibration)
"""

from __future__ import annotations

from typing import TYPE_CHECKING

__version__ = "0.1.0"

# The names a user needs, imported on first use: `stereogeo --version` and the CLI's start stay light.
_EXPORTS = {
    "calibrate": "stereogeo_cli.api",
    "Calibrator": "stereogeo_cli.pipeline",
    "CalibrationResult": "stereogeo_cli.pipeline",
    "StereoCalibration": "stereogeo_cli.io",
    "load_image": "stereogeo_cli.io",
    "write_calibration": "stereogeo_cli.io",
    "StereoGeoError": "stereogeo_cli.errors",
    "CalibrationFailed": "stereogeo_cli.errors",
}
__all__ = [
    "CalibrationFailed", "CalibrationResult", "Calibrator", "StereoCalibration", "StereoGeoError",
    "__version__", "calibrate", "load_image", "write_calibration",
]  # fmt: skip

if TYPE_CHECKING:
    from stereogeo_cli.api import calibrate
    from stereogeo_cli.errors import CalibrationFailed, StereoGeoError
    from stereogeo_cli.io import StereoCalibration, load_image, write_calibration
    from stereogeo_cli.pipeline import CalibrationResult, Calibrator


def __getattr__(name: str):
    if name in _EXPORTS:
        import importlib

        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'stereogeo_cli' has no attribute {name!r}")
