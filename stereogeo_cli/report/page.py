"""``report.html``: one self-contained page (images as data URIs, no script, no network) that shows a
calibration's result and the pictures that tell whether to trust it, each with one sentence on how to
read it. It is built from the JSON report (the same dict report.json is written from, so the numbers
agree) and, where given, the :class:`~stereogeo_cli.report.inputs.ReportInputs` the figures draw.

Each figure is a ``<figure data-figure="NAME">``; a figure whose data are not there is left out. The
names: ``result``, ``gravity-fields``, ``rectified``, ``row-errors``, ``coverage``, ``focal-evidence``,
``trajectory``, ``frames``, ``blocks``, ``frame-counts``, ``same-rig``.
"""

from __future__ import annotations

import base64
import struct
from html import escape

import numpy as np

from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.io.calibration import StereoCalibration
from stereogeo_cli.report import pictures, plots, tables
from stereogeo_cli.report.inputs import FocalRead, ReportInputs
from stereogeo_cli.report.measures import rotation_apart_deg, row_errors
from stereogeo_cli.report.style import STYLE

SIDES = ("left", "right")


def figure(name: str, title: str, body: str, caption: str) -> str:
    """One figure: its marker (``data-figure``), title, content and the sentence on how to read it."""
    return (
        f'<figure class="figure" data-figure="{name}" id="figure-{name}"><h3>{escape(title)}</h3>{body}'
        f"<figcaption>{escape(caption)}</figcaption></figure>"
    )


def image_tag(data: bytes, kind: str, alt: str, size: tuple[int, int], css: str = "") -> str:
    """An ``<img>`` with ``data`` (PNG or JPEG bytes) as a data URI and its size in pixels."""
    uri = f"data:image/{kind};base64,{base64.b64encode(data).decode('ascii')}"
    extra = f' class="{css}"' if css else ""
    return f'<img src="{uri}" width="{size[0]}" height="{size[1]}" alt="{escape(alt, quote=True)}"{extra}>'


def picture_tag(picture: np.ndarray, alt: str, kind: str = "jpeg", css: str = "") -> str:
    return image_tag(pictures.encode(picture, kind), kind, alt, (picture.shape[1], picture.shape[0]), css)


def plot_tag(png: bytes, alt: str, css: str = "plot") -> str:
    width, height = struct.unpack(">II", png[16:24])  # the PNG's IHDR chunk
    return image_tag(png, "png", alt, (width, height), css)


def _panel(content: str, label: str, css: str = "panel") -> str:
    return f'<div class="{css}">{content}<div class="label">{label}</div></div>'


def _scale(cmap: str, low: str, middle: str, high: str) -> str:
    """A colour bar with its ends' and middle's labels."""
    bar = picture_tag(pictures.colour_bar(cmap), f"colour scale from {low} to {high}", "png", "bar")
    ticks = "".join(f"<span>{label}</span>" for label in (low, middle, high))
    return f'<div class="scale">{bar}<div class="ticks">{ticks}</div></div>'


def result_section(report: dict) -> str:
    """The result as tables: cameras, rig, what was given, warnings (and a sequence's frames)."""
    body = (
        '<div class="tables">' + tables.camera_table(report) + tables.rig_table(report) + "</div>"
        "<h4>Given</h4>" + tables.given_list(report) + "<h4>Warnings</h4>" + tables.warnings_list(report)
    )
    caption = (
        "Each value with its 1-sigma uncertainty: where the sigmas are honest, 68 % of the errors lie "
        "within them; “held” values were given and not fitted."
    )
    return figure("result", "Result", body, caption)


def _camera(calibration: StereoCalibration, side: str):
    if side == "left":
        return calibration.K_left, calibration.dist_left, calibration.gravity_left
    return calibration.K_right, calibration.dist_right, calibration.gravity_right


def gravity_section(inputs: ReportInputs, calibration: StereoCalibration) -> str:
    """Each image with its calibrated horizon and gravity, beside the network's fields and confidences."""
    if inputs.images is None or calibration.gravity_left is None:
        return ""
    rows = []
    for index, side in enumerate(SIDES):
        K, D, gravity = _camera(calibration, side)
        image = inputs.images[index]
        cells = [_panel(picture_tag(pictures.gravity_picture(image, K, D, gravity), f"{side} image"),
                        f"{side} image: calibrated horizon and up", "panel main")]  # fmt: skip
        if inputs.fields is not None:
            maps = inputs.fields[index]
            half = pictures.latitude_range_deg(maps)
            cells += [
                _panel(picture_tag(pictures.up_field_picture(image, maps, K, gravity), f"{side} up-vectors"),
                       "up-vectors: network (blue), calibrated (yellow)"),
                _panel(picture_tag(pictures.latitude_picture(maps), f"{side} latitude field")
                       + _scale("coolwarm", f"−{half:.0f}°", "0°", f"+{half:.0f}°"), "network: latitude"),
                _panel(picture_tag(pictures.confidence_picture(maps.up_confidence, maps), "up confidence")
                       + _scale("viridis", "0", "0.5", "1"), "confidence of the up-vectors"),
                _panel(picture_tag(pictures.confidence_picture(maps.latitude_confidence, maps),
                                   "latitude confidence")
                       + _scale("viridis", "0", "0.5", "1"), "confidence of the latitude"),
            ]  # fmt: skip
        css = "fields" if inputs.fields is not None else "fields plain"
        rows.append(f'<div class="{css}">' + "".join(cells) + "</div>")
    caption = (
        "The magenta line is the calibrated horizon (eye level) and the yellow arrows point up as the "
        "calibration has it, along the scene's verticals when it is right; the network's up-vectors and "
        "latitude (each ray's angle above the horizon, 0° on the white line, a contour every 10°) should "
        "agree with them, and where its confidence is dark it read the image poorly."
    )
    return figure("gravity-fields", "Gravity: horizon, up and the network's fields", "".join(rows), caption)


