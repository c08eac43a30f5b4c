"""Loading images and writing calibration files (OpenCV, ROS, Kalibr, COLMAP, JSON)."""

from stereogeo_cli.io.calibration import StereoCalibration
from stereogeo_cli.io.images import check_pair, load_image, load_pair
from stereogeo_cli.io.writers import write_calibration

__all__ = ["StereoCalibration", "check_pair", "load_image", "load_pair", "write_calibration"]
