"""One pass of ``batch-calibrate`` over its pairs: each pair loaded, calibrated and written (in this process,
or in worker processes with one network session each), in the pairs' order whatever the order they finish
in; on SIGINT or SIGTERM the pairs in flight are finished, at a second the workers are stopped at once
(:mod:`~stereogeo_cli.jobs.interrupt`)."""

from __future__ import annotations

import multiprocessing
import time
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, ThreadPoolExecutor, wait
from typing import Any

import numpy as np

from stereogeo_cli.batch.records import PairJob, PairOutcome, json_safe
from stereogeo_cli.batch.resume import pair_options, write_pair_files
from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.io.pairs import PairEntry
from stereogeo_cli.jobs.interrupt import (
    Interrupted,
    Stop,
    protected,
    signals_blocked,
    worker_exits_with_parent,
    worker_ignores_signals,
)
from stereogeo_cli.jobs.progress import PairProgress
from stereogeo_cli.pipeline import usable_cores
from stereogeo_cli.rig.evidence import PairEvidence


def load_entry(entry: PairEntry, job: PairJob) -> tuple[np.ndarray, np.ndarray, tuple | None]:
    """A pair's images (checked as a pair) and, if ``job.pair.exif``, what their EXIF says of the focal
    length."""
    from stereogeo_cli.io import load_pair
    from stereogeo_cli.io.exif import exif_focals

    left, right = load_pair(entry.left, entry.right)
    return left, right, exif_focals((entry.left, entry.right), (left, right)) if job.pair.exif else None


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
            left, right, baseline_m=job.pair.baseline_m, focal_left=job.pair.focal_left,
            focal_right=job.pair.focal_right, exif=exif, upcoming=upcoming, rotate=job.pair.rotate,
        )  # fmt: skip
        report = json_safe(result.report())
        evidence = PairEvidence.from_result(result) if job.keep_evidence else None
        if job.out_dir is not None:
            options = pair_options(report.get("model") or {}, job.pair)
            figures = None
            if "html" in job.formats:  # what the pair's report.html draws
                from stereogeo_cli.report.inputs import pair_inputs

                figures = pair_inputs(result, left, right)
            try:
                with protected():  # the pair's files and marker all written, even if a second Ctrl-C comes
                    outcome.time_ms = write_pair_files(
                        job.out_dir / entry.name, result.calibration, job.formats, evidence,
                        (entry.left, entry.right), options, report, start, figures,
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
    key = (job.model, job.threads, job.pair.pinhole, job.pair.lines)
    if _WORKER.get("key") != key:
        from stereogeo_cli.pipeline import Calibrator

        try:
            calibrator = Calibrator(job.model, threads=job.threads, conf=job.pair.calibrator_conf())
            _WORKER["calibrator"], _WORKER["key"] = calibrator, key
        except StereoGeoError as error:
            return PairOutcome(entry.name, entry.left, entry.right, "failed", str(error), fatal=True)
    return calibrate_pair(_WORKER["calibrator"], entry, job)


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


def run_pass(
    entries: list[PairEntry], job: PairJob, workers: int, calibrator, progress: PairProgress,
    stop: Stop | None = None, outcomes: list[PairOutcome | None] | None = None,
) -> list[PairOutcome | None]:  # fmt: skip
    """Outcomes of ``entries`` in their order, whatever the order in which they finish, put into
    ``outcomes`` (a new list if None) as they come; None for a pair not started.

    Once ``stop`` is requested (a first SIGINT or SIGTERM) no pair is started and the pairs in flight are
    finished. An exception (a second signal's :class:`~stereogeo_cli.jobs.interrupt.Interrupted`
    included) stops the workers at once: killed, with what they left half done removed.
    """
    if outcomes is None:
        outcomes = [None] * len(entries)
    if not entries:
        return outcomes

    if workers <= 1 or len(entries) <= 1:
        return _run_here(entries, job, calibrator, progress, stop, outcomes)
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
                if not (stop is not None and stop.requested):
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


def _run_here(entries, job: PairJob, calibrator, progress: PairProgress, stop, outcomes) -> list:
    """:func:`run_pass` in this process: one pair after the other, each loaded on a thread while the one
    before it is calibrated, and its image work started on the pool while that one's last stages run."""

    def stopping() -> bool:
        return stop is not None and stop.requested

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
