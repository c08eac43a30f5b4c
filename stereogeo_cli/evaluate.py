"""``stereogeo evaluate``: the calibrate pipeline on a dataset with ground truth, and the paper's metrics.

Dataset layout (what ``make-data`` writes): ``left/<id>.png``, ``right/<id>.png``, ``calib.jsonl``.
Per camera: roll, pitch and vFoV errors (degrees) and the relative focal error; per pair: the relative
rotation error (degrees), the translation error (metres) and the translation-direction error (degrees).
A metric whose ground truth is missing (e.g. no gravity) is skipped and said so. Optional baselines use
the ground-truth intrinsics: ORB (5000 features) or SIFT matches, essential matrix and recoverPose.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from stereogeo_cli.errors import CalibrationFailed, StereoGeoError
from stereogeo_cli.fuse import Matches, essential_pose, match_features
from stereogeo_cli.geometry import gravity_angle, roll_pitch_from_gravity, rotation_error, vfov_from_focal
from stereogeo_cli.io import load_image
from stereogeo_cli.metrics import summarize


def read_dataset(folder: str | Path) -> list[dict]:
    """The records of ``calib.jsonl`` (one per pair); a folder that is not a dataset is a StereoGeoError."""
    folder = Path(folder)
    path = folder / "calib.jsonl"
    if not path.is_file():
        raise StereoGeoError(f"{folder} is not a dataset folder: {path} is missing")
    records = []
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if line.strip():
            try:
                records.append(json.loads(line))
            except json.JSONDecodeError:
                raise StereoGeoError(f"{path}:{number} is not valid JSON") from None
    if not records:
        raise StereoGeoError(f"{path} lists no pairs")
    return records


def _direction_error_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(float(gravity_angle(a, b)))  # the angle between two direction vectors


def orb_matches(left: np.ndarray, right: np.ndarray, features: int = 5000) -> Matches:
    """ORB matches (Hamming, cross-checked), the paper's baseline."""
    orb = cv2.ORB_create(nfeatures=features)
    kl, dl = orb.detectAndCompute(cv2.cvtColor(left, cv2.COLOR_RGB2GRAY), None)
    kr, dr = orb.detectAndCompute(cv2.cvtColor(right, cv2.COLOR_RGB2GRAY), None)
    if dl is None or dr is None:
        return Matches(np.zeros((0, 2)), np.zeros((0, 2)))
    pairs = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(dl, dr)
    return Matches(
        np.array([kl[m.queryIdx].pt for m in pairs]).reshape(-1, 2),
        np.array([kr[m.trainIdx].pt for m in pairs]).reshape(-1, 2),
    )


def undistort_with_lens(points: np.ndarray, cam: dict) -> np.ndarray:
    """Pixel points [N x 2] of a camera with OpenCV distortion ``dist`` → undistorted pixels (same K)."""
    if not cam.get("dist") or len(points) == 0:
        return points
    K, D = np.asarray(cam["K"], dtype=float), np.asarray(cam["dist"], dtype=float)
    return cv2.undistortPoints(points.reshape(-1, 1, 2), K, D, P=K).reshape(-1, 2)


def _baseline_pose(left, right, record, matcher: Callable) -> tuple[float, float | None] | None:
    """(rotation error, direction error) in degrees of matches + essential matrix with the GT intrinsics."""
    m = matcher(left, right)
    if len(m) == 0:
        return None
    lk, rk = record["left"], record["right"]
    undistorted = Matches(undistort_with_lens(m.left, lk), undistort_with_lens(m.right, rk))
    K_left, K_right = np.asarray(lk["K"], dtype=float), np.asarray(rk["K"], dtype=float)
    # OpenCV's own pipeline (MAGSAC, recoverPose), as a user would run it
    pose = essential_pose(undistorted, K_left, K_right, {"essential_second_opinion": False})
    if pose is None:
        return None
    R, t, _ = pose
    T = np.asarray(record["T"], dtype=float)
    direction = (
        _direction_error_deg(t, T) if np.linalg.norm(T) > 1e-9 else None
    )  # pure rotation: no direction
    return math.degrees(rotation_error(R, np.asarray(record["R"]))), direction


BASELINES = {
    "orb+essential": orb_matches,
    "sift+essential": lambda left, right: match_features(left, right),
}


