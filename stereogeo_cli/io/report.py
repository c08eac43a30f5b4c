"""``report.json``: the JSON report (docs/io.md, "report.json"), as ``calibrate --json`` prints it."""

from __future__ import annotations

import json
import re

from stereogeo_cli.io.calibration import Rectification, StereoCalibration

# A list spread over lines by json.dumps(indent=...) that holds only numbers/null. JSON strings cannot
# hold a raw newline, so this never matches inside one.
_NUMBER_LIST = re.compile(r"\[\n\s*([^\[\]{}\"]*?)\n\s*\]")


def report_json(calibration: StereoCalibration) -> str:
    """The report as indented JSON text with a final newline; number lists (K rows, T, ...) on one line.

    Unknown values are ``null``, never NaN.
    """
    text = json.dumps(calibration.to_report(), indent=2, allow_nan=False)
    text = _NUMBER_LIST.sub(lambda m: "[" + re.sub(r",\s+", ", ", m.group(1)) + "]", text)
    return text + "\n"


def render_report(calibration: StereoCalibration, rect: Rectification | None = None) -> dict[str, str]:
    """``{"report.json": text}``."""
    return {"report.json": report_json(calibration)}
