"""``stereogeo evaluate`` on single photographs with known intrinsics: a folder with a ``labels.jsonl``.

Layout: ``labels.jsonl``, one JSON object per image: ``file`` (its path from the folder), ``width``,
``height``, ``K`` (3×3, pixels), ``gravity_up`` (the up direction in the camera frame, or null), ``camera``
(the camera's model, optional), ``set`` (e.g. ``photo`` or ``car``, optional). The first folder of ``file``
is the image's *source*.

Each photograph is calibrated as the stereo pair (photo, photo less its 8 leftmost columns), given as arrays
so that no EXIF focal length is read: what is measured is the network, the refiner, the straight edges
and the fusion, not the EXIF. The photo is the pair's left camera and is scored as
:func:`stereogeo_cli.evaluate.camera_errors` scores a pair's camera (``photo_`` keys); beside it the naive
guess f = 0.7 · max(w, h), with a level camera (roll = pitch = 0), is scored the same way (``naive_`` keys).

**Weighting**: every camera counts once. A camera is a source with one camera model (all its images), or
in a source of several models one model of it; an image weighs 1 / (images of its camera). Medians and
means are weighted (:func:`stereogeo_cli.evaluate.weighted_quantile`: the value at half the total weight)
over the calibrated images; AUC@t (t = 1°, 5°, 10°) is (1/t) ∫₀ᵗ recall(e) de with recall(e) the weight of
the images whose vFoV error is ≤ e over the weight of all images (a failed calibration is never recalled),
held flat below 1° at recall(1°) as GeoCalib's evaluation does (so AUC@1° is the share within 1°); the
shares within 1 and 3 reported sigmas are weighted shares.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections import Counter, defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from stereogeo_cli.errors import CalibrationFailed, StereoGeoError
from stereogeo_cli.evaluate import camera_errors, sigma_coverage, weighted_quantile
from stereogeo_cli.geometry import vfov_from_focal
from stereogeo_cli.io import load_image
from stereogeo_cli.metrics import auc

LABELS = "labels.jsonl"
SHIFT_COLUMNS = 8  # the pair's right image: the photo less this many leftmost columns
NAIVE_FOCAL_SHARE = 0.7  # the naive guess: f = 0.7 · max(w, h)
THRESHOLDS = (1.0, 5.0, 10.0)  # AUC@ degrees
MIN_ERROR = 1.0  # the recall curve is held flat below 1° (GeoCalib's evaluation; evaluate._summaries too)
# the split of the project's real photographs into a training and a measurement half (a checkout's file)
DEFAULT_SPLIT_FILE = Path(__file__).resolve().parents[1] / "benchmarks" / "real_photos_split.json"
HALVES = ("train", "measure")


def is_photo_set(folder: str | Path) -> bool:
    """Whether ``folder`` holds single photographs (a ``labels.jsonl``, no ``calib.jsonl`` of pairs)."""
    folder = Path(folder)
    return (folder / LABELS).is_file() and not (folder / "calib.jsonl").is_file()


def read_labels(folder: str | Path) -> list[dict]:
    """The records of ``labels.jsonl``, each with its ``camera_id`` and ``source`` added."""
    path = Path(folder) / LABELS
    records = []
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            raise StereoGeoError(f"{path}:{number} is not valid JSON") from None
        missing = [key for key in ("file", "width", "height", "K") if record.get(key) is None]
        if missing:
            raise StereoGeoError(f"{path}:{number} has no {', '.join(missing)}")
        records.append(record)
    if not records:
        raise StereoGeoError(f"{path} lists no images")
    ids = camera_ids(records)
    return [{**r, "source": source_of(r), "camera_id": i} for r, i in zip(records, ids, strict=True)]


def source_of(record: dict) -> str:
    """An image's source: the first folder of its ``file`` (``.`` for a file at the top)."""
    parts = Path(record["file"]).parts
    return parts[0] if len(parts) > 1 else "."