def camera_errors(fit, cam: dict, view: str, sigma: dict | None = None) -> dict:
    """One camera's errors against its ground truth (a ``calib.jsonl`` camera), keys prefixed by ``view``:
    vFoV error and signed bias (> 0 reads the lens too wide), relative focal error, and roll and pitch
    errors where gravity is known, each with its error/sigma ratio (``_z``; ``sigma``: the reported sigmas,
    by default the fit's own)."""
    row: dict = {}
    sigma = fit.sigma if sigma is None else sigma
    K = np.asarray(cam["K"], dtype=float)
    vfov = math.degrees(float(vfov_from_focal(K[1, 1], cam["height"])))
    row[f"{view}_vfov_error_deg"] = abs(fit.vfov_deg - vfov)
    row[f"{view}_vfov_bias_deg"] = fit.vfov_deg - vfov
    row[f"{view}_vfov_z"] = _z(row[f"{view}_vfov_error_deg"], sigma["vfov_deg"])
    row[f"{view}_focal_error_rel"] = abs(fit.focal_px / (0.5 * (K[0, 0] + K[1, 1])) - 1)
    if cam.get("gravity_up") is not None:
        roll, pitch = (math.degrees(float(a)) for a in roll_pitch_from_gravity(np.asarray(cam["gravity_up"])))
        row[f"{view}_roll_error_deg"] = abs((fit.roll_deg - roll + 180) % 360 - 180)
        row[f"{view}_pitch_error_deg"] = abs(fit.pitch_deg - pitch)
        row[f"{view}_roll_z"] = _z(row[f"{view}_roll_error_deg"], sigma["roll_deg"])
        row[f"{view}_pitch_z"] = _z(row[f"{view}_pitch_error_deg"], sigma["pitch_deg"])
    return row


def pair_errors(result, record: dict) -> dict:
    """The errors of one calibrated pair (a ``CalibrationResult``) against its ``calib.jsonl`` record: each
    camera's (:func:`camera_errors`) and, where the record has a pose, the rotation's, the translation's
    and its direction's and length's, each with its error/sigma ratio (``_z``)."""
    row: dict = {}
    c = result.calibration
    for view, fit, sigma in (("left", result.left, c.sigma_left), ("right", result.right, c.sigma_right)):
        row.update(camera_errors(fit, record[view], view, sigma))
    if record.get("R") is None:
        return row
    row["rotation_error_deg"] = math.degrees(rotation_error(c.R, np.asarray(record["R"])))
    T = np.asarray(record["T"], dtype=float)
    if np.linalg.norm(T) > 1e-9:
        row["translation_error_m"] = float(np.linalg.norm(c.T - T))
        # the baseline's length: the metric scale, which only the pose head (or --baseline) gives
        row["baseline_error_rel"] = abs(float(np.linalg.norm(c.T) / np.linalg.norm(T)) - 1.0)
        row["direction_error_deg"] = _direction_error_deg(c.T, T)
    row["pose_source"] = result.pose.source
    # the pose's errors in units of the 1-sigmas its report gives (the fusion's, or the pose head's; R's with
    # the focal lengths' uncertainty taken in: fuse.assemble.rotation_sigma_deg)
    reported = result.calibration.extra_report.get("pose", {})
    row["rotation_z"] = _z(row["rotation_error_deg"], reported.get("sigma_rotation_deg") or math.inf)
    if row.get("direction_error_deg") is not None:
        row["direction_z"] = _z(row["direction_error_deg"], reported.get("sigma_direction_deg") or math.inf)
        scale_sigma = reported.get("sigma_baseline_rel")
        if scale_sigma is not None:
            row["baseline_z"] = _z(row["baseline_error_rel"], scale_sigma)
    return row


def sigma_coverage(z: np.ndarray, weights: np.ndarray | None = None) -> dict[str, float]:
    """How honest reported sigmas are, from the errors in sigmas ``z``: honest ones hold 68 % of the errors
    within 1 sigma and 99.7 % within 3; the 68th percentile of ``z`` is the factor that would make them so.
    With ``weights``, weighted shares and a weighted percentile (:func:`weighted_quantile`)."""
    if weights is None:
        return {
            "within_1_sigma": float(np.mean(z <= 1)),
            "within_3_sigma": float(np.mean(z <= 3)),
            "scale_for_68": float(np.percentile(z, 68.27)),
        }
    return {
        "within_1_sigma": float(np.average(z <= 1, weights=weights)),
        "within_3_sigma": float(np.average(z <= 3, weights=weights)),
        "scale_for_68": weighted_quantile(z, weights, 0.6827),
    }


