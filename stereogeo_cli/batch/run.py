"""Running ``batch-calibrate``: every pair of a folder calibrated (:mod:`~stereogeo_cli.batch.passes`), the
per-pair results and the summary files, ``--same-rig``'s joint calibration; on SIGINT or SIGTERM the pairs
done are kept and summarised (:mod:`~stereogeo_cli.jobs.interrupt`), and ``resume`` takes them from their
folders (:mod:`~stereogeo_cli.batch.resume`)."""

from __future__ import annotations

import csv
import io
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from stereogeo_cli.batch import resume as resuming
from stereogeo_cli.batch.passes import run_pass
from stereogeo_cli.batch.records import (
    CSV_COLUMNS,
    NUMERIC_COLUMNS,
    RIG_FOLDER,
    BatchOptions,
    PairJob,
    PairOutcome,
    json_safe,
)
from stereogeo_cli.batch.same_rig import same_rig_calibration
from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.io.pairs import discover_pairs, select_shard
from stereogeo_cli.io.text import plural
from stereogeo_cli.jobs.interrupt import Stop, protected
from stereogeo_cli.jobs.progress import PairProgress


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
    return {f"{stem}.csv": text.getvalue(), f"{stem}.json": json.dumps(json_safe(summary), indent=2) + "\n"}


def run_batch(
    folder: str | os.PathLike,
    out_dir: str | os.PathLike,
    options: BatchOptions = BatchOptions(),
    stop: Stop | None = None,
) -> BatchSummary:
    """Calibrate every pair of ``folder`` into ``out_dir/<name>/`` as ``options`` say
    (:class:`~stereogeo_cli.batch.records.BatchOptions`), write the summaries (and ``rig/``).

    Without ``options.resume`` or ``options.overwrite``, an ``out_dir`` that already holds results of these
    pairs (their folders, the summaries, ``rig/``) is refused; with either, the temporary files of the atomic
    writes that a run killed mid-write left there go first
    (:func:`stereogeo_cli.batch.resume.remove_leftovers`).

    ``stop``: the :class:`~stereogeo_cli.jobs.interrupt.Stop` of an active ``interruptible()`` block: once a
    signal comes, no pair is started, the pairs in flight are finished (at a second signal: the workers are
    stopped at once), the summaries are written with the other pairs "not run", and the summary is returned
    with ``interrupted`` set. Without it a ``KeyboardInterrupt`` is raised again once the summaries are
    written.

    Raises:
        StereoGeoError: no pairs (exit code 2), results already in ``out_dir``, or a model that cannot be
        loaded. A pair that fails does not raise: its outcome is "failed". A failed joint calibration is
        returned in ``rig_error``.
    """
    folder, out_dir = Path(folder), Path(out_dir)
    entries = _entries(folder, out_dir, options)
    pairs = [e for e in entries if e.problem is None]
    job = PairJob(out_dir, options.formats, options.pair, options.model, options.threads, options.same_rig)
    summary = BatchSummary([])
    with PairProgress(options.progress) as bar:
        unmatched = {e.name: PairOutcome(e.name, e.left, e.right, "failed", e.problem) for e in entries
                     if e.problem is not None}  # fmt: skip
        for outcome in unmatched.values():
            bar.line(f"unmatched: {outcome.error}")
        done: list[PairOutcome | None] = [None] * len(pairs)
        interrupted = _calibrate(pairs, done, job, options, bar, stop, summary)
        ran = {
            e.name: o or PairOutcome(e.name, e.left, e.right, "not run")
            for e, o in zip(pairs, done, strict=True)
        }
        summary.outcomes = [{**unmatched, **ran}[e.name] for e in entries]
    stopped = interrupted is not None or (
        stop is not None and stop.requested
        and (summary.not_run > 0 or (options.same_rig and summary.rig is None))
    )  # fmt: skip
    if stopped:
        summary.interrupted = (stop.name if stop is not None else None) or "SIGINT"
    try:
        with protected():  # a signal now waits until the rig and the summaries are written
            _write_results(folder, out_dir, options, summary, stopped)
    except KeyboardInterrupt as error:  # everything is written: nothing more to stop
        if stop is None:
            raise
        interrupted = interrupted or error
    if interrupted is not None and stop is None:
        raise interrupted
    return summary


