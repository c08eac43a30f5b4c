"""``batch-calibrate``: every stereo pair of a folder, one network session per process.

Pair discovery (:func:`discover_pairs`), in this order — the first layout present is the only one used:

1. ``FOLDER/left/`` and ``FOLDER/right/``: a pair is a left and a right image with the **same name
   stem** (``left/0001.png`` + ``right/0001.png``; the extensions may differ). ``make-data`` datasets and
   the evaluation sets (``calib.jsonl`` beside ``left/`` and ``right/``) have this layout.
2. ``FOLDER/cam0/`` (left) and ``FOLDER/cam1/`` (right), matched the same way; EuRoC/ASL's
   ``cam0/data/`` and ``cam1/data/`` are used when present.
3. Otherwise the images in ``FOLDER`` itself: ``<name>_left.<ext>`` + ``<name>_right.<ext>`` or
   ``<name>_L.<ext>`` + ``<name>_R.<ext>`` (suffixes in any letter case; the two styles may be mixed).

Everywhere: an image is a file whose extension, in any letter case, is one OpenCV decodes
(:data:`IMAGE_EXTENSIONS`); other files are ignored; folders are not searched recursively. The pair's name
is the stem (layouts 1, 2) or ``<name>`` (layout 3); its results go to ``OUT/<name>/``. A left image
without its right (or the reverse), two images of one side with the same name (``a.png`` and ``a.jpg``),
and in layout 3 an image without a side suffix, are each reported on one line and **count as failed
pairs**. A folder without a single pair is an error (exit code 2). Pairs are in natural sort order
(``img2`` before ``img10``), the same on every machine.

Sharding: ``--shard i/n`` (1-based: ``1/4`` … ``4/4``) takes the entries ``i-1, i-1+n, i-1+2n, …`` of that
sorted list, unmatched entries included, so the shards of a job array cover every entry exactly once.

Same rig (``--same-rig``, :func:`calibrate_rig`): one focal length per camera and one R, T from all pairs,
gravity per pair. Pass 1 calibrates each pair alone. Per camera the focal lengths are combined in log f: the
median as a robust centre (one vote per pair: a confidently wrong pair cannot pull it), pairs further than
3·max(σᵢ, 1.4826·MAD) from it rejected, then the inverse-variance weighted mean of the rest (σ inflated by the
Birge ratio when the pairs scatter more than their σ say, and never below a typical pair's σ: the network's
error on one camera is mostly common to all its pairs). Pass 2 re-runs every pair with those focal lengths
held fixed, which re-estimates its gravity and its relative pose with consistent intrinsics. The matches
consistent with a pair's pass-2 pose (Sampson error below :data:`POOL_THRESHOLD_PX`) of all pairs are
concatenated — they share K and R, T, so this is exact — into one relative-pose estimation, with the chordal
mean of the pairs' rotations and the mean of their translation directions as the prior. The baseline is
``--baseline`` or the median of the pairs' learned baselines.
"""

from __future__ import annotations

import csv
import io
import json
import math
import multiprocessing
import os
import re
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from stereogeo_cli.errors import CalibrationFailed, StereoGeoError
from stereogeo_cli.pipeline import calibrator_conf

IMAGE_EXTENSIONS = frozenset(
    ".png .jpg .jpeg .jpe .jp2 .tif .tiff .bmp .dib .webp .ppm .pgm .pbm .pnm .pxm .pfm .sr .ras .exr .hdr "
    ".pic".split()
)  # what cv2.imdecode reads (when OpenCV is built with the codec)
POOL_THRESHOLD_PX = 2.0  # a match joins the same-rig pool if its Sampson error under its pair's pose is below
FOCAL_REJECT_SIGMAS = 3.0  # same-rig: focal estimates this many sigmas from the weighted median are dropped
# same-rig: the share of one pair's focal variance that every pair of the rig has in common. The network's
# error on one camera is mostly a bias of that camera (the same lens, the same kind of scene), which no
# number of pairs averages away and which the pairs' scatter cannot show; 1 keeps the combined focal
# length's sigma at least a typical pair's (docs/batch.md, "Same rig")
FOCAL_COMMON_SHARE = 1.0
RIG_FOLDER = "rig"
CSV_COLUMNS = (
    "name", "status", "error",
    "left_focal_px", "left_vfov_deg", "left_roll_deg", "left_pitch_deg",
    "right_focal_px", "right_vfov_deg", "right_roll_deg", "right_pitch_deg",
    "rotation_deg", "baseline_m", "matches", "inliers", "time_ms", "left_file", "right_file",
)  # fmt: skip
NUMERIC_COLUMNS = CSV_COLUMNS[3:16]
_SIDE_SUFFIX = re.compile(r"^(?P<name>.+)_(?P<side>left|right|l|r)$", re.IGNORECASE)


