"""The Python front door: ``calibrate(left, right)`` gives exactly what ``stereogeo calibrate`` gives."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.options import API_NAMES, PairOptions
from stereogeo_cli.pipeline import CalibrationResult, Calibrator

ImageInput = str | os.PathLike | np.ndarray


def calibrate(
    left: ImageInput,
    right: ImageInput,
    *,
    baseline: float | None = None,
    focal_left: float | None = None,
    focal_right: float | None = None,
    focal_sigma: float | None = None,
    pinhole: bool = False,
    lines: bool = True,
    exif: bool = True,
    rotate: int = 0,
    model: str | os.PathLike | None = None,
    threads: int = 0,
    calibrator: Calibrator | None = None,
) -> CalibrationResult:
    """Calibrate one stereo pair, as ``stereogeo calibrate`` does with the same options.

    Args:
        left, right: image files (their EXIF focal length is read unless ``exif`` is False), or RGB
            arrays [H x W x 3] uint8 as :func:`stereogeo_cli.io.load_image` returns them (no EXIF then).
        baseline: the rig's baseline in metres, if known (sets |T|).
        focal_left, focal_right: known focal lengths in pixels; held fixed, or priors with the relative
            1-sigma ``focal_sigma``.
        pinhole: fit no lens distortion (rectified or undistorted images).
        lines: use the images' line segments (vertical ones for gravity, vanishing points for the focal).
        rotate: degrees (0, 90, 180 or 270) to turn both images clockwise before they are read, for a rig
            mounted upside down (180) or on its side; the result is for the images as given.
        model, threads: the ONNX model (default: the shipped one) and the network's threads.
        calibrator: a :class:`Calibrator` to reuse across pairs (``model``, ``threads``, ``pinhole`` and
            ``lines`` are then its own).

    Returns the :class:`CalibrationResult`; ``result.calibration`` is what the files are written from
    (:func:`stereogeo_cli.io.write_calibration`) and ``result.report()`` the JSON report.

    Raises :class:`StereoGeoError` for bad input (its ``exit_code`` is the CLI's).
    """
    options = PairOptions(
        baseline, focal_left, focal_right, focal_sigma, pinhole=pinhole, lines=lines, exif=exif, rotate=rotate
    ).checked(API_NAMES)
    return calibrate_with(left, right, options, model=model, threads=threads, calibrator=calibrator)


def calibrate_with(
    left: ImageInput,
    right: ImageInput,
    options: PairOptions,
    *,
    model: str | os.PathLike | None = None,
    threads: int = 0,
    calibrator: Calibrator | None = None,
) -> CalibrationResult:
    """:func:`calibrate` with its options already made and checked (``stereogeo calibrate``'s way in)."""
    from stereogeo_cli.io import load_image
    from stereogeo_cli.io.exif import exif_focals

    images = [image if isinstance(image, np.ndarray) else load_image(image) for image in (left, right)]
    paths = [None if isinstance(image, np.ndarray) else Path(image) for image in (left, right)]
    if calibrator is None:
        # the pair's image work starts while the network's session opens
        first = None if options.rotate else (images[0], images[1])  # a turned pair's starts in calibrate
        calibrator = Calibrator(model, threads=threads, conf=options.calibrator_conf(), first_pair=first)
    elif options.focal_sigma is not None:
        raise StereoGeoError("give focal_sigma in the calibrator's conf (known_focal_sigma) when reusing one")
    found = None
    if options.exif and None not in paths:
        found = exif_focals(paths, images)
    return calibrator.calibrate(
        images[0],
        images[1],
        baseline_m=options.baseline_m,
        focal_left=options.focal_left,
        focal_right=options.focal_right,
        exif=found,
        rotate=options.rotate,
    )
