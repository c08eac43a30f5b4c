"""Writing a dataset in the project layout (left/, right/, calib.jsonl), in parallel and resumable.

Every file is written under a temporary name in its own folder and renamed into place; a calib.jsonl
line is appended only after both images (and depth maps) of its pair exist. Resuming skips the ids
already in calib.jsonl and drops a trailing partial line, so an interrupted run never leaves a broken
file and, for the same seed, ends with the same bytes as an uninterrupted one.
"""

from __future__ import annotations

import json
import multiprocessing
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.synth.config import SynthConfig
from stereogeo_cli.synth.sample import StereoSample, sample_id, sample_pair

SETTINGS_FILE = "make-data.json"
_TMP_PREFIX = ".tmp-"


@dataclass(frozen=True)
class WriteSummary:
    folder: Path
    written: int  # pairs rendered by this run
    skipped: int  # pairs already present (resumed)
    total: int


def _atomic_write(path: Path, data: bytes) -> None:
    tmp = path.with_name(f"{_TMP_PREFIX}{os.getpid()}-{path.name}")
    with open(tmp, "wb") as f:
        f.write(data)
    os.replace(tmp, path)


def _png(image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", cv2.cvtColor(image, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:  # pragma: no cover - OpenCV failure
        raise StereoGeoError("PNG encoding failed")
    return buf.tobytes()


def _npy(array: np.ndarray) -> bytes:
    import io

    buffer = io.BytesIO()
    np.save(buffer, np.ascontiguousarray(array, dtype=np.float32))
    return buffer.getvalue()


def write_sample(folder: Path, sample: StereoSample) -> str:
    """Write one pair's files atomically and return its calib.jsonl line (without the newline)."""
    pid = sample.id
    _atomic_write(folder / "left" / f"{pid}.png", _png(sample.left))
    _atomic_write(folder / "right" / f"{pid}.png", _png(sample.right))
    if sample.depth_left is not None:
        _atomic_write(folder / "depth" / "left" / f"{pid}.npy", _npy(sample.depth_left))
        _atomic_write(folder / "depth" / "right" / f"{pid}.npy", _npy(sample.depth_right))
    return json.dumps(sample.calib, separators=(", ", ": "))


# a make-data.json without one of these settings belongs to a folder rendered as these values render it
# (no desks; crops ≤ 1.5× magnified), so a resume compares it with them filled in
_ADDED_SETTINGS = {"close_share": 0.0, "panorama_max_upsampling": 1.5}


def _settings(seed: int, config: SynthConfig) -> dict:
    d = asdict(config)
    d = {k: (str(v) if isinstance(v, Path) else list(v) if isinstance(v, tuple) else v) for k, v in d.items()}
    return {"seed": seed, "config": d}


def read_done_ids(calib_path: Path) -> set[str]:
    """Ids of the complete lines of calib.jsonl; a trailing partial line is cut off the file."""
    if not calib_path.exists():
        return set()
    data = calib_path.read_bytes()
    end = data.rfind(b"\n") + 1
    if end != len(data):
        with open(calib_path, "r+b") as f:
            f.truncate(end)
    done = set()
    for number, line in enumerate(data[:end].splitlines(), 1):
        try:
            done.add(json.loads(line)["id"])
        except (ValueError, KeyError) as error:
            raise StereoGeoError(
                f"{calib_path} line {number} is not a calib.jsonl record: {error}"
            ) from error
    return done


def _prepare(folder: Path, seed: int, config: SynthConfig) -> None:
    try:
        for sub in ["left", "right"] + (["depth/left", "depth/right"] if config.depth else []):
            (folder / sub).mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise StereoGeoError(f"cannot create the output folder {folder}: {error.strerror}") from error
    for sub in ["", "left", "right", "depth/left", "depth/right"]:
        if (folder / sub).is_dir():
            for stale in (folder / sub).glob(f"{_TMP_PREFIX}*"):
                stale.unlink(missing_ok=True)
    settings_path = folder / SETTINGS_FILE
    settings = _settings(seed, config)
    if settings_path.exists():
        previous = json.loads(settings_path.read_text())
        # a setting the file lacks takes the value that renders what the folder holds (_ADDED_SETTINGS)
        for key, value in _ADDED_SETTINGS.items():
            previous.get("config", {}).setdefault(key, value)
        if previous != settings:
            raise StereoGeoError(
                f"{folder} holds a dataset made with other settings ({settings_path}); "
                "resume with the same options or use another folder"
            )
    else:
        _atomic_write(settings_path, (json.dumps(settings, indent=2) + "\n").encode())


_WORKER: dict = {}


def _init_worker(folder: Path, seed: int, config: SynthConfig, single_thread: bool) -> None:
    if single_thread:  # two processes on two cores: one rasteriser thread each
        os.environ.setdefault("LP_NUM_THREADS", "1")
        cv2.setNumThreads(1)
    _WORKER.update(folder=folder, seed=seed, config=config)


def _render_and_write(index: int) -> str:
    sample = sample_pair(_WORKER["seed"], index, _WORKER["config"])
    return write_sample(_WORKER["folder"], sample)


def make_dataset(
    folder: Path,
    count: int,
    seed: int = 0,
    config: SynthConfig | None = None,
    workers: int = 1,
    progress: bool = True,
) -> WriteSummary:
    """Render pairs 0 … count-1 of ``seed`` into ``folder`` (resuming what is already there)."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    config = config or SynthConfig()
    if count < 0:
        raise StereoGeoError("--count must be ≥ 0")
    folder = Path(folder)
    _prepare(folder, seed, config)
    calib_path = folder / "calib.jsonl"
    done = read_done_ids(calib_path)
    todo = [i for i in range(count) if sample_id(i) not in done]
    skipped = count - len(todo)
    columns = (TextColumn("rendering"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
    with Progress(*columns, disable=not progress, transient=False) as bar, open(calib_path, "a") as out:
        task = bar.add_task("render", total=count, completed=skipped)
        if workers <= 1 or len(todo) <= 1:
            _init_worker(folder, seed, config, single_thread=False)
            lines = map(_render_and_write, todo)
            _consume(lines, out, bar, task)
        else:
            ctx = multiprocessing.get_context("spawn")
            with ctx.Pool(workers, _init_worker, (folder, seed, config, True)) as pool:
                _consume(pool.imap(_render_and_write, todo, chunksize=1), out, bar, task)
    return WriteSummary(folder, len(todo), skipped, count)


def _consume(lines, out, bar, task) -> None:
    for line in lines:
        out.write(line + "\n")
        out.flush()
        bar.advance(task)