# ---------------------------------------------------------------------------------------------- discovery
@dataclass(frozen=True)
class PairEntry:
    """A discovered pair, or a name that could not be made into one (``problem`` says why)."""

    name: str
    left: Path | None
    right: Path | None
    problem: str | None = None


def _natural_key(name: str) -> tuple:
    return tuple(int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)), name


def _images(folder: Path) -> list[Path]:
    return [p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file()]


def _child_folder(folder: Path, name: str) -> Path | None:
    found = [p for p in folder.iterdir() if p.is_dir() and p.name.lower() == name]
    return sorted(found)[0] if found else None


def _match(groups: dict[str, dict[str, list[Path]]], labels: tuple[str, str]) -> list[PairEntry]:
    """Entries from ``{name: {"left": [paths], "right": [paths]}}``; labels name the sides in messages."""
    entries = []
    for name, sides in groups.items():
        left, right = sides.get("left", []), sides.get("right", [])
        for side_files, label in ((left, labels[0]), (right, labels[1])):
            if len(side_files) > 1:
                listed = ", ".join(p.name for p in sorted(side_files))
                entries.append(PairEntry(name, None, None, f"several {label} images named {name}: {listed}"))
                break
        else:
            if left and right:
                entries.append(PairEntry(name, left[0], right[0]))
            elif left:
                entries.append(PairEntry(name, left[0], None, f"{left[0].name} has no {labels[1]} image"))
            else:
                entries.append(PairEntry(name, None, right[0], f"{right[0].name} has no {labels[0]} image"))
    return entries


def discover_pairs(folder: str | os.PathLike) -> list[PairEntry]:
    """The pairs of ``folder`` (rules in the module docstring), in natural sort order of their names.

    Raises :class:`StereoGeoError` (exit code 2) for a missing folder or one without any pair.
    """
    folder = Path(folder)
    if not folder.exists():
        raise StereoGeoError(f"folder not found: {folder}")
    if not folder.is_dir():
        raise StereoGeoError(f"{folder} is not a folder")
    groups: dict[str, dict[str, list[Path]]] = {}
    entries: list[PairEntry] = []
    for left_name, right_name in (("left", "right"), ("cam0", "cam1")):
        left_dir, right_dir = _child_folder(folder, left_name), _child_folder(folder, right_name)
        if left_dir is None and right_dir is None:
            continue
        if left_dir is None or right_dir is None:
            have, missing = (left_name, right_name) if right_dir is None else (right_name, left_name)
            raise StereoGeoError(f"{folder} has a {have}/ folder but no {missing}/ folder")
        labels = (left_dir.name + "/", right_dir.name + "/")
        for side, side_dir in (("left", left_dir), ("right", right_dir)):
            if (side_dir / "data").is_dir() and not _images(side_dir):  # EuRoC / ASL: cam0/data/*.png
                side_dir = side_dir / "data"
            for path in _images(side_dir):
                groups.setdefault(path.stem, {}).setdefault(side, []).append(path)
        entries = _match(groups, labels)
        layout = f"{labels[0]} + {labels[1]}"
        break
    else:
        layout = "<name>_left/_right or <name>_L/_R image files"
        for path in _images(folder):
            m = _SIDE_SUFFIX.match(path.stem)
            if m is None:
                problem = f"{path.name} is not part of a pair: its name must end in _left, _right, _L or _R"
                entries.append(PairEntry(path.stem, None, None, problem))
                continue
            side = "left" if m["side"].lower() in ("left", "l") else "right"
            groups.setdefault(m["name"], {}).setdefault(side, []).append(path)
        entries += _match(groups, ("left", "right"))
    if not any(e.problem is None for e in entries):
        found = f" ({len(entries)} unmatched image{'s' * (len(entries) != 1)})" if entries else ""
        raise StereoGeoError(f"no stereo pairs in {folder}{found}; expected {layout} (see docs/batch.md)")
    return sorted(entries, key=lambda e: _natural_key(e.name))


def parse_shard(text: str) -> tuple[int, int]:
    """``"i/n"`` → (i, n), 1-based (1 ≤ i ≤ n); anything else raises :class:`StereoGeoError` (exit code 2)."""
    m = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", text)
    if m is None:
        raise StereoGeoError(f"--shard must look like i/n (e.g. 1/4), got {text!r}")
    i, n = int(m[1]), int(m[2])
    if n < 1 or not 1 <= i <= n:
        hint = " (shards are numbered from 1)" if i == 0 else ""
        raise StereoGeoError(f"--shard {text}: i must be between 1 and n, and n at least 1{hint}")
    return i, n