def rectified_sections(inputs: ReportInputs, calibration: StereoCalibration) -> str:
    """The rectified pair with its guide rows, and the histogram of the matches' row errors."""
    out = ""
    if inputs.images is not None:
        picture = pictures.rectified_picture(*inputs.images, calibration)
        caption = ("Rectified, a point of the scene lies on the same row in both images: things must cross "
                   "the green rows at the same height left and right (magenta: the horizon).")  # fmt: skip
        out += figure(
            "rectified", "Rectified pair", picture_tag(picture, "rectified pair", css="wide"), caption
        )
    if inputs.matches is not None and len(inputs.matches[0]):
        errors = row_errors(calibration, *inputs.matches)
        median, p95 = float(np.median(errors)), float(np.percentile(errors, 95))
        caption = (f"How far apart in rows the {len(errors)} matches lie after rectification: median "
                   f"{median:.2f} px, 95th percentile {p95:.2f} px; ROS's stereo calibrator calls under "
                   "0.25 px good and under 0.1 px excellent (dotted lines).")  # fmt: skip
        plot = plot_tag(plots.row_error_plot(errors), "row errors after rectification")
        body = plot + (f'<p class="numbers" data-median-px="{median!r}" data-p95-px="{p95!r}">median '
                       f"{median:.3f} px · 95 % {p95:.3f} px · {len(errors)} matches</p>")  # fmt: skip
        out += figure("row-errors", "Row errors of the matches after rectification", body, caption)
    return out


def coverage_section(inputs: ReportInputs, calibration: StereoCalibration) -> str:
    """The matches the pose was fitted to over each image, with the lens as a grid where one was fitted."""
    if inputs.images is None or inputs.matches is None or not len(inputs.matches[0]):
        return ""
    cells = []
    for index, side in enumerate(SIDES):
        K, D, _ = _camera(calibration, side)
        image, points = inputs.images[index], inputs.matches[index]
        counts = pictures.coverage(points, (image.shape[1], image.shape[0]))
        share = 100.0 * float(np.mean(counts > 0))
        lens = "; cyan: the fitted lens" if np.any(D) else "; no lens fitted"
        label = f"{side}: {len(points)} matches in {share:.0f} % of the cells{lens}"
        cells.append(
            _panel(picture_tag(pictures.coverage_picture(image, points, K, D), f"{side} coverage"), label)
        )
    caption = ("The matches R, T and the lens were fitted to (green) and the cells of the image with none of "
               "them (red): the calibration is trustworthy where they spread over the whole image; the cyan "
               "lines are a square grid as the fitted lens bends it.")  # fmt: skip
    body = '<div class="pair">' + "".join(cells) + "</div>"
    return figure("coverage", "Coverage of the matches", body, caption)


def _results(report: dict) -> list[tuple[float, float | None]]:
    return [(report[s]["focal_px"], (report[s].get("sigma") or {}).get("focal_px")) for s in SIDES]


def _sequence_reads(report: dict) -> tuple[list[FocalRead], list[FocalRead]] | None:
    focal = ((report.get("sequence") or {}).get("evidence") or {}).get("focal")
    if not focal:
        return None
    reads: tuple[list[FocalRead], list[FocalRead]] = ([], [])
    for index, side in enumerate(SIDES):
        for key, label in (("pairs", "pairs alone"), ("adjustment", "bundle adjustment")):
            entry = focal[side].get(key) or {}
            # a reading without a sigma read nothing (no adjustment: the pairs alone calibrated the rig)
            if entry.get("focal_px") is not None and entry.get("sigma_px") is not None:
                reads[index].append(FocalRead(label, entry["focal_px"], entry["sigma_px"]))
    return reads


