"""The report's result as HTML tables, every number read from the JSON report and carried in the cell as
``data-key`` (its path in report.json, e.g. ``left.sigma.focal_px``) and ``data-value`` (the value as
JSON has it), so that a reader, or a test, can tell each shown number for the report's own."""

from __future__ import annotations

import json
import math
from html import escape
from typing import Any

from stereogeo_cli.report.measures import rotation_vector_deg

SIDES = ("left", "right")


def lookup(report: dict, key: str) -> Any:
    """The value at a ``data-key`` path of the report (dots between keys, list indices as numbers)."""
    value: Any = report
    for part in key.split("."):
        value = value[int(part)] if isinstance(value, list) else value[part]
    return value


def _known(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def number(report: dict, key: str, digits: int = 2, scale: float = 1.0) -> str:
    """The report's value at ``key`` shown with ``digits`` decimals (times ``scale``), in a span that
    carries its key and exact value; "–" where it is unknown."""
    try:
        value = lookup(report, key)
    except (KeyError, IndexError, TypeError, ValueError):
        return "–"
    shown = f"{value * scale:.{digits}f}".replace("-", "−") if _known(value) else "–"
    exact = escape(json.dumps(value), quote=True)
    return f'<span class="num" data-key="{escape(key, quote=True)}" data-value="{exact}">{shown}</span>'


def with_sigma(report: dict, key: str, sigma_key: str, digits: int = 2) -> str:
    """A value ± its 1-sigma; "held" where the sigma is 0 (the value was given and not fitted)."""
    try:
        sigma = lookup(report, sigma_key)
    except (KeyError, IndexError, TypeError):
        sigma = None
    if sigma == 0:
        return f'{number(report, key, digits)} <span class="held">(held)</span>'
    if _missing(report, key) and ("sequence" in report or "pairs" in report):
        where = "per frame" if "sequence" in report else "per pair"
        return f'{number(report, key, digits)} <span class="note">({where})</span>'
    return f"{number(report, key, digits)} ± {number(report, sigma_key, digits)}"


def _missing(report: dict, key: str) -> bool:
    try:
        return lookup(report, key) is None
    except (KeyError, IndexError, TypeError, ValueError):
        return True


def _row(label: str, cells: list[str]) -> str:
    return f"<tr><th>{escape(label)}</th>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>"


def camera_table(report: dict) -> str:
    """Per camera (a column each): focal length, vFoV, principal point, image size, lens, roll, pitch."""
    rows = [
        ("focal length f (px)", lambda s: with_sigma(report, f"{s}.focal_px", f"{s}.sigma.focal_px", 1)),
        ("vertical field of view (°)", lambda s: with_sigma(report, f"{s}.vfov_deg", f"{s}.sigma.vfov_deg")),
        ("principal point cx, cy (px)",
         lambda s: f"{number(report, f'{s}.K.0.2', 1)}, {number(report, f'{s}.K.1.2', 1)}"),
        ("image (px)", lambda s: f"{number(report, f'{s}.width', 0)} × {number(report, f'{s}.height', 0)}"),
        ("lens (OpenCV k1 k2 p1 p2 k3 …)", lambda s: _lens(report, s)),
        ("roll (°)", lambda s: with_sigma(report, f"{s}.roll_deg", f"{s}.sigma.roll_deg")),
        ("pitch (°)", lambda s: with_sigma(report, f"{s}.pitch_deg", f"{s}.sigma.pitch_deg")),
    ]  # fmt: skip
    body = "".join(_row(label, [cell(side) for side in SIDES]) for label, cell in rows)
    head = "<tr><th></th><th>left camera</th><th>right camera</th></tr>"
    return f'<table class="result" data-table="cameras">{head}{body}</table>'


def _lens(report: dict, side: str) -> str:
    dist = report[side].get("dist") or []
    if not any(dist):
        shown = "none (pinhole)"
    else:
        shown = " ".join(number(report, f"{side}.dist.{i}", 4) for i in range(len(dist)))
    pose = report.get("pose") or {}
    index = SIDES.index(side)
    k = (pose.get("distortion_k") or [None, None])[index]
    if k:  # the fusion's division-model term, with its sigma
        sigma = number(report, f"pose.sigma_distortion_k.{index}", 4)
        shown += f"<br>division k {number(report, f'pose.distortion_k.{index}', 4)} ± {sigma}"
    return shown


def rig_table(report: dict) -> str:
    """R as angles (its angle ± 1-sigma, and the axis-angle vector), T, the baseline and T's direction
    with their 1-sigmas, and where the pose and the scale came from."""
    pose = report.get("pose") or {}
    vector = ", ".join(f"{v:.3f}".replace("-", "−") for v in rotation_vector_deg(report["R"]))
    rows = [
        ("R: rotation angle (°)", f"{number(report, 'pose.rotation_deg', 3)} ± "
                                  f"{number(report, 'pose.sigma_rotation_deg', 3)}"),
        ("R: axis × angle (°, x y z)", f'<span class="derived">{vector}</span>'),
        ("T (m, x y z)", ", ".join(number(report, f"T.{i}", 4) for i in range(3))),
        ("baseline |T| (m)", _baseline(report)),
        ("T direction: 1-sigma (°)", number(report, "pose.sigma_direction_deg", 2)),
        ("pose from", f"{_text(pose.get('source'))}; sign of T from {_text(pose.get('sign_source'))}"),
        ("scale from", _text(report.get("scale_source"))),
        ("matches (found, inliers)",
         f"{number(report, 'matches.found', 0)}, {number(report, 'matches.inliers', 0)}"),
    ]  # fmt: skip
    if _known(pose.get("gravity_error_deg")):
        rows.append(
            ("gravity through R: R·g_left vs g_right (°)", number(report, "pose.gravity_error_deg", 2))
        )
    body = "".join(_row(label, [cell]) for label, cell in rows)
    return f'<table class="result" data-table="rig">{body}</table>'


def _baseline(report: dict) -> str:
    shown = number(report, "baseline_m", 4)
    rel = (report.get("pose") or {}).get("sigma_baseline_rel")
    if _known(rel):
        shown += f" ± {number(report, 'pose.sigma_baseline_rel', 0, 100.0)} %"
    return shown


def _text(value: Any) -> str:
    return escape(str(value)) if value is not None else "–"


def given_list(report: dict) -> str:
    """What the calibration was given rather than read from the images: EXIF or given focal lengths,
    held focal lengths, the baseline, a turn of the images."""
    items = []
    for index, side in enumerate(SIDES):
        prior = (report.get("focal_prior") or [None, None])[index]
        if prior and prior.get("source") == "exif":
            tag = f"{_text(prior.get('tag'))} {number(report, f'focal_prior.{index}.tag_mm', 1)} mm"
            items.append(f"{side} camera: EXIF focal length ({tag}) → "
                         f"{number(report, f'focal_prior.{index}.focal_px', 1)} ± "
                         f"{number(report, f'focal_prior.{index}.sigma_px', 1)} px, combined with the "
                         "fields' read")  # fmt: skip
        elif prior and prior.get("source") == "given":
            items.append(f"{side} camera: focal length given as a prior, "
                         f"{number(report, f'focal_prior.{index}.focal_px', 1)} ± "
                         f"{number(report, f'focal_prior.{index}.sigma_px', 1)} px")  # fmt: skip
        if (report[side].get("sigma") or {}).get("focal_px") == 0:
            items.append(f"{side} camera: focal length held at {number(report, f'{side}.focal_px', 1)} px")
    if report.get("scale_source") == "baseline":
        items.append(f"baseline given: {number(report, 'baseline_m', 4)} m")
    if report.get("rotate_deg"):
        items.append(f"images turned by {number(report, 'rotate_deg', 0)}° before they were read")
    if not items:
        items.append("nothing: every value was read from the images")
    return '<ul class="given" data-list="given">' + "".join(f"<li>{i}</li>" for i in items) + "</ul>"


def warnings_list(report: dict) -> str:
    """The report's warnings (none: a line that says so)."""
    warnings = report.get("warnings") or []
    if not warnings:
        return '<p class="none" data-list="warnings">No warnings.</p>'
    items = "".join(f"<li>{escape(w)}</li>" for w in warnings)
    return f'<ul class="warnings" data-list="warnings">{items}</ul>'


def sequence_table(report: dict) -> str:
    """A sequence's frames read, kept and registered, its models, the adjustment's reprojection error, the
    motion's turn, and the left-out stretches' row check."""
    seq = report["sequence"]
    rows = [
        ("frames read (after --every, --fps, --max-frames)", number(report, "sequence.frames_read", 0)),
        ("frames kept (keyframes by motion, or all)", number(report, "sequence.frames_kept", 0)),
        ("frames registered by the adjustment", number(report, "sequence.frames_registered", 0)),
        ("frames with a roll and pitch", f'<span class="derived">{len(seq.get("frames") or [])}</span>'),
        ("models the mapping made", number(report, "sequence.models", 0)),
        ("3-D points", number(report, "sequence.points", 0)),
        ("mean reprojection error (px)", number(report, "sequence.reprojection_error_px", 3)),
        ("rotation span (°)", number(report, "sequence.rotation_span_deg", 1)),
        ("focal length fixed by the motion", _text(seq.get("focal_observable"))),
    ]
    if seq.get("principal_point_reading"):
        rows.append(("the principal points freed under a prior: the focal length parts by (%)",
                     number(report, "sequence.principal_point_reading.focal_rel", 2, 100.0)))  # fmt: skip
    if seq.get("left_out"):
        rows.append(("left-out frames, rectified: row difference median / 95 % (px)",
                     f"{number(report, 'sequence.left_out.row_error_px.median', 3)} / "
                     f"{number(report, 'sequence.left_out.row_error_px.p95', 3)}"))  # fmt: skip
    body = "".join(_row(label, [cell]) for label, cell in rows)
    return f'<table class="result" data-table="frames">{body}</table>'