def select_shard(entries: Sequence[PairEntry], shard: tuple[int, int] | None) -> list[PairEntry]:
    """Every n-th entry starting at entry i-1 for ``shard = (i, n)``; all entries for None."""
    if shard is None:
        return list(entries)
    i, n = shard
    return list(entries[i - 1 :: n])


# ------------------------------------------------------------------------------------------ per-pair work
@dataclass(frozen=True)
class PairJob:
    """What to do with each pair: the same for every pair of a pass."""

    out_dir: Path | None  # per-pair files go to out_dir/<name>/; None: write nothing
    formats: tuple[str, ...]
    baseline_m: float | None
    model: Path | None
    threads: int
    focal_left: float | None = None
    focal_right: float | None = None
    keep_evidence: bool = False  # keep what --same-rig needs (focal, gravity, pose, matches)
    pinhole: bool = False  # --pinhole: fit no lens distortion
    lines: bool = True  # --no-lines: gravity from the fields alone, no vertical line segments
    exif: bool = True  # --no-exif: no EXIF focal length as a prior


@dataclass
class RigEvidence:
    """What one pair tells about its rig (pixels, radians, unit vectors; matches [N x 2] pixels)."""

    size_left: tuple[int, int]
    size_right: tuple[int, int]
    focal: tuple[float, float]  # left, right
    focal_sigma: tuple[float, float]
    gravity_left: np.ndarray
    gravity_right: np.ndarray
    R: np.ndarray
    t_direction: np.ndarray
    pose_source: str
    baseline_m: float
    matches_left: np.ndarray
    matches_right: np.ndarray
    distortion: tuple[float, float] = (0.0, 0.0)  # division-model k per camera, for the refined focal
    # per camera the EXIF (or given) prior (focal, sigma) in pixels that the pair's focal took in, or None;
    # where there is one, ``focal`` and ``focal_sigma`` are the fields' own, so that --same-rig counts the
    # prior once (a focal length combined with the image's straight edges has none: pipeline._with_manhattan)
    focal_prior: tuple[tuple[float, float] | None, tuple[float, float] | None] = (None, None)


@dataclass
class PairOutcome:
    """One pair's result: ``status`` "ok" with its JSON ``report``, or "failed" with ``error``."""

    name: str
    left: Path | None
    right: Path | None
    status: str
    error: str = ""
    report: dict[str, Any] | None = None
    time_ms: float = 0.0
    evidence: RigEvidence | None = None
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


def _evidence(result) -> RigEvidence:
    matches = result.matches
    empty = np.zeros((0, 2))
    priors = result.calibration.extra_report.get("focal_prior") or [None, None]
    focal, sigma, prior = [], [], []
    for fit, entry in zip((result.left, result.right), priors, strict=True):
        fields_sigma = None if entry is None else entry.get("fields_sigma_px")
        # a focal length combined with its straight edges' is the pair's own evidence, as the fields' alone is
        # (each pair's edges are another scene's; an EXIF prior is one camera's tags, counted once)
        if entry is None or fields_sigma is None or entry.get("source") == "lines":
            focal.append(fit.focal_px)
            sigma.append(fit.sigma["focal_px"])
            prior.append(None)
        else:  # the fields' own reading, scaled by what the matches did to the combined focal
            scale = fit.focal_px / entry["combined_focal_px"]
            focal.append(entry["fields_focal_px"] * scale)
            sigma.append(fields_sigma * scale)
            prior.append((entry["focal_px"], entry["sigma_px"]))
    return RigEvidence(
        size_left=(result.left.width, result.left.height),
        size_right=(result.right.width, result.right.height),
        focal=(focal[0], focal[1]),
        focal_sigma=(sigma[0], sigma[1]),
        focal_prior=(prior[0], prior[1]),
        gravity_left=np.asarray(result.left.gravity_up, dtype=float),
        gravity_right=np.asarray(result.right.gravity_up, dtype=float),
        R=np.asarray(result.pose.R, dtype=float),
        t_direction=np.asarray(result.pose.t_direction, dtype=float),
        pose_source=result.pose.source,
        baseline_m=result.calibration.baseline_m,
        matches_left=empty if matches is None else np.asarray(matches.left, dtype=float),
        matches_right=empty if matches is None else np.asarray(matches.right, dtype=float),
        distortion=tuple(result.pose.distortion),
    )