def camera_ids(records: list[dict]) -> list[str]:
    """Each image's camera: its source where all the source's images name one camera model (or none), else
    ``source/model``."""
    models = defaultdict(set)
    for record in records:
        models[source_of(record)].add((record.get("camera") or "").strip())
    ids = []
    for record in records:
        source = source_of(record)
        model = (record.get("camera") or "").strip()
        ids.append(source if len(models[source]) == 1 else f"{source}/{model}")
    return ids


def select(records: list[dict], split: str | None, split_file: str | Path | None = None) -> list[dict]:
    """The records of one half of a split (``split`` ``train`` or ``measure``: the cameras ``split_file``
    lists under that name), or of a file listing image paths (``file``), one a line; None: all."""
    if split is None:
        return records
    if split in HALVES:
        path = Path(split_file) if split_file is not None else DEFAULT_SPLIT_FILE
        if not path.is_file():
            raise StereoGeoError(f"split file {path} is missing; give one with --split-file")
        try:
            halves = json.loads(path.read_text())
            chosen = set(halves[split])
            listed = chosen | set(halves[HALVES[split == "train"]])
        except (json.JSONDecodeError, KeyError, TypeError):
            raise StereoGeoError(f"{path} is not a split file (lists 'train' and 'measure')") from None
        unlisted = sorted({r["camera_id"] for r in records} - listed)
        if unlisted:
            raise StereoGeoError(
                f"{path} does not place camera(s) {', '.join(unlisted[:3])}: it was made for other labels"
            )
        return [r for r in records if r["camera_id"] in chosen]
    path = Path(split)
    if not path.is_file():
        raise StereoGeoError(f"--split takes 'train', 'measure' or a file of image paths; {path} is none")
    wanted = [line.strip() for line in path.read_text().splitlines()]
    wanted = [w for w in wanted if w and not w.startswith("#")]
    known = {r["file"] for r in records}
    unknown = [w for w in wanted if w not in known]
    if unknown:
        raise StereoGeoError(f"{path} lists image(s) not in the labels: {', '.join(unknown[:3])}")
    wanted_set = set(wanted)
    return [r for r in records if r["file"] in wanted_set]


def make_split(records: list[dict]) -> dict[str, list[str]]:
    """A split of the cameras into ``train`` and ``measure`` halves, from the labels alone (no model).

    Every camera lies wholly in one half. A camera with any image marked ``train_ok: false`` is measured.
    The others, in the order of the SHA-256 of their ids, go each to the half holding fewer cameras of their
    source so far (ties: the half with fewer images; then ``train``), so each source of many cameras is
    halved; a camera whose model (``camera``, case and spacing aside) a placed camera of another source
    shares follows that camera, so no camera model is on both sides."""
    cameras: dict[str, dict] = {}
    for record in records:
        camera = cameras.setdefault(
            record["camera_id"],
            {"source": record["source"], "images": 0, "measure_only": False, "model": _model(record)},
        )
        camera["images"] += 1
        camera["measure_only"] |= record.get("train_ok") is False

    def digest(camera_id: str) -> str:
        return hashlib.sha256(camera_id.encode()).hexdigest()

    order = sorted(cameras, key=lambda c: (not cameras[c]["measure_only"], digest(c)))
    side: dict[str, str] = {}
    images = Counter()
    per_source: dict[str, Counter] = defaultdict(Counter)
    model_side: dict[str, str] = {}
    for camera_id in order:
        camera = cameras[camera_id]
        if camera["measure_only"]:
            half = "measure"
        elif camera["model"] and camera["model"] in model_side:
            half = model_side[camera["model"]]
        else:
            counts = per_source[camera["source"]]
            half = min(HALVES, key=lambda h: (counts[h], images[h], HALVES.index(h)))
        side[camera_id] = half
        images[half] += camera["images"]
        per_source[camera["source"]][half] += 1
        if camera["model"]:
            model_side.setdefault(camera["model"], half)
    return {half: sorted(c for c in cameras if side[c] == half) for half in HALVES}


def _model(record: dict) -> str:
    return " ".join((record.get("camera") or "").lower().split())


