"""Accuracy metrics as the GeoCalib and StereoGeo papers report them."""

from __future__ import annotations

import numpy as np


def auc(
    errors: np.ndarray, thresholds=(1.0, 5.0, 10.0), min_error: float | None = None, weights=None
) -> list[float]:
    """Area under the recall curve of ``errors`` up to each threshold, normalised to [0, 1].

    The recall at error e is the share of samples with error ≤ e; non-finite errors (failures) count in
    the denominator and are never recalled. The curve starts at (0, 0) and is held flat from the largest
    error below a threshold up to the threshold. With ``min_error`` (GeoCalib's evaluation uses 1° for
    roll, pitch and vFoV) the curve is held flat at the recall of ``min_error`` from 0 to ``min_error``:
    errors below it all count as equally good, so AUC@min_error is the share of errors ≤ min_error.
    ``weights`` [N]: the recall is the weight of the errors ≤ e over the total weight (default: equal).
    """
    errors = np.asarray(errors, dtype=float).ravel()
    if errors.size == 0:
        return [float("nan")] * len(thresholds)
    weights = np.ones(errors.size) if weights is None else np.asarray(weights, dtype=float).ravel()
    order = np.argsort(np.where(np.isfinite(errors), errors, np.inf), kind="stable")
    errors = np.where(np.isfinite(errors), errors, np.inf)[order]
    recall = np.cumsum(weights[order]) / weights.sum()
    if min_error is not None:
        below = int(np.searchsorted(errors, min_error, side="right"))
        held = recall[below - 1] if below else 0.0
        errors = np.r_[0.0, min_error, errors[below:]]
        recall = np.r_[held, held, recall[below:]]
    else:
        errors = np.r_[0.0, errors]
        recall = np.r_[0.0, recall]
    out = []
    for t in thresholds:
        last = int(np.searchsorted(errors, t, side="right"))
        x = np.r_[errors[:last], t]
        y = np.r_[recall[:last], recall[last - 1]]
        out.append(float(np.trapezoid(y, x) / t))
    return out


def summarize(
    errors: np.ndarray, thresholds=(1.0, 5.0, 10.0), min_error: float | None = None
) -> dict[str, float]:
    """Median and mean of the finite errors, and AUC@thresholds of all (non-finite = failed; same unit as
    the thresholds; ``min_error`` as in :func:`auc`)."""
    errors = np.asarray(errors, dtype=float)
    finite = errors[np.isfinite(errors)]
    result = {
        "median": float(np.median(finite)) if finite.size else float("nan"),
        "mean": float(np.mean(finite)) if finite.size else float("nan"),
    }
    for t, a in zip(thresholds, auc(errors, thresholds, min_error), strict=True):
        result[f"auc@{t:g}"] = a
    return result
