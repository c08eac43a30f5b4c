"""Running ``batch-calibrate``: each pair in a worker process (one network session each), progress, the
per-pair results and the summary files; on SIGINT or SIGTERM the pairs done are kept and summarised
(:mod:`~stereogeo_cli.batch.interrupt`), and ``resume`` takes them from their folders
(:mod:`~stereogeo_cli.batch.resume`)."""

from __future__ import annotations

import csv
import io
import json
import math
import multiprocessing
import os
import sys
import time
from collections.abc import Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from stereogeo_cli.batch.discovery import PairEntry, discover_pairs, select_shard
from stereogeo_cli.batch.interrupt import (
    Interrupted,
    Stop,
    protected,
    signals_blocked,
    worker_exits_with_parent,
    worker_ignores_signals,
)
from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.io.text import plural
from stereogeo_cli.pipeline import calibrator_conf, usable_cores

RIG_FOLDER = "rig"  # --same-rig: the joint calibration's folder in OUT
CSV_COLUMNS = (
    "name", "status", "error",
    "left_focal_px", "left_vfov_deg", "left_roll_deg", "left_pitch_deg",
    "right_focal_px", "right_vfov_deg", "right_roll_deg", "right_pitch_deg",
    "rotation_deg", "baseline_m", "matches", "inliers", "time_ms", "left_file", "right_file",
)  # fmt: skip
NUMERIC_COLUMNS = CSV_COLUMNS[3:16]


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
    rotate: int = 0  # --rotate: degrees both images are turned clockwise before they are read


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
    """One pair's result: ``status`` "ok" with its JSON ``report``, "failed" with ``error``, or "not run"
    (the batch was stopped before it)."""

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
    focal, sigma, prior = [], [], []
    for fit, source in zip((result.left, result.right), result.focal_sources, strict=True):
        # a focal length combined with its straight edges' is the pair's own evidence, as the fields' alone is
        # (each pair's edges are another scene's; an EXIF prior is one camera's tags, counted once)
        if source is None or not math.isfinite(source.fields_sigma_px) or source.source == "lines":
            focal.append(fit.focal_px)
            sigma.append(fit.sigma["focal_px"])
            prior.append(None)
        else:  # the fields' own reading, scaled by what the matches did to the combined focal
            scale = fit.focal_px / source.combined_focal_px
            focal.append(source.fields_focal_px * scale)
            sigma.append(source.fields_sigma_px * scale)
            prior.append((source.focal_px, source.sigma_px))
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


def load_entry(entry: PairEntry, job: PairJob) -> tuple[np.ndarray, np.ndarray, tuple | None]:
    """A pair's images (checked as a pair) and, if ``job.exif``, what their EXIF says of the focal length."""
    from stereogeo_cli.io import load_pair
    from stereogeo_cli.io.exif import exif_focals

    left, right = load_pair(entry.left, entry.right)
    return left, right, exif_focals((entry.left, entry.right), (left, right)) if job.exif else None


