"""``write_calibration``: every output format from one :class:`StereoCalibration`.

The formats and their files are listed in docs/io.md, "Output files".
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.io.atomic import write_files_atomically
from stereogeo_cli.io.calibration import Rectification, StereoCalibration, rectify
from stereogeo_cli.io.colmap import render_colmap
from stereogeo_cli.io.kalibr import render_kalibr
from stereogeo_cli.io.opencv_yaml import render_opencv
from stereogeo_cli.io.report import render_report
from stereogeo_cli.io.ros import render_ros

Renderer = Callable[[StereoCalibration, Rectification], dict[str, str]]


def render_html(calibration: StereoCalibration, rect: Rectification | None = None, figures: Any = None):
    """``{"report.html": text}``: the HTML report of the JSON report's numbers, with the figures of
    ``figures`` (a :class:`~stereogeo_cli.report.ReportInputs`; None: those the numbers alone give). The
    report package, and matplotlib with it, is imported only here."""
    from stereogeo_cli.report import report_html

    return {"report.html": report_html(calibration.to_report(), figures)}


FORMATS: dict[str, Renderer] = {
    "opencv": render_opencv,  # intrinsics.yml, extrinsics.yml
    "ros": render_ros,  # left.yaml, right.yaml
    "kalibr": render_kalibr,  # camchain.yaml
    "colmap": render_colmap,  # cameras.txt
    "json": render_report,  # report.json
    "html": render_html,  # report.html
}
DEFAULT_FORMATS = tuple(FORMATS)
# the files each format writes: what a folder of stereogeo's results may hold
FORMAT_FILES: dict[str, tuple[str, ...]] = {
    "opencv": ("intrinsics.yml", "extrinsics.yml"),
    "ros": ("left.yaml", "right.yaml"),
    "kalibr": ("camchain.yaml",),
    "colmap": ("cameras.txt",),
    "json": ("report.json",),
    "html": ("report.html",),
}


def write_calibration(
    out_dir: str | os.PathLike,
    calibration: StereoCalibration,
    formats: Sequence[str] = DEFAULT_FORMATS,
    *,
    alpha: float = 0.0,
    figures: Any = None,
) -> list[Path]:
    """Write the calibration files of ``formats`` into ``out_dir``; return their paths.

    Formats: ``opencv`` (intrinsics.yml, extrinsics.yml), ``ros`` (left.yaml, right.yaml), ``kalibr``
    (camchain.yaml), ``colmap`` (cameras.txt), ``json`` (report.json), ``html`` (report.html). ``alpha`` is
    the free scaling of ``cv2.stereoRectify`` for R1, R2, P1, P2, Q (0: only valid pixels in the rectified
    images, 1: all pixels of the originals). ``figures``: what report.html draws beyond the numbers (a
    :class:`~stereogeo_cli.report.ReportInputs`, e.g. ``pair_inputs(result, left, right)``). Everything is
    rendered before anything is written, and the writes are atomic.

    Raises :class:`StereoGeoError` (exit code 2) for an unknown format or an output folder that cannot be
    made or written.
    """
    return write_files_atomically(
        out_dir, render_calibration(calibration, formats, alpha=alpha, figures=figures)
    )


def render_calibration(
    calibration: StereoCalibration,
    formats: Sequence[str] = DEFAULT_FORMATS,
    *,
    alpha: float = 0.0,
    figures: Any = None,
) -> dict[str, str]:
    """The files of :func:`write_calibration` as ``{file name: text}``, written nowhere (for a caller that
    writes them together with files of its own)."""
    if isinstance(formats, str):
        formats = (formats,)
    unknown = [f for f in formats if f not in FORMATS]
    if unknown:
        raise StereoGeoError(f"unknown output format {unknown[0]!r}; choose from {', '.join(FORMATS)}")
    rect = rectify(calibration, alpha)
    files: dict[str, str] = {}
    for name in dict.fromkeys(formats):  # in order, each once
        if name == "html":
            files.update(render_html(calibration, rect, figures))
        else:
            files.update(FORMATS[name](calibration, rect))
    return files