def _entries(folder: Path, out_dir: Path, options: BatchOptions) -> list:
    """The pairs of ``folder`` (this shard's), once ``out_dir`` is known to take their results."""
    if options.resume and options.overwrite:
        raise StereoGeoError("--resume keeps the results in the output folder and --overwrite replaces them: "
                             "choose one")  # fmt: skip
    entries = select_shard(discover_pairs(folder), options.shard)
    if options.same_rig and any(e.name == RIG_FOLDER for e in entries):
        raise StereoGeoError(f"--same-rig writes {out_dir / RIG_FOLDER}/, but a pair is named {RIG_FOLDER!r}")
    names = [e.name for e in entries if e.problem is None]
    rig = RIG_FOLDER if options.same_rig else None
    if not (options.resume or options.overwrite):
        found = resuming.existing_results(out_dir, names, summary_stem(options.shard), rig)
        if found:
            folders = sum(p.is_dir() for p in found)
            what = ", ".join(
                [plural(folders, "folder")] * (folders > 0) + [p.name for p in found if not p.is_dir()]
            )
            raise StereoGeoError(
                f"{out_dir} already holds results ({what}): add --resume to keep them and calibrate only the "
                "pairs not done, or --overwrite to replace them"
            )
    else:  # what a run killed mid-write left behind goes first
        resuming.remove_leftovers(out_dir, names, summary_stem(options.shard), rig)
    return entries


def _calibrate(pairs, done, job: PairJob, options: BatchOptions, bar, stop, summary) -> BaseException | None:
    """The pairs kept from an earlier run (``--resume``), the others calibrated and the joint calibration,
    into ``done`` (the pairs' outcomes, None for a pair not run) and ``summary``. Returns the
    ``KeyboardInterrupt`` that stopped it at once (a second signal, or Ctrl-C without ``stop``), or None."""
    calibrator_cache: list = []

    def calibrator():  # the in-process session, made once (and only when needed)
        if not calibrator_cache:
            from stereogeo_cli.pipeline import Calibrator

            conf = options.pair.calibrator_conf()
            calibrator_cache.append(Calibrator(options.model, threads=options.threads, conf=conf))
        return calibrator_cache[0]

    try:
        if options.resume:
            summary.resumed = _resumed(pairs, done, job.out_dir, options, stop)
            bar.line(f"resuming: {summary.resumed} of {plural(len(pairs), 'pair')} taken from {job.out_dir}")
        todo = [i for i, o in enumerate(done) if o is None]
        if options.workers <= 1 and todo and not (stop is not None and stop.requested):
            calibrator()  # a bad model fails here, before any pair
        bar.stage("calibrating", len(todo))
        computed: list[PairOutcome | None] = [None] * len(todo)
        try:
            run_pass([pairs[i] for i in todo], job, options.workers, calibrator, bar, stop, computed)
        finally:
            for i, outcome in zip(todo, computed, strict=True):
                done[i] = outcome
        if options.same_rig and all(o is not None for o in done):
            try:
                summary.rig = same_rig_calibration(done, job, options.workers, calibrator, bar, stop)
            except StereoGeoError as error:
                summary.rig_error = error
    except KeyboardInterrupt as error:
        return error
    return None


def _resumed(pairs, done, out_dir: Path, options: BatchOptions, stop) -> int:
    """Put into ``done`` each pair whose folder holds a complete calibration made as this run would make
    it (:func:`stereogeo_cli.batch.resume.completed_pair`); returns how many."""
    recorded = resuming.pair_options(resuming.model_identity(options.model), options.pair)
    for i, e in enumerate(pairs):
        if stop is not None and stop.requested:
            break
        kept = resuming.completed_pair(out_dir / e.name, (e.left, e.right), recorded, options.formats,
                                       options.same_rig)  # fmt: skip
        if kept is not None:
            report, time_ms, evidence = kept
            done[i] = PairOutcome(e.name, e.left, e.right, "ok", "", report, time_ms, evidence)
    return sum(o is not None for o in done)


def _write_results(folder: Path, out_dir: Path, options: BatchOptions, summary: BatchSummary, stopped: bool):
    """The joint calibration's folder and the summaries, into ``summary.written``."""
    from stereogeo_cli.io import write_calibration
    from stereogeo_cli.io.atomic import write_files_atomically

    rig_entry = None
    if summary.rig is not None:
        figures = None
        if "html" in options.formats:  # the joint report sets each pair's own calibration against it
            from stereogeo_cli.report.inputs import ReportInputs

            pairs = [(o.name, o.report) for o in summary.outcomes if o.status == "ok" and o.report]
            figures = ReportInputs(pairs=pairs)
        summary.written += write_calibration(
            out_dir / RIG_FOLDER, summary.rig, options.formats, figures=figures
        )
        rig_entry = {"folder": RIG_FOLDER, "report": json_safe(summary.rig.to_report())}
    elif summary.rig_error is not None:
        rig_entry = {"folder": None, "error": str(summary.rig_error)}
    elif options.same_rig and stopped:
        rig_entry = {"folder": None, "error": f"not run: interrupted by {summary.interrupted}"}
    files = summary_files(
        summary.outcomes, folder, options.shard, rig_entry, summary.interrupted, summary.resumed
    )
    summary.json_text = files[next(k for k in files if k.endswith(".json"))]
    summary.written += write_files_atomically(out_dir, files)