def focal_section(report: dict, inputs: ReportInputs) -> str:
    """The focal length's pieces of evidence per camera, and the result that combines them."""
    reads = inputs.focal_reads if inputs.focal_reads is not None else _sequence_reads(report)
    if reads is None or not any(reads):  # held focal lengths: no evidence to show
        return ""
    caption = (
        "Each reading of the focal length with its 1-sigma bar, and the result that combines them (red, its "
        "1-sigma shaded, which also allows for how far the network can misread a real lens): readings "
        "further apart than their bars mean one of them is off."
    )
    plot = plot_tag(plots.focal_plot(reads, _results(report)), "focal length evidence")
    return figure("focal-evidence", "Focal length: the evidence", plot, caption)


def sequence_sections(report: dict, inputs: ReportInputs) -> str:
    """A sequence's trajectory, its frames' attitude and reprojection, the left-out stretches' focal
    lengths and its frame counts."""
    seq = report.get("sequence")
    if not seq:
        return ""
    out = ""
    track = inputs.track
    if track is not None and len(track.positions) >= 2:
        caption = (
            "The left camera's path seen from above (z up, metres), dark to light in time, arrows its "
            "viewing direction: a path that turns fixes the focal lengths, a straight one does not."
        )
        plot = plot_tag(plots.trajectory_plot(track.positions, track.axes), "trajectory", "plot square")
        out += figure("trajectory", "Trajectory from above", plot, caption)
    frames = seq.get("frames") or []
    if frames:
        reprojection = track.reprojection_px if track is not None else None
        caption = (
            "Roll and pitch of each frame's cameras follow the motion smoothly on a good calibration; "
            "frames whose reprojection error stands out fit the adjusted model badly."
        )
        plot = plot_tag(plots.frames_plot(frames, reprojection), "roll, pitch and reprojection per frame")
        out += figure("frames", "Per frame: roll, pitch, reprojection error", plot, caption)
    blocks = (seq.get("left_out") or {}).get("focal_px")
    if blocks:
        caption = (
            "Each stretch of the recording left out of the adjustment in turn: focal lengths within the "
            "result's band say every part of the recording agrees on them."
        )
        plot = plot_tag(plots.blocks_plot(blocks, _results(report)), "focal length per left-out stretch")
        out += figure("blocks", "Focal length over stretches of frames", plot, caption)
    caption = (
        "How many frame pairs were read, placed in the adjusted model and given an attitude: frames "
        "left unregistered did not fit the rig's model."
    )
    out += figure("frame-counts", "Frames", tables.sequence_table(report), caption)
    return out


def same_rig_section(report: dict, inputs: ReportInputs) -> str:
    """Each pair's focal lengths and R against the joint calibration's (``batch-calibrate --same-rig``)."""
    pairs = [(name, r) for name, r in (inputs.pairs or []) if r and "left" in r and "R" in r]
    if not pairs:
        return ""
    focals = [
        [(r[s]["focal_px"], (r[s].get("sigma") or {}).get("focal_px")) for _, r in pairs] for s in SIDES
    ]
    rotations = [(rotation_apart_deg(r["R"], report["R"]), (r.get("pose") or {}).get("sigma_rotation_deg"))
                 for _, r in pairs]  # fmt: skip
    plot = plots.same_rig_plot([n for n, _ in pairs], focals, _results(report), rotations,
                               (report.get("pose") or {}).get("sigma_rotation_deg"))  # fmt: skip
    caption = (
        "Each pair calibrated alone (blue, 1-sigma bars) against the joint calibration (red, its 1-sigma "
        "shaded): a pair far outside the band is from another rig or was calibrated badly."
    )
    return figure("same-rig", "Pairs against the joint calibration", plot_tag(plot, "pairs against the rig"),
                  caption)  # fmt: skip


def _title(report: dict) -> str:
    if report.get("sequence"):
        return "Calibration from a sequence"
    if report.get("pairs"):
        return f"Joint calibration of {len(report['pairs'])} pairs of one rig"
    return "Calibration from one image pair"


def report_html(report: dict, inputs: ReportInputs | None = None) -> str:
    """The whole page for the JSON report ``report`` (:meth:`StereoCalibration.to_report`) and what its
    figures draw (``inputs``; None: the result's tables and the figures the report alone holds)."""
    try:
        import matplotlib  # noqa: F401  (the plots' and the colour maps')
    except ImportError:
        raise StereoGeoError(
            "report.html needs matplotlib (pip install matplotlib); or leave html out of --format"
        ) from None
    inputs = inputs or ReportInputs()
    calibration = StereoCalibration.from_report(report)
    model = report.get("model") or {}
    sections = [
        result_section(report),
        gravity_section(inputs, calibration),
        rectified_sections(inputs, calibration),
        coverage_section(inputs, calibration),
        focal_section(report, inputs),
        sequence_sections(report, inputs),
        same_rig_section(report, inputs),
    ]
    title = _title(report)
    subtitle = (
        f"stereogeo · model {escape(str(model.get('file')))} ({escape(str(model.get('sha256') or '')[:12])})"
    )
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{escape(title)}</title><style>{STYLE}</style></head>"
        f'<body><header><h1>{escape(title)}</h1><p class="subtitle">{subtitle}</p></header>'
        + "".join(s for s in sections if s)
        + "</body></html>\n"
    )
