"""The HTML report, ``report.html``: a calibration's result and the pictures that show whether to trust it.

- :mod:`~stereogeo_cli.report.inputs`: what the figures draw beyond the JSON report (images, fields,
  matches, the focal length's evidence, a sequence's track, a rig's pairs), taken from a result.
- :mod:`~stereogeo_cli.report.tables`: the result as tables, every number carrying its report.json key.
- :mod:`~stereogeo_cli.report.pictures` (OpenCV) and :mod:`~stereogeo_cli.report.plots` (matplotlib, imported
  only when a report is written): the figures.
- :mod:`~stereogeo_cli.report.page`: the page, one self-contained HTML file.

The writers (:mod:`stereogeo_cli.io.writers`, format ``html``) call :func:`report_html`.
"""

from stereogeo_cli.report.inputs import FieldMaps, FocalRead, ReportInputs, SequenceTrack, pair_inputs
from stereogeo_cli.report.page import report_html

__all__ = ["FieldMaps", "FocalRead", "ReportInputs", "SequenceTrack", "pair_inputs", "report_html"]