def calibrate_pair(
    calibrator, entry: PairEntry, job: PairJob, loading: Future | None = None, upcoming=None
) -> PairOutcome:
    """Load, calibrate and (if ``job.out_dir``) write one pair, its marker last (``batch/resume.py``); any
    failure becomes a "failed" outcome.

    ``loading``: the pair's :func:`load_entry`, already under way; ``upcoming``: the next pair's images
    when they are loaded (:meth:`stereogeo_cli.pipeline.Calibrator.calibrate`)."""
    start = time.perf_counter()
    outcome = PairOutcome(entry.name, entry.left, entry.right, "failed")
    try:
        left, right, exif = loading.result() if loading is not None else load_entry(entry, job)
        result = calibrator.calibrate(
            left, right, baseline_m=job.baseline_m, focal_left=job.focal_left, focal_right=job.focal_right,
            exif=exif, upcoming=upcoming, rotate=job.rotate,
        )  # fmt: skip
        report = _json_safe(result.report())
        evidence = _evidence(result) if job.keep_evidence else None
        if job.out_dir is not None:
            from stereogeo_cli.batch.resume import pair_options, write_pair_files

            options = pair_options(
                report.get("model") or {}, job.baseline_m, job.pinhole, job.lines, job.exif, job.rotate
            )
            try:
                with protected():  # the pair's files and marker all written, even if a second Ctrl-C comes
                    outcome.time_ms = write_pair_files(
                        job.out_dir / entry.name, result.calibration, job.formats, evidence,
                        (entry.left, entry.right), options, report, start,
                    )  # fmt: skip
            except Interrupted as stop_now:  # it came meanwhile: the pair is done, and the batch stops
                outcome.status, outcome.report, outcome.evidence = "ok", report, evidence
                stop_now.outcome = outcome
                raise
        outcome.status, outcome.report, outcome.evidence = "ok", report, evidence
    except StereoGeoError as error:
        outcome.error = str(error)
    except Exception as error:  # noqa: BLE001 - one pair's bug must not stop the batch
        first = str(error).strip().splitlines()[0] if str(error).strip() else ""
        outcome.error = f"internal error: {type(error).__name__}{': ' + first if first else ''}"
    if not outcome.time_ms:  # else as the pair's marker records it
        outcome.time_ms = (time.perf_counter() - start) * 1e3
    return outcome


_WORKER: dict[str, Any] = {}  # the process's Calibrator in a worker process


def _init_worker(threads: int) -> None:
    worker_ignores_signals()  # Ctrl-C reaches the whole process group: the parent stops the workers
    worker_exits_with_parent()  # a parent killed outright (SIGKILL) cannot: the worker ends with it
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


def _images_when_loaded(loading: Future | None, stop: Stop | None = None):
    """For ``Calibrator.calibrate``'s ``upcoming``: the pair's images if ``loading`` has loaded them by
    then, else None (still loading, or failed: the pair's own turn reports why; or the batch is stopping)."""

    def images():
        if loading is None or not loading.done() or loading.exception() is not None:
            return None
        if stop is not None and stop.requested:
            return None
        left, right, _ = loading.result()
        return left, right

    return images