def weighted_quantile(values: np.ndarray, weights: np.ndarray, q: float) -> float | None:
    """The ``q`` quantile of ``values`` with ``weights``: the smallest value whose share of the total weight
    with all smaller ones reaches ``q``, or where it reaches ``q`` exactly, the mean of that value and the
    next (equal weights and q = 0.5: ``np.median``). None for no values."""
    values, weights = np.asarray(values, dtype=float), np.asarray(weights, dtype=float)
    if values.size == 0:
        return None
    order = np.argsort(values, kind="stable")
    v, share = values[order], np.cumsum(weights[order]) / weights.sum()
    i = min(int(np.searchsorted(share, q - 1e-12)), len(v) - 1)
    if abs(share[i] - q) < 1e-12 and i + 1 < len(v):
        return float(0.5 * (v[i] + v[i + 1]))
    return float(v[i])


def evaluate_dataset(folder: str | Path, calibrator, *, baselines: bool = False, progress=None) -> dict:
    """Run ``calibrator`` (a :class:`stereogeo_cli.pipeline.Calibrator`) on every pair of a dataset.

    Returns ``{"pairs": [...per-pair errors...], "metrics": {name: summary}, "skipped": [reasons],
    "failed": [...]}``; with ``baselines``, ``metrics`` also holds each baseline's pose errors.
    """
    folder = Path(folder)
    records = read_dataset(folder)
    per_pair, failed = [], []
    for record in records:
        name = record["id"]
        try:
            left = load_image(folder / "left" / f"{name}.png")
            right = load_image(folder / "right" / f"{name}.png")
            result = calibrator.calibrate(left, right)
        except (StereoGeoError, CalibrationFailed) as error:
            failed.append({"id": name, "error": str(error)})
            if progress:
                progress()
            continue
        row = {"id": name, **pair_errors(result, record)}
        if record.get("R") is not None and baselines:
            for label, matcher in BASELINES.items():
                errors = _baseline_pose(left, right, record, matcher)
                row[f"{label}_rotation_error_deg"] = errors[0] if errors else None
                row[f"{label}_direction_error_deg"] = errors[1] if errors else None
        per_pair.append(row)
        if progress:
            progress()
    return {
        "dataset": str(folder),
        "pairs": per_pair,
        "failed": failed,
        **_summaries(per_pair, len(records), len(failed)),
    }


def _z(error: float, sigma: float) -> float | None:
    """An error in units of its reported 1-sigma (None when the sigma is unknown or zero)."""
    return error / sigma if sigma and math.isfinite(sigma) else None


def _summaries(rows: list[dict], total: int, failed: int = 0) -> dict:
    metrics, skipped = {}, []

    def column(key):
        return [r[key] for r in rows if r.get(key) is not None]

    for name in ("roll", "pitch", "vfov"):
        values = column(f"left_{name}_error_deg") + column(f"right_{name}_error_deg")
        if values:
            # As GeoCalib's evaluation: the recall held flat below 1°, and a failed pair (both cameras)
            # counts as never recalled in the AUCs (medians and means are over the calibrated pairs).
            values += [math.inf] * (2 * failed)
            metrics[f"{name}_deg"] = summarize(np.array(values), min_error=1.0)
        else:
            skipped.append(f"{name}: no ground truth in this dataset")
        z = np.array(column(f"left_{name}_z") + column(f"right_{name}_z"))
        if z.size:
            # honest sigmas hold 68 % of the errors within 1 sigma; the 68th percentile of error/sigma is
            # the factor that would make them so
            metrics[f"{name}_sigma"] = sigma_coverage(z)
    for name in ("rotation", "direction", "baseline"):
        z = np.array(column(f"{name}_z"))
        if z.size:
            metrics[f"{name}_sigma"] = sigma_coverage(z)
    bias = column("left_vfov_bias_deg") + column("right_vfov_bias_deg")
    if bias:
        metrics["vfov_bias_deg"] = {"median": float(np.median(bias)), "mean": float(np.mean(bias))}
    focal = column("left_focal_error_rel") + column("right_focal_error_rel")
    if focal:
        metrics["focal_rel"] = {"median": float(np.median(focal)), "mean": float(np.mean(focal))}
    for key in (
        "rotation_error_deg",
        "direction_error_deg",
        "translation_error_m",
        "baseline_error_rel",
    ) + tuple(f"{b}_{k}" for b in BASELINES for k in ("rotation_error_deg", "direction_error_deg")):
        values = column(key)
        if values:
            v = np.array(values)
            metrics[key] = {"median": float(np.median(v)), "mean": float(np.mean(v)), "std": float(np.std(v)),
                            "count": len(v)}  # fmt: skip
    if not any(r.get("rotation_error_deg") is not None for r in rows):
        skipped.append("relative pose: no ground truth R, T in this dataset")
    metrics["pairs"] = {"evaluated": len(rows), "total": total}
    return {"metrics": metrics, "skipped": skipped}


