"""What the HTML report draws beyond the JSON report's numbers: the images, the network's fields, the
matches the pose was fitted to, the focal length's pieces of evidence, a sequence's track and a rig's
pairs. Every piece is optional: the report shows the figures whose data are there.

These are plain arrays and numbers, taken from a calibration's result as it ends (:func:`pair_inputs`);
nothing here computes a calibration again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class FieldMaps:
    """One view's perspective fields as the network read them, one value per cell of its grid [h x w]:
    ``up`` [h x w x 2] unit up-vectors in image axes (x right, y down), ``latitude`` in radians, and the
    two confidences in (0, 1). ``extent``: the rectangle of the original image the grid covers, (x0, y0,
    x1, y1) in pixels of the image as given (the network reads a centred crop of a resized image)."""

    up: np.ndarray
    latitude: np.ndarray
    up_confidence: np.ndarray
    latitude_confidence: np.ndarray
    extent: tuple[float, float, float, float]

    @classmethod
    def from_view(cls, view) -> FieldMaps:
        """The maps of a :class:`~stereogeo_cli.network.runtime.ViewFields`."""
        w, h = view.resize_crop.out_size
        corners = view.resize_crop.points_to_input(np.array([[-0.5, -0.5], [w - 0.5, h - 0.5]]))
        (x0, y0), (x1, y1) = corners + 0.5  # pixel centres to the edges of the pixels
        return cls(
            np.asarray(view.up, dtype=float), np.asarray(view.latitude, dtype=float),
            np.asarray(view.up_confidence, dtype=float), np.asarray(view.latitude_confidence, dtype=float),
            (float(x0), float(y0), float(x1), float(y1)),
        )  # fmt: skip


@dataclass(frozen=True)
class FocalRead:
    """One piece of evidence of a camera's focal length: what it is (``label``), its value and 1-sigma in
    pixels (None: held, or no sigma)."""

    label: str
    focal_px: float
    sigma_px: float | None = None


@dataclass(frozen=True)
class SequenceTrack:
    """A sequence's left camera per registered frame, in time order: its centre in the output world
    (``positions`` [N x 3], metres, z up) and viewing direction (``axes`` [N x 3]); and per frame index the
    mean reprojection error of its two images' observations in the adjusted model (pixels)."""

    positions: np.ndarray
    axes: np.ndarray
    reprojection_px: dict[int, float]


@dataclass(frozen=True)
class ReportInputs:
    """The report's data beyond the JSON report, each optional.

    ``images``: the pair as given, RGB [H x W x 3] uint8; ``fields``: each view's :class:`FieldMaps`;
    ``matches``: the matches the relative pose was fitted to, (left [N x 2], right [N x 2]) in pixels of
    the images as given; ``focal_reads``: per camera its focal length's pieces of evidence before they were
    combined; ``track``: a sequence's :class:`SequenceTrack`; ``pairs``: a rig's pairs, each (name, its
    own JSON report), to set against the joint calibration."""

    images: tuple[np.ndarray, np.ndarray] | None = None
    fields: tuple[FieldMaps, FieldMaps] | None = None
    matches: tuple[np.ndarray, np.ndarray] | None = None
    focal_reads: tuple[list[FocalRead], list[FocalRead]] | None = None
    track: SequenceTrack | None = None
    pairs: list[tuple[str, dict[str, Any]]] | None = None


def _source_label(source: str) -> str:
    return {"exif": "EXIF tag", "given": "given (--focal-*)", "lines": "vanishing points"}.get(source, source)


def focal_reads(result) -> tuple[list[FocalRead], list[FocalRead]]:
    """Per camera of a :class:`~stereogeo_cli.pipeline.CalibrationResult` its focal length's pieces of
    evidence: the fields' own read, the prior combined with it (EXIF, given, the vanishing points), and the
    matches' read where the fusion refined the two focal lengths' common scale (at the value written)."""
    reads: tuple[list[FocalRead], list[FocalRead]] = ([], [])
    common = getattr(result.pose, "sigma_common_focal", None)
    for side, fit in enumerate((result.left, result.right)):
        fields = result.fields_focal[side]
        if fields is not None and math.isfinite(fields[0]):
            reads[side].append(FocalRead("fields", fields[0], _finite(fields[1])))
        source = result.focal_sources[side]
        if source is not None:
            reads[side].append(
                FocalRead(_source_label(source.source), source.focal_px, _finite(source.sigma_px))
            )
        if common is not None and math.isfinite(common) and fields is not None:
            reads[side].append(FocalRead("matches", fit.focal_px, common * fit.focal_px))
    return reads


def pair_inputs(result, left: np.ndarray | None = None, right: np.ndarray | None = None) -> ReportInputs:
    """The report's data of one calibrated pair (a :class:`~stereogeo_cli.pipeline.CalibrationResult`) and
    its images as given (RGB; None: no image figures)."""
    fields = None
    if getattr(result, "fields", None) is not None:
        fields = (FieldMaps.from_view(result.fields[0]), FieldMaps.from_view(result.fields[1]))
    matches = None
    if result.matches is not None and result.inliers is not None and result.inliers.any():
        keep = np.asarray(result.inliers, dtype=bool)
        matches = (np.asarray(result.matches.left)[keep], np.asarray(result.matches.right)[keep])
    images = None if left is None or right is None else (left, right)
    return ReportInputs(images=images, fields=fields, matches=matches, focal_reads=focal_reads(result))


def _finite(value: float | None) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None