def _run_pass(
    entries: list[PairEntry], job: PairJob, workers: int, calibrator, progress: _Progress,
    stop: Stop | None = None, outcomes: list[PairOutcome | None] | None = None,
) -> list[PairOutcome | None]:  # fmt: skip
    """Outcomes of ``entries`` in their order, whatever the order in which they finish, put into
    ``outcomes`` (a new list if None) as they come; None for a pair not started.

    Once ``stop`` is requested (a first SIGINT or SIGTERM) no pair is started and the pairs in flight are
    finished. An exception (a second signal's :class:`~stereogeo_cli.batch.interrupt.Interrupted`
    included) stops the workers at once: killed, with what they left half done removed.
    """
    if outcomes is None:
        outcomes = [None] * len(entries)
    if not entries:
        return outcomes

    def stopping() -> bool:
        return stop is not None and stop.requested

    if workers <= 1 or len(entries) <= 1:
        # one after the other, each pair loaded on a thread while the one before it is calibrated, and its
        # image work started on the pool while that one's last stages run
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="stereogeo-load") as loader:
            loading = loader.submit(load_entry, entries[0], job)
            for i, entry in enumerate(entries):
                if stopping():
                    break
                current, loading = loading, None
                if i + 1 < len(entries) and not stopping():
                    loading = loader.submit(load_entry, entries[i + 1], job)
                upcoming = _images_when_loaded(loading, stop)
                try:
                    outcomes[i] = calibrate_pair(calibrator(), entry, job, current, upcoming)
                except Interrupted as stop_now:  # a pair written whole before the stop is done
                    outcomes[i] = getattr(stop_now, "outcome", None)
                    raise
                progress.finished(outcomes[i])
        return outcomes
    total = job.threads if job.threads > 0 else usable_cores()
    per_worker = max(1, total // workers)
    job = PairJob(**{**job.__dict__, "threads": per_worker})
    queue = iter(enumerate(entries))
    pending: dict[Future, int] = {}
    # spawn: a fresh interpreter per worker (no forked ONNX Runtime / OpenCV thread pools); a worker ignores
    # SIGINT and SIGTERM (they reach the whole process group) and starts with them blocked until it does
    with signals_blocked():
        pool = ProcessPoolExecutor(
            max_workers=min(workers, len(entries)), mp_context=multiprocessing.get_context("spawn"),
            initializer=_init_worker, initargs=(per_worker,),
        )  # fmt: skip

    def submit_next() -> None:  # one pair per worker at a time: a stop starts no other
        for i, entry in queue:
            with signals_blocked():  # submit() starts the workers
                pending[pool.submit(_worker_task, entry, job)] = i
            return

    try:
        for _ in range(min(workers, len(entries))):
            submit_next()
        while pending:
            done, _ = wait(pending, timeout=1.0, return_when=FIRST_COMPLETED)
            for future in done:
                i = pending.pop(future)
                outcome = future.result()
                if outcome.fatal:
                    raise StereoGeoError(outcome.error)
                outcomes[i] = outcome
                progress.finished(outcome)
                if not stopping():
                    submit_next()
    except Exception:
        try:  # the pairs in flight are finished, none other started
            pool.shutdown(wait=True, cancel_futures=True)
        except BaseException:
            _kill_workers(pool, [entries[i] for i in pending.values()], job)
            raise
        raise
    except BaseException:  # Interrupted (a second signal), KeyboardInterrupt: stop now
        _kill_workers(pool, [entries[i] for i in pending.values()], job)
        raise
    pool.shutdown(wait=True)
    return outcomes


def _kill_workers(pool: ProcessPoolExecutor, in_flight: list[PairEntry], job: PairJob) -> None:
    """Stop the pool's workers at once, and remove the temporary files of the pairs they were writing (an
    atomic write leaves no half-written target, only its ``.<name>.*.tmp``): such a pair's folder lacks its
    marker, so it counts as not done."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for process in processes:
        try:
            process.kill()
        except (OSError, ValueError):
            pass
    for process in processes:
        try:
            process.join(timeout=5.0)
        except (OSError, ValueError, AssertionError):
            pass
    pool.shutdown(wait=False, cancel_futures=True)
    if job.out_dir is None:
        return
    from stereogeo_cli.io.atomic import remove_leftovers

    for entry in in_flight:
        folder = job.out_dir / entry.name
        remove_leftovers(folder)
        try:
            folder.rmdir()  # only if the pair had written nothing yet
        except OSError:
            pass


# ------------------------------------------------------------------------------------------ same-rig maths


@dataclass
class BatchSummary:
    """What a batch did: outcomes in sorted order, the files written, and the same-rig result or error;
    ``interrupted``: the signal that stopped it before its end ("SIGINT", "SIGTERM"), else None;
    ``resumed``: the pairs taken from an earlier run's folders."""

    outcomes: list[PairOutcome]
    written: list[Path] = field(default_factory=list)
    rig: Any = None  # the joint StereoCalibration of --same-rig
    rig_error: StereoGeoError | None = None
    json_text: str = ""
    interrupted: str | None = None
    resumed: int = 0

    @property
    def failed(self) -> int:
        return sum(o.status == "failed" for o in self.outcomes)

    @property
    def not_run(self) -> int:
        return sum(o.status == "not run" for o in self.outcomes)


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


def summary_stem(shard: tuple[int, int] | None) -> str:
    """The summary files' name without extension: ``summary``, or ``summary-shard-i-of-n`` for a shard."""
    return "summary" if shard is None else f"summary-shard-{shard[0]}-of-{shard[1]}"


def summary_files(
    outcomes: Sequence[PairOutcome], folder: Path, shard: tuple[int, int] | None, rig: dict | None,
    interrupted: str | None = None, resumed: int = 0,
) -> dict[str, str]:  # fmt: skip
    """``{file name: text}`` of summary.csv and summary.json (``summary-shard-i-of-n.*`` for a shard)."""
    stem = summary_stem(shard)
    text = io.StringIO()
    writer = csv.DictWriter(text, CSV_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for outcome in outcomes:
        writer.writerow({k: "" if v is None else v for k, v in outcome.row().items()})
    counts = {status: sum(o.status == status for o in outcomes) for status in ("ok", "failed", "not run")}
    summary = {
        "folder": str(folder),
        "shard": None if shard is None else f"{shard[0]}/{shard[1]}",
        "interrupted": interrupted,
        "resumed": resumed,
        "counts": {
            "pairs": len(outcomes),
            "ok": counts["ok"],
            "failed": counts["failed"],
            "not_run": counts["not run"],
        },
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
    rotate: int = 0,
    resume: bool = False,
    overwrite: bool = False,
    stop: Stop | None = None,
) -> BatchSummary:
    """Calibrate every pair of ``folder`` into ``out_dir/<name>/``, write the summaries (and ``rig/``).

    Args:
        formats: output formats of each pair (and of the joint calibration).
        workers: processes; each has its own network session with ``threads // workers`` threads.
        progress: a Rich progress bar on stderr (else one plain line per pair there).
        pinhole: the images have no lens distortion (rectified or undistorted): none is fitted.
        lines: fit each camera's gravity to the image's vertical line segments too (docs/refine.md).
        exif: take each photo's EXIF focal length as a prior (stereogeo_cli/io/exif.py).
        rotate: degrees (0, 90, 180 or 270) to turn both images of every pair clockwise before they are read
            (``Calibrator.calibrate``); the results are for the images as they are.
        resume: take each pair whose folder holds a complete calibration made with the same options, model
            and images (stereogeo_cli/batch/resume.py) from it, and calibrate the others.
        overwrite: replace what ``out_dir`` holds. Without ``resume`` or ``overwrite``, an ``out_dir`` that
            already holds results of these pairs (their folders, the summaries, ``rig/``) is refused; with
            either, the temporary files of the atomic writes that a run killed mid-write left there go first
            (:func:`stereogeo_cli.batch.resume.remove_leftovers`).
        stop: the :class:`~stereogeo_cli.batch.interrupt.Stop` of an active ``interruptible()`` block: once
            a signal comes, no pair is started, the pairs in flight are finished (at a second signal: the
            workers are stopped at once), the summaries are written with the other pairs "not run", and the
            summary is returned with ``interrupted`` set. Without it a ``KeyboardInterrupt`` is raised again
            once the summaries are written.
    Raises:
        StereoGeoError: no pairs (exit code 2), results already in ``out_dir``, or a model that cannot be
        loaded. A pair that fails does not raise: its outcome is "failed". A failed joint calibration is
        returned in ``rig_error``.
    """
    from stereogeo_cli.batch import resume as resuming

    folder, out_dir = Path(folder), Path(out_dir)
    if resume and overwrite:
        raise StereoGeoError("--resume keeps the results in the output folder and --overwrite replaces them: "
                             "choose one")  # fmt: skip
    entries = select_shard(discover_pairs(folder), shard)
    if same_rig and any(e.name == RIG_FOLDER for e in entries):
        raise StereoGeoError(f"--same-rig writes {out_dir / RIG_FOLDER}/, but a pair is named {RIG_FOLDER!r}")
    pairs = [e for e in entries if e.problem is None]
    if not (resume or overwrite):
        found = resuming.existing_results(
            out_dir, [e.name for e in pairs], summary_stem(shard), RIG_FOLDER if same_rig else None
        )
        if found:
            folders = sum(p.is_dir() for p in found)
            what = ", ".join(
                [plural(folders, "folder")] * (folders > 0) + [p.name for p in found if not p.is_dir()]
            )
            raise StereoGeoError(
                f"{out_dir} already holds results ({what}): add --resume to keep them and calibrate only the "
                "pairs not done, or --overwrite to replace them"
            )
    if resume or overwrite:  # what a run killed mid-write left behind goes first
        resuming.remove_leftovers(
            out_dir, [e.name for e in pairs], summary_stem(shard), RIG_FOLDER if same_rig else None
        )
    calibrator_cache: list = []

    def calibrator():  # the in-process session, made once (and only when needed)
        if not calibrator_cache:
            from stereogeo_cli.pipeline import Calibrator

            calibrator_cache.append(Calibrator(model, threads=threads, conf=calibrator_conf(pinhole, lines)))
        return calibrator_cache[0]

    job = PairJob(
        out_dir, formats, baseline_m, model, threads, keep_evidence=same_rig, pinhole=pinhole, lines=lines,
        exif=exif, rotate=rotate,
    )  # fmt: skip
    outcomes_by_name: dict[str, PairOutcome] = {}
    done: list[PairOutcome | None] = [None] * len(pairs)
    summary = BatchSummary([])
    interrupted: BaseException | None = None
    with _Progress(progress) as bar:
        for e in entries:
            if e.problem is not None:
                bar.line(f"unmatched: {e.problem}")
                outcomes_by_name[e.name] = PairOutcome(e.name, e.left, e.right, "failed", e.problem)
        try:
            if resume:
                options = resuming.pair_options(
                    resuming.model_identity(model), baseline_m, pinhole, lines, exif, rotate
                )
                for i, e in enumerate(pairs):
                    if stop is not None and stop.requested:
                        break
                    kept = resuming.completed_pair(
                        out_dir / e.name, (e.left, e.right), options, formats, same_rig
                    )
                    if kept is not None:
                        report, time_ms, evidence = kept
                        done[i] = PairOutcome(e.name, e.left, e.right, "ok", "", report, time_ms, evidence)
                summary.resumed = sum(o is not None for o in done)
                bar.line(f"resuming: {summary.resumed} of {plural(len(pairs), 'pair')} taken from {out_dir}")
            todo = [i for i, o in enumerate(done) if o is None]
            if workers <= 1 and todo and not (stop is not None and stop.requested):
                calibrator()  # a bad model fails here, before any pair
            bar.stage("calibrating", len(todo))
            computed: list[PairOutcome | None] = [None] * len(todo)
            try:
                _run_pass([pairs[i] for i in todo], job, workers, calibrator, bar, stop, computed)
            finally:
                for i, outcome in zip(todo, computed, strict=True):
                    done[i] = outcome
            if same_rig and all(o is not None for o in done):
                try:
                    from stereogeo_cli.batch.same_rig import same_rig_calibration

                    summary.rig = same_rig_calibration(done, job, workers, calibrator, bar, baseline_m, stop)
                except StereoGeoError as error:
                    summary.rig_error = error
        except KeyboardInterrupt as error:  # a second signal (Interrupted), or Ctrl-C without ``stop``
            interrupted = error
        for e, outcome in zip(pairs, done, strict=True):
            outcomes_by_name[e.name] = outcome or PairOutcome(e.name, e.left, e.right, "not run")
        summary.outcomes = [outcomes_by_name[e.name] for e in entries]
    from stereogeo_cli.io import write_calibration
    from stereogeo_cli.io.atomic import write_files_atomically

    stopped = interrupted is not None or (
        stop is not None and stop.requested and (summary.not_run > 0 or (same_rig and summary.rig is None))
    )
    if stopped:
        summary.interrupted = (stop.name if stop is not None else None) or "SIGINT"
    try:
        with protected():  # a signal now waits until the rig and the summaries are written
            rig_entry = None
            if summary.rig is not None:
                summary.written += write_calibration(out_dir / RIG_FOLDER, summary.rig, formats)
                rig_entry = {"folder": RIG_FOLDER, "report": _json_safe(summary.rig.to_report())}
            elif summary.rig_error is not None:
                rig_entry = {"folder": None, "error": str(summary.rig_error)}
            elif same_rig and stopped:
                rig_entry = {"folder": None, "error": f"not run: interrupted by {summary.interrupted}"}
            files = summary_files(
                summary.outcomes, folder, shard, rig_entry, summary.interrupted, summary.resumed
            )
            summary.json_text = files[next(k for k in files if k.endswith(".json"))]
            summary.written += write_files_atomically(out_dir, files)
    except KeyboardInterrupt as error:  # everything is written: nothing more to stop
        if stop is None:
            raise
        interrupted = interrupted or error
    if interrupted is not None and stop is None:
        raise interrupted
    return summary