_PLOT_SERIES = (
    ("roll_error_deg", "roll", (31, 119, 180)),
    ("pitch_error_deg", "pitch", (255, 127, 14)),
    ("vfov_error_deg", "vFoV", (44, 160, 44)),
    ("rotation_error_deg", "rotation R", (214, 39, 40)),
    ("sift+essential_rotation_error_deg", "SIFT+E (true K): R", (148, 103, 189)),
)


def plot_error_cdfs(results: dict, path: str | Path, max_error: float = 10.0) -> Path:
    """Draw the cumulative error curves (share of errors ≤ x, x in degrees up to ``max_error``) as a PNG."""
    from stereogeo_cli.io.atomic import write_files_atomically

    width, height, margin = 900, 540, 70
    canvas = np.full((height, width, 3), 255, np.uint8)
    x0, y0, x1, y1 = margin, height - margin, width - 30, 40

    def to_px(x: float, y: float) -> tuple[int, int]:
        return round(x0 + (x1 - x0) * x / max_error), round(y0 - (y0 - y1) * y)

    for i in range(11):
        cv2.line(canvas, to_px(i * max_error / 10, 0), to_px(i * max_error / 10, 1), (225, 225, 225), 1)
        cv2.line(canvas, to_px(0, i / 10), to_px(max_error, i / 10), (225, 225, 225), 1)
        cv2.putText(canvas, f"{i * max_error / 10:g}", (to_px(i * max_error / 10, 0)[0] - 8, y0 + 22),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)  # fmt: skip
        cv2.putText(canvas, f"{i * 10}%", (12, to_px(0, i / 10)[1] + 5), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                    (0, 0, 0), 1, cv2.LINE_AA)  # fmt: skip
    cv2.rectangle(canvas, (x0, y1), (x1, y0), (0, 0, 0), 1)
    cv2.putText(canvas, "error (degrees)", (width // 2 - 60, height - 18), cv2.FONT_HERSHEY_SIMPLEX, 0.55,
                (0, 0, 0), 1, cv2.LINE_AA)  # fmt: skip
    legend_y = y1 + 20
    for key, label, colour in _PLOT_SERIES:
        values = [
            r[k]
            for r in results["pairs"]
            for k in (f"left_{key}", f"right_{key}", key)
            if r.get(k) is not None
        ]
        if not values:
            continue
        errors = np.sort(np.asarray(values, dtype=float))
        recall = np.arange(1, len(errors) + 1) / len(errors)
        points = [to_px(0, 0)] + [
            to_px(min(e, max_error), r) for e, r in zip(errors, recall, strict=True) if e <= max_error
        ]
        if len(points) > 1:
            cv2.polylines(canvas, [np.array(points, np.int32)], False, colour[::-1], 2, cv2.LINE_AA)
        cv2.line(canvas, (x1 - 230, legend_y - 5), (x1 - 200, legend_y - 5), colour[::-1], 3)
        cv2.putText(canvas, f"{label} ({len(errors)})", (x1 - 192, legend_y), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                    (0, 0, 0), 1, cv2.LINE_AA)  # fmt: skip
        legend_y += 22
    ok, data = cv2.imencode(".png", canvas)
    if not ok:
        raise RuntimeError("PNG encoding of the plot failed")
    path = Path(path)
    write_files_atomically(path.parent, {path.name: data.tobytes()})
    return path
