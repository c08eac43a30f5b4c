"""What ``batch-calibrate`` passes around: the job of a pass, each pair's outcome and what it tells of its
rig, the output folder's names, and the JSON form of the numbers."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from stereogeo_cli.options import PairOptions
from stereogeo_cli.rig.evidence import PairEvidence

RIG_FOLDER = "rig"  # --same-rig: the joint calibration's folder in OUT


CSV_COLUMNS = (
    "name", "status", "error",
    "left_focal_px", "left_vfov_deg", "left_roll_deg", "left_pitch_deg",
    "right_focal_px", "right_vfov_deg", "right_roll_deg", "right_pitch_deg",
    "rotation_deg", "baseline_m", "matches", "inliers", "time_ms", "left_file", "right_file",
)  # fmt: skip


NUMERIC_COLUMNS = CSV_COLUMNS[3:16]


@dataclass(frozen=True)
class BatchOptions:
    """How ``batch-calibrate`` runs, resolved once where the command starts.

    ``formats``: the output formats of each pair (and of the joint calibration); ``pair``: how each pair is
    calibrated (its baseline, ``--pinhole``, ``--no-lines``, ``--no-exif``, ``--rotate``); ``workers``:
    processes, each with its own network session of ``threads // workers`` threads; ``same_rig``: also one
    joint calibration of all pairs (``rig/``); ``shard``: only shard i of n (1-based); ``progress``: a Rich
    progress bar on stderr (else one plain line per pair there); ``resume``: keep each pair whose folder holds
    a complete calibration made with the same options, model and images (``batch/resume.py``); ``overwrite``:
    replace what the output folder holds."""

    formats: tuple[str, ...] = ("opencv", "json")
    pair: PairOptions = PairOptions()
    model: Path | None = None
    threads: int = 0
    workers: int = 1
    same_rig: bool = False
    shard: tuple[int, int] | None = None
    progress: bool = False
    resume: bool = False
    overwrite: bool = False


@dataclass(frozen=True)
class PairJob:
    """What to do with each pair: the same for every pair of a pass."""

    out_dir: Path | None  # per-pair files go to out_dir/<name>/; None: write nothing
    formats: tuple[str, ...]
    pair: PairOptions  # how each pair is calibrated (the second pass of --same-rig: at the rig's focals)
    model: Path | None
    threads: int
    keep_evidence: bool = False  # keep what --same-rig needs (focal, gravity, pose, matches)


@dataclass
class PairOutcome:
    """One pair's result: ``status`` "ok" with its JSON ``report``, "failed" with ``error``, or "not run"
    (the batch was stopped before it)."""

    name: str
    left: Path | None
    right: Path | None
    status: str
    error: str = ""
    report: dict[str, Any] | None = None
    time_ms: float = 0.0
    evidence: PairEvidence | None = None
    fatal: bool = False  # the failure is not the pair's (e.g. the model cannot be loaded): stop the batch

    def row(self) -> dict[str, Any]:
        """The pair's summary.csv row (None for unknown values)."""
        r = self.report or {}
        cams = {side: r.get(side) or {} for side in ("left", "right")}
        row: dict[str, Any] = {"name": self.name, "status": self.status, "error": self.error}
        for side, cam in cams.items():
            for key in ("focal_px", "vfov_deg", "roll_deg", "pitch_deg"):
                row[f"{side}_{key}"] = cam.get(key)
        row["rotation_deg"] = (r.get("pose") or {}).get("rotation_deg")
        row["baseline_m"] = r.get("baseline_m")
        row["matches"] = (r.get("matches") or {}).get("found")
        row["inliers"] = (r.get("matches") or {}).get("inliers")
        row["time_ms"] = round(self.time_ms, 1) if self.status == "ok" else None
        row["left_file"] = str(self.left) if self.left else ""
        row["right_file"] = str(self.right) if self.right else ""
        return row


def _finite(value: Any) -> float | None:
    return float(value) if value is not None and math.isfinite(float(value)) else None


def json_safe(value: Any) -> Any:
    """``value`` with NumPy numbers made Python's and non-finite floats None, as JSON takes them."""
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    if isinstance(value, float | np.floating):
        return _finite(value)
    if isinstance(value, np.integer):
        return int(value)
    return value