def calibrate_pair(calibrator, entry: PairEntry, job: PairJob) -> PairOutcome:
    """Load, calibrate and (if ``job.out_dir``) write one pair; any failure becomes a "failed" outcome."""
    from stereogeo_cli.io import load_pair, write_calibration
    from stereogeo_cli.io.exif import exif_focals

    start = time.perf_counter()
    outcome = PairOutcome(entry.name, entry.left, entry.right, "failed")
    try:
        left, right = load_pair(entry.left, entry.right)
        result = calibrator.calibrate(
            left, right, baseline_m=job.baseline_m, focal_left=job.focal_left, focal_right=job.focal_right,
            exif=exif_focals((entry.left, entry.right), (left, right)) if job.exif else None,
        )  # fmt: skip
        if job.out_dir is not None:
            write_calibration(job.out_dir / entry.name, result.calibration, job.formats)
        outcome.status, outcome.report = "ok", _json_safe(result.report())
        if job.keep_evidence:
            outcome.evidence = _evidence(result)
    except StereoGeoError as error:
        outcome.error = str(error)
    except Exception as error:  # noqa: BLE001 - one pair's bug must not stop the batch
        first = str(error).strip().splitlines()[0] if str(error).strip() else ""
        outcome.error = f"internal error: {type(error).__name__}{': ' + first if first else ''}"
    outcome.time_ms = (time.perf_counter() - start) * 1e3
    return outcome


_WORKER: dict[str, Any] = {}  # the process's Calibrator in a worker process


def _init_worker(threads: int) -> None:
    import cv2

    cv2.setNumThreads(max(threads, 1))


def _worker_task(entry: PairEntry, job: PairJob) -> PairOutcome:
    key = (job.model, job.threads, job.pinhole, job.lines)
    if _WORKER.get("key") != key:
        from stereogeo_cli.pipeline import Calibrator

        try:
            calibrator = Calibrator(
                job.model, threads=job.threads, conf=calibrator_conf(job.pinhole, job.lines)
            )
            _WORKER["calibrator"], _WORKER["key"] = calibrator, key
        except StereoGeoError as error:
            return PairOutcome(entry.name, entry.left, entry.right, "failed", str(error), fatal=True)
    return calibrate_pair(_WORKER["calibrator"], entry, job)


class _Progress:
    """Reports finished pairs on stderr: a Rich progress bar on a terminal, else one plain line per pair."""

    def __init__(self, rich: bool):
        self.rich = rich
        self.bar = None

    def __enter__(self) -> _Progress:
        if self.rich:
            from rich.console import Console
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

            self.bar = Progress(
                TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                console=Console(stderr=True), transient=False,
            )  # fmt: skip
            self.bar.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        if self.bar is not None:
            self.bar.__exit__(*exc)

    def stage(self, description: str, total: int) -> None:
        self.done, self.total, self.description = 0, total, description
        if self.bar is not None:
            self.task = self.bar.add_task(description, total=total)

    def line(self, text: str) -> None:
        if self.bar is not None:
            self.bar.console.print(text, markup=False, highlight=False)
        else:
            print(text, file=sys.stderr, flush=True)

    def finished(self, outcome: PairOutcome) -> None:
        self.done += 1
        if outcome.status != "ok":
            self.line(f"{self.description}: {outcome.name}: failed: {outcome.error}")
        elif self.bar is None:
            done = f"{self.done}/{self.total}"
            self.line(f"{self.description}: {done} {outcome.name}: ok ({outcome.time_ms:.0f} ms)")
        if self.bar is not None:
            self.bar.advance(self.task)


