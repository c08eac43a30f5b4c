"""Accuracy metrics as the GeoCalib and StereoGeo papers report them."""

from __future__ import annotations

import numpy as np


def auc(errors: np.ndarray, thresholds=(1.0, 5.0, 10.0)) -> list[float]:
    """Area under the recall curve of ``errors`` up to each threshold, normalised to [0, 1].

    The recall at error e is the share of samples with error ≤ e; the curve starts at (0, 0) and is
    held flat from the largest error below a threshold up to the threshold.
    """
    errors = np.sort(np.asarray(errors, dtype=float).ravel())
    errors = errors[np.isfinite(errors)] if errors.size else errors
    if errors.size == 0:
        return [float("nan")] * len(thresholds)
    recall = np.arange(1, len(errors) + 1) / len(errors)
    errors = np.r_[0.0, errors]
    recall = np.r_[0.0, recall]
    out = []
    for t in thresholds:
        last = int(np.searchsorted(errors, t, side="right"))
        x = np.r_[errors[:last], t]
        y = np.r_[recall[:last], recall[last - 1]]
        out.append(float(np.trapezoid(y, x) / t))
    return out


def summarize(errors: np.ndarray, thresholds=(1.0, 5.0, 10.0)) -> dict[str, float]:
    """Median, mean and AUC@thresholds of errors (same unit as the thresholds)."""
    errors = np.asarray(errors, dtype=float)
    finite = errors[np.isfinite(errors)]
    result = {
        "median": float(np.median(finite)) if finite.size else float("nan"),
        "mean": float(np.mean(finite)) if finite.size else float("nan"),
    }
    for t, a in zip(thresholds, auc(finite, thresholds), strict=True):
        result[f"auc@{t:g}"] = a
    return result