class _Guess(NamedTuple):
    """The naive guess as a fit :func:`camera_errors` can score: f = 0.7 · max(w, h), a level camera."""

    focal_px: float
    vfov_deg: float
    roll_deg: float = 0.0
    pitch_deg: float = 0.0


_NO_SIGMA = {"vfov_deg": math.inf, "roll_deg": math.inf, "pitch_deg": math.inf}


def naive_errors(record: dict) -> dict:
    """The naive guess's errors (``naive_`` keys), scored as the network's are."""
    focal = NAIVE_FOCAL_SHARE * max(record["width"], record["height"])
    guess = _Guess(focal, math.degrees(float(vfov_from_focal(focal, record["height"]))))
    row = camera_errors(guess, record, "naive", _NO_SIGMA)
    return {k: v for k, v in row.items() if v is not None}


def photo_pair(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The stereo pair a single photograph is calibrated as: (photo, photo less its 8 leftmost columns)."""
    return image, np.ascontiguousarray(image[:, SHIFT_COLUMNS:])


def soften(image: np.ndarray, factor: float = 2.0, upsample: int | None = None) -> np.ndarray:
    """The image resized down by ``factor`` (area filter) and back up to its own size (``upsample``,
    default linear): the same view and geometry, less sharp. Sharpness must not tell the lens: the
    sharpness benchmark reads photographs both ways, and ``make-data --photos`` trains on both."""
    height, width = image.shape[:2]
    small = cv2.resize(
        image, (max(1, int(width / factor)), max(1, int(height / factor))), interpolation=cv2.INTER_AREA
    )
    return cv2.resize(
        small, (width, height), interpolation=cv2.INTER_LINEAR if upsample is None else upsample
    )


def calibrate_photo(calibrator, image: np.ndarray):
    """Calibrate one photograph [H x W x 3] uint8 as :func:`photo_pair` (arrays: no EXIF is read)."""
    return calibrator.calibrate(*photo_pair(image))


def evaluate_photos(
    folder: str | Path,
    calibrator,
    records: list[dict] | None = None,
    *,
    progress: Callable[[], None] | None = None,
    image_filter: Callable[[np.ndarray], np.ndarray] | None = None,
) -> dict:
    """Calibrate every photograph of ``folder`` (or those of ``records``, from :func:`read_labels`) with
    ``calibrator`` and score them (:func:`score_photos`). ``image_filter``: applied to each image first.

    Returns ``{"dataset", "layout": "photos", "weighting", "photos": [per-image rows], "failed": [...],
    "photo_metrics": {"all", "sets", "sources"}, "skipped"}``."""
    folder = Path(folder)
    records = read_labels(folder) if records is None else records
    rows, failed = [], []
    for record in records:
        row = {
            "id": record["file"],
            "camera": record["camera_id"],
            "source": record["source"],
            "set": record.get("set") or "",
            **naive_errors(record),
        }
        try:
            image = load_image(folder / record["file"])
            if image.shape[:2] != (record["height"], record["width"]):
                raise StereoGeoError(
                    f"the image is {image.shape[1]}x{image.shape[0]}, its labels say "
                    f"{record['width']}x{record['height']}"
                )
            if image_filter is not None:
                image = image_filter(image)
            result = calibrate_photo(calibrator, image)
        except (StereoGeoError, CalibrationFailed) as error:
            row["error"] = str(error)
            failed.append({"id": record["file"], "error": str(error)})
        else:
            row.update(camera_errors(result.left, record, "photo", result.calibration.sigma_left))
            row["photo_vfov_deg"] = result.left.vfov_deg
        rows.append(row)
        if progress:
            progress()
    skipped = []
    if not any("naive_roll_error_deg" in row for row in rows):
        skipped.append("roll, pitch: no gravity in these labels")
    return {
        "dataset": str(folder),
        "layout": "photos",
        "weighting": "each camera counts once: an image weighs 1 / (images of its camera)",
        "photos": rows,
        "failed": failed,
        "photo_metrics": score_photos(rows),
        "skipped": skipped,
    }


def score_photos(rows: list[dict]) -> dict:
    """The summaries of per-image rows (``camera``, ``source``, ``set``, ``photo_*`` and ``naive_*``
    errors; a row with ``error`` failed): of all images, of each set and of each source."""
    groups = {"sets": defaultdict(list), "sources": defaultdict(list)}
    for row in rows:
        groups["sets"][row.get("set") or ""].append(row)
        groups["sources"][row["source"]].append(row)
    return {
        "all": summarize_group(rows),
        **{name: {k: summarize_group(v) for k, v in sorted(g.items())} for name, g in groups.items()},
    }


def summarize_group(rows: list[dict]) -> dict:
    """One group's summary, every camera counting once (weights :func:`camera_weights`): for stereogeo and
    the naive guess (``naive_`` keys) the vFoV error (weighted median, mean, AUC@1/5/10°), its signed bias,
    the relative focal error and, where gravity is known, roll and pitch; for stereogeo the weighted shares
    of errors within the reported 1 and 3 sigma (``*_sigma``)."""
    weights = camera_weights(rows)
    out: dict = {
        "images": len(rows),
        "cameras": len({r["camera"] for r in rows}),
        "failed": sum("error" in r for r in rows),
    }
    for name in ("vfov", "roll", "pitch"):
        known = np.array([f"naive_{name}_error_deg" in r for r in rows])  # where there is ground truth
        if not known.any():
            continue
        for who, key in (("photo", f"{name}_deg"), ("naive", f"naive_{name}_deg")):
            # a failed calibration: never recalled in the AUCs
            errors = [
                r.get(f"{who}_{name}_error_deg", math.inf) for r, k in zip(rows, known, strict=True) if k
            ]
            out[key] = weighted_summary(np.array(errors), weights[known], min_error=MIN_ERROR)
        z, w = _column(rows, weights, f"photo_{name}_z")
        if z.size:
            out[f"{name}_sigma"] = sigma_coverage(z, w)
    for key, name in (("vfov_bias_deg", "vfov_bias_deg"), ("focal_error_rel", "focal_rel")):
        for who, label in (("photo", name), ("naive", f"naive_{name}")):
            values, w = _column(rows, weights, f"{who}_{key}")
            if values.size:
                mean = float(np.average(values, weights=w))
                out[label] = {"median": weighted_quantile(values, w, 0.5), "mean": mean}
    return out


def _column(rows: list[dict], weights: np.ndarray, key: str) -> tuple[np.ndarray, np.ndarray]:
    """The values of ``key`` in the rows that have one (not None), and those rows' weights."""
    have = np.array([r.get(key) is not None for r in rows], dtype=bool)
    return np.array([r[key] for r in rows if r.get(key) is not None], dtype=float), weights[have]


def camera_weights(rows: list[dict]) -> np.ndarray:
    """Each row's weight 1 / (rows of its ``camera``): every camera weighs one in all."""
    count = Counter(r["camera"] for r in rows)
    return np.array([1.0 / count[r["camera"]] for r in rows])


def weighted_auc(
    errors: np.ndarray, weights: np.ndarray, thresholds=THRESHOLDS, min_error: float | None = None
) -> list[float]:
    """:func:`stereogeo_cli.metrics.auc` with weights: the recall at error e is the weight of the errors
    ≤ e over the total weight (non-finite errors count in the total and are never recalled)."""
    return auc(errors, thresholds, min_error, weights=weights)


def weighted_summary(errors: np.ndarray, weights: np.ndarray, min_error: float | None = None) -> dict:
    """Weighted median and mean of the finite errors (None: none) and weighted AUC@1/5/10 of all
    (:func:`weighted_auc`)."""
    errors, weights = np.asarray(errors, dtype=float), np.asarray(weights, dtype=float)
    finite = np.isfinite(errors)
    out = {
        "median": weighted_quantile(errors[finite], weights[finite], 0.5),
        "mean": float(np.average(errors[finite], weights=weights[finite])) if finite.any() else None,
    }
    for t, a in zip(THRESHOLDS, weighted_auc(errors, weights, THRESHOLDS, min_error), strict=True):
        out[f"auc@{t:g}"] = a
    return out
