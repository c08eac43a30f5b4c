"""The refiner: camera parameters from perspective fields (Levenberg–Marquardt, NumPy)."""

from stereogeo_cli.refine.lm import (
    CameraFit,
    combine_focal,
    default_conf,
    initial_estimate,
    parse_sigma_inflation,
    refine_camera,
)

__all__ = [
    "CameraFit",
    "combine_focal",
    "default_conf",
    "initial_estimate",
    "parse_sigma_inflation",
    "refine_camera",
]