def _run_pass(entries: list[PairEntry], job: PairJob, workers: int, calibrator, progress: _Progress):
    """Outcomes of ``entries`` in their order, whatever the order in which they finish."""
    outcomes: list[PairOutcome | None] = [None] * len(entries)
    if workers <= 1 or len(entries) <= 1:
        for i, entry in enumerate(entries):
            outcomes[i] = calibrate_pair(calibrator(), entry, job)
            progress.finished(outcomes[i])
        return outcomes
    total = job.threads if job.threads > 0 else (os.cpu_count() or 1)
    per_worker = max(1, total // workers)
    job = PairJob(**{**job.__dict__, "threads": per_worker})
    # spawn: a fresh interpreter per worker (no forked ONNX Runtime / OpenCV thread pools)
    with ProcessPoolExecutor(
        max_workers=min(workers, len(entries)), mp_context=multiprocessing.get_context("spawn"),
        initializer=_init_worker, initargs=(per_worker,),
    ) as pool:  # fmt: skip
        futures = {pool.submit(_worker_task, entry, job): i for i, entry in enumerate(entries)}
        try:
            for future in as_completed(futures):
                outcome = future.result()
                if outcome.fatal:
                    raise StereoGeoError(outcome.error)
                outcomes[futures[future]] = outcome
                progress.finished(outcome)
        except BaseException:
            pool.shutdown(wait=True, cancel_futures=True)
            raise
    return outcomes


# ------------------------------------------------------------------------------------------ same-rig maths
@dataclass(frozen=True)
class FocalEstimate:
    """A combined focal length in pixels, its 1-sigma, and which inputs were used."""

    focal_px: float
    sigma_px: float
    used: np.ndarray  # [N] bool


def combine_focals(focals: Sequence[float], sigmas: Sequence[float]) -> FocalEstimate:
    """Robust inverse-variance combination of focal estimates [N] (pixels) with 1-sigmas [N], in log f.

    Centre: the median (not weighted: a pair with a small but wrong sigma must not own it). Rejected:
    estimates more than 3·max(σᵢ, 1.4826·MAD) from it. Result: the weighted mean (w = 1/σ²) of the rest;
    its sigma is √(1/Σw) times the Birge ratio √(χ²/(k-1)) when that exceeds 1 (the estimates scatter more
    than their sigmas say), and at least √FOCAL_COMMON_SHARE times the median sigma of the pairs used (the
    error they have in common does not average away). A missing or non-finite sigma counts as the largest
    finite one (or 100 % when there is none).
    """
    f = np.asarray(focals, dtype=float)
    s = np.asarray(sigmas, dtype=float) / f  # sigma of log f
    if f.size == 0 or not np.all(np.isfinite(f) & (f > 0)):
        raise ValueError("focal estimates must be positive and finite")
    finite = np.isfinite(s) & (s > 0)
    s = np.where(finite, s, np.max(s[finite]) if finite.any() else 1.0)
    s = np.maximum(s, 1e-6)
    x, w = np.log(f), 1.0 / s**2
    centre = float(np.median(x))
    spread = 1.4826 * float(np.median(np.abs(x - centre)))
    used = np.abs(x - centre) <= FOCAL_REJECT_SIGMAS * np.maximum(s, spread)
    xu, wu = x[used], w[used]
    mean = float(np.sum(wu * xu) / np.sum(wu))
    sigma = math.sqrt(1.0 / float(np.sum(wu)))
    if used.sum() > 1:
        birge = math.sqrt(float(np.sum(wu * (xu - mean) ** 2)) / (used.sum() - 1))
        sigma *= max(1.0, birge)
    sigma = max(sigma, math.sqrt(FOCAL_COMMON_SHARE) * float(np.median(s[used])))
    focal = math.exp(mean)
    return FocalEstimate(focal, focal * sigma, used)


def chordal_mean(rotations: Sequence[np.ndarray]) -> np.ndarray:
    """The rotation nearest (Frobenius) to the mean of rotations [N x 3 x 3]."""
    from stereogeo_cli.geometry import closest_rotation

    return closest_rotation(np.sum(np.asarray(rotations, dtype=float), axis=0))


def pool_matches(evidence: Sequence[RigEvidence], K_left: np.ndarray, K_right: np.ndarray):
    """All pairs' matches consistent with their own pose (Sampson error < POOL_THRESHOLD_PX) as one Matches.

    The matches are judged after undoing the pair's own lens distortion, and pooled as observed (the joint
    fit estimates the distortion again). Pairs whose pose did not come from matches add nothing. Returns
    (Matches, inliers per pair [N]).
    """
    from stereogeo_cli.fuse import Matches, sampson_errors
    from stereogeo_cli.geometry import fundamental_matrix, intrinsic_matrix, undistort_division

    left, right, counts = [], [], []
    for ev in evidence:
        if ev.pose_source != "matches" or len(ev.matches_left) == 0:
            counts.append(0)
            continue
        F = fundamental_matrix(K_left, K_right, ev.R, ev.t_direction)
        # the pair's lens undone (its k belongs to its own focal; the pixels stay the same pixels)
        seen = [
            undistort_division(points, intrinsic_matrix(focal, *size), k)
            for points, size, focal, k in zip(
                (ev.matches_left, ev.matches_right),
                (ev.size_left, ev.size_right),
                ev.focal,
                ev.distortion,
                strict=True,
            )
        ]
        keep = np.abs(sampson_errors(F, *seen)) < POOL_THRESHOLD_PX
        left.append(ev.matches_left[keep])
        right.append(ev.matches_right[keep])
        counts.append(int(keep.sum()))
    if not left:
        return Matches(np.zeros((0, 2)), np.zeros((0, 2))), counts
    return Matches(np.concatenate(left), np.concatenate(right)), counts


def _same_sizes(outcomes: Sequence[PairOutcome]) -> None:
    for side in ("left", "right"):
        sizes = {getattr(o.evidence, f"size_{side}") for o in outcomes}
        if len(sizes) > 1:
            listed = ", ".join(f"{w}x{h}" for w, h in sorted(sizes))
            raise StereoGeoError(f"--same-rig: the {side} images differ in size ({listed}); one rig has one")


def calibrate_rig(
    first: Sequence[PairOutcome],
    second: Sequence[PairOutcome],
    focals,
    baseline_m: float | None,
    model,
    pinhole: bool = False,
    focal_sigma_scale: tuple[float, float] = (1.0, 1.0),
):
    """The joint calibration (a StereoCalibration) from pass-1 and pass-2 outcomes of the same pairs.

    ``focals``: the (left, right) :class:`FocalEstimate`; ``model``: (file name, sha256) for the report;
    ``pinhole``: fit no lens distortion; ``focal_sigma_scale``: what each focal length's reported sigma is
    widened by (the model's photo_sigma_scale, as a single pair's is: ``Calibrator.reported_sigma``).
    """
    from stereogeo_cli.fuse import fuse_relative_pose
    from stereogeo_cli.geometry import (
        corner_radius,
        gravity_angle,
        intrinsic_matrix,
        opencv_from_division,
        roll_pitch_from_gravity,
        rotation_angle,
    )
    from stereogeo_cli.io import StereoCalibration

    ok = [o for o in second if o.status == "ok"]
    if not ok:
        raise CalibrationFailed("--same-rig: no pair could be calibrated with the combined focal lengths")
    ev = [o.evidence for o in ok]
    (w_l, h_l), (w_r, h_r) = ev[0].size_left, ev[0].size_right
    K_left = intrinsic_matrix(focals[0].focal_px, w_l, h_l)
    K_right = intrinsic_matrix(focals[1].focal_px, w_r, h_r)
    pooled, counts = pool_matches(ev, K_left, K_right)
    t_mean = np.sum([e.t_direction for e in ev], axis=0)
    pose = fuse_relative_pose(
        pooled, K_left, K_right, prior_R=chordal_mean([e.R for e in ev]),
        prior_t=t_mean if np.linalg.norm(t_mean) > 1e-9 else ev[0].t_direction,
        conf=calibrator_conf(pinhole).get("fuse"),
        # the focal ratio is refined with the pose, as for a single pair: the lens shows only with it free
        focal_sigma_rel=tuple(est.sigma_px / est.focal_px for est in focals),
    )  # fmt: skip
    focals = tuple(
        replace(est, focal_px=est.focal_px * scale, sigma_px=est.sigma_px * scale)
        for est, scale in zip(focals, pose.focal_scale, strict=True)
    )
    K_left = intrinsic_matrix(focals[0].focal_px, w_l, h_l)
    K_right = intrinsic_matrix(focals[1].focal_px, w_r, h_r)
    D_left, D_right = (
        opencv_from_division(k, corner_radius(K))
        for k, K in zip(pose.distortion, (K_left, K_right), strict=True)
    )
    if baseline_m is not None:
        baseline, scale_source = float(baseline_m), "baseline"
    else:
        baseline = float(np.median([o.evidence.baseline_m for o in first if o.status == "ok"]))
        scale_source = "learned"
    pairs = []
    for o, e, n in zip(ok, ev, counts, strict=True):
        entry: dict[str, Any] = {"name": o.name, "pooled_matches": n}
        for side, g in (("left", e.gravity_left), ("right", e.gravity_right)):
            roll, pitch = roll_pitch_from_gravity(g)
            entry[f"gravity_{side}"] = [float(v) for v in g]
            entry[f"{side}_roll_deg"], entry[f"{side}_pitch_deg"] = math.degrees(roll), math.degrees(pitch)
        coupling = gravity_angle(pose.R @ e.gravity_left, e.gravity_right)  # how well R·g_left = g_right
        entry["gravity_error_deg"] = math.degrees(float(coupling))
        pairs.append(entry)

    def sigma(est: FocalEstimate, height: int, scale: float) -> dict[str, float]:
        dvfov = height * est.focal_px / (est.focal_px**2 + height * height / 4.0)  # d vfov / d log f
        s = est.sigma_px * scale
        return {"focal_px": s, "vfov_deg": math.degrees(dvfov * s / est.focal_px)}

    notes = list(pose.notes) + [
        f"joint calibration of {len(ok)} pairs; gravity per pair in 'pairs'",
        f"focal from {int(focals[0].used.sum())} (left) and {int(focals[1].used.sum())} (right) pairs",
    ]
    return StereoCalibration(
        K_left=K_left, K_right=K_right, image_size_left=(w_l, h_l), image_size_right=(w_r, h_r),
        R=pose.R, T=pose.translation(baseline), D_left=D_left, D_right=D_right,
        sigma_left=sigma(focals[0], h_l, focal_sigma_scale[0]),
        sigma_right=sigma(focals[1], h_r, focal_sigma_scale[1]),
        scale_source=scale_source, matches_found=pose.matches_found, matches_inliers=pose.inliers,
        model_file=model[0], model_sha256=model[1], notes="; ".join(notes),
        extra_report={
            "pose": {
                "source": pose.source,
                "sigma_rotation_deg": _finite(pose.sigma_rotation_deg),
                "sigma_direction_deg": _finite(pose.sigma_direction_deg),
                "rotation_deg": math.degrees(rotation_angle(pose.R)),
                "distortion_k": [float(k) for k in pose.distortion],
                "sigma_distortion_k": [_finite(s) for s in pose.sigma_distortion],
            },
            "pairs": pairs,
            "warnings": list(pose.notes),
        },
    )  # fmt: skip


# ---------------------------------------------------------------------------------------------- the batch
@dataclass
class BatchSummary:
    """What a batch did: outcomes in sorted order, the files written, and the same-rig result or error."""

    outcomes: list[PairOutcome]
    written: list[Path] = field(default_factory=list)
    rig: Any = None  # the joint StereoCalibration of --same-rig
    rig_error: StereoGeoError | None = None
    json_text: str = ""

    @property
    def failed(self) -> int:
        return sum(o.status != "ok" for o in self.outcomes)


def _finite(value: Any) -> float | None:
    return float(value) if value is not None and math.isfinite(float(value)) else None


def _json_safe(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    if isinstance(value, float | np.floating):
        return _finite(value)
    if isinstance(value, np.integer):
        return int(value)
    return value


def medians(outcomes: Sequence[PairOutcome]) -> dict[str, float | None]:
    """Median of each numeric summary column over the pairs that succeeded (None when there is none)."""
    rows = [o.row() for o in outcomes if o.status == "ok"]
    result = {}
    for column in NUMERIC_COLUMNS:
        values = [float(r[column]) for r in rows if r[column] is not None]
        result[column] = float(np.median(values)) if values else None
    return result


def summary_files(
    outcomes: Sequence[PairOutcome], folder: Path, shard: tuple[int, int] | None, rig: dict | None
) -> dict[str, str]:
    """``{file name: text}`` of summary.csv and summary.json (``summary-shard-i-of-n.*`` for a shard)."""
    stem = "summary" if shard is None else f"summary-shard-{shard[0]}-of-{shard[1]}"
    text = io.StringIO()
    writer = csv.DictWriter(text, CSV_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for outcome in outcomes:
        writer.writerow({k: "" if v is None else v for k, v in outcome.row().items()})
    ok = sum(o.status == "ok" for o in outcomes)
    summary = {
        "folder": str(folder),
        "shard": None if shard is None else f"{shard[0]}/{shard[1]}",
        "counts": {"pairs": len(outcomes), "ok": ok, "failed": len(outcomes) - ok},
        "medians": medians(outcomes),
        "pairs": [
            {
                "name": o.name,
                "status": o.status,
                "error": o.error or None,
                "left_file": str(o.left) if o.left else None,
                "right_file": str(o.right) if o.right else None,
                "time_ms": round(o.time_ms, 1) if o.status == "ok" else None,
                "report": o.report,
            }
            for o in outcomes
        ],
    }
    if rig is not None:
        summary["rig"] = rig
    return {f"{stem}.csv": text.getvalue(), f"{stem}.json": json.dumps(_json_safe(summary), indent=2) + "\n"}


def run_batch(
    folder: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    formats: tuple[str, ...] = ("opencv", "json"),
    baseline_m: float | None = None,
    model: Path | None = None,
    threads: int = 0,
    workers: int = 1,
    same_rig: bool = False,
    shard: tuple[int, int] | None = None,
    progress: bool = False,
    pinhole: bool = False,
    lines: bool = True,
    exif: bool = True,
) -> BatchSummary:
    """Calibrate every pair of ``folder`` into ``out_dir/<name>/``, write the summaries (and ``rig/``).

    Args:
        formats: output formats of each pair (and of the joint calibration).
        workers: processes; each has its own network session with ``threads // workers`` threads.
        progress: a Rich progress bar on stderr (else one plain line per pair there).
        pinhole: the images have no lens distortion (rectified or undistorted): none is fitted.
        lines: fit each camera's gravity to the image's vertical line segments too (docs/refine.md).
        exif: take each photo's EXIF focal length as a prior (stereogeo_cli/io/exif.py).
    Raises:
        StereoGeoError: no pairs (exit code 2), or a model that cannot be loaded. A pair that fails does
        not raise: its outcome is "failed". A failed joint calibration is returned in ``rig_error``.
    """
    folder, out_dir = Path(folder), Path(out_dir)
    entries = select_shard(discover_pairs(folder), shard)
    if same_rig and any(e.name == RIG_FOLDER for e in entries):
        raise StereoGeoError(f"--same-rig writes {out_dir / RIG_FOLDER}/, but a pair is named {RIG_FOLDER!r}")
    calibrator_cache: list = []

    def calibrator():  # the in-process session, made once (and only when needed)
        if not calibrator_cache:
            from stereogeo_cli.pipeline import Calibrator

            calibrator_cache.append(Calibrator(model, threads=threads, conf=calibrator_conf(pinhole, lines)))
        return calibrator_cache[0]

    if workers <= 1 and any(e.problem is None for e in entries):
        calibrator()  # a bad model fails here, before any pair
    job = PairJob(
        out_dir, formats, baseline_m, model, threads, keep_evidence=same_rig, pinhole=pinhole, lines=lines,
        exif=exif,
    )  # fmt: skip
    pairs = [e for e in entries if e.problem is None]
    outcomes_by_name: dict[str, PairOutcome] = {}
    with _Progress(progress) as bar:
        for e in entries:
            if e.problem is not None:
                bar.line(f"unmatched: {e.problem}")
                outcomes_by_name[e.name] = PairOutcome(e.name, e.left, e.right, "failed", e.problem)
        bar.stage("calibrating", len(pairs))
        for outcome in _run_pass(pairs, job, workers, calibrator, bar):
            outcomes_by_name[outcome.name] = outcome
        outcomes = [outcomes_by_name[e.name] for e in entries]
        summary = BatchSummary(outcomes)
        if same_rig:
            try:
                summary.rig = _same_rig(outcomes, job, workers, calibrator, bar, baseline_m)
            except StereoGeoError as error:
                summary.rig_error = error
    from stereogeo_cli.io import write_calibration
    from stereogeo_cli.io.atomic import write_files_atomically

    rig_entry = None
    if summary.rig is not None:
        summary.written += write_calibration(out_dir / RIG_FOLDER, summary.rig, formats)
        rig_entry = {"folder": RIG_FOLDER, "report": _json_safe(summary.rig.to_report())}
    elif summary.rig_error is not None:
        rig_entry = {"folder": None, "error": str(summary.rig_error)}
    files = summary_files(outcomes, folder, shard, rig_entry)
    summary.json_text = files[next(k for k in files if k.endswith(".json"))]
    summary.written += write_files_atomically(out_dir, files)
    return summary


def _with_exif_prior(fields: FocalEstimate, priors: list[tuple[float, float]]) -> FocalEstimate:
    """The rig's focal from its pairs' fields, combined once with their photos' EXIF focal (the median of
    their priors, with one prior's sigma: the photos of one camera share the error of its tags)."""
    from stereogeo_cli.refine import combine_focal

    if not priors:
        return fields
    prior = float(np.median([p[0] for p in priors]))
    sigma_rel = float(np.median([p[1] / p[0] for p in priors]))
    focal, sigma = combine_focal(fields.focal_px, fields.sigma_px, prior, prior * sigma_rel)
    return replace(fields, focal_px=focal, sigma_px=sigma)


def _same_rig(outcomes, job: PairJob, workers, calibrator, bar: _Progress, baseline_m):
    start = time.perf_counter()
    ok = [o for o in outcomes if o.status == "ok"]
    if not ok:
        raise CalibrationFailed("--same-rig: no pair was calibrated, so there is nothing to combine")
    _same_sizes(ok)
    focals = tuple(
        _with_exif_prior(
            combine_focals([o.evidence.focal[i] for o in ok], [o.evidence.focal_sigma[i] for o in ok]),
            [o.evidence.focal_prior[i] for o in ok if o.evidence.focal_prior[i] is not None],
        )
        for i in (0, 1)
    )
    second_job = PairJob(
        None, job.formats, job.baseline_m, job.model, job.threads,
        focal_left=focals[0].focal_px, focal_right=focals[1].focal_px, keep_evidence=True,
        pinhole=job.pinhole, lines=job.lines, exif=job.exif,
    )  # fmt: skip
    bar.stage("same rig", len(ok))
    entries = [PairEntry(o.name, o.left, o.right) for o in ok]
    second = _run_pass(entries, second_job, workers, calibrator, bar)
    model_info = (ok[0].report or {}).get("model") or {}
    model_id = (model_info.get("file"), model_info.get("sha256"))
    # the rig's focal lengths are reported as a single pair's are: widened for photographs unless an EXIF
    # prior took part (Calibrator.reported_sigma)
    photo = calibrator().photo_sigma_scale[2]
    scale = tuple(1.0 if any(o.evidence.focal_prior[i] is not None for o in ok) else photo for i in (0, 1))
    rig = calibrate_rig(
        ok, second, focals, baseline_m, model_id, pinhole=job.pinhole, focal_sigma_scale=scale
    )
    return replace(rig, timing_ms={"total": (time.perf_counter() - start) * 1e3})  # the same-rig stage
