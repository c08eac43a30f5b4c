"""Where a rig's own calibration starts from its pairs: R and T's direction, and its baseline."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from stereogeo_cli.rig.combine import chordal_mean, mean_direction
from stereogeo_cli.rig.evidence import PairEvidence


def rig_pose(evidence: Sequence[PairEvidence]) -> tuple[np.ndarray, np.ndarray]:
    """The rig's R (the chordal mean of its pairs') and T's unit direction (their directions' mean)."""
    return chordal_mean([e.R for e in evidence]), mean_direction([e.t_direction for e in evidence])


def rig_baseline(evidence: Sequence[PairEvidence], given_m: float | None) -> tuple[float, str, float | None]:
    """The rig's baseline (metres), where it came from, and its relative 1-sigma: ``--baseline``
    (``given_m``, exact), or else the median of the pairs' learned ones with a typical pair's sigma (the
    pairs of one rig share the pose head's error on it, which does not average away; None where no pair
    measured one)."""
    if given_m is not None:
        return float(given_m), "baseline", 0.0
    sigmas = [s for e in evidence if (s := e.sigma_baseline_rel) is not None and math.isfinite(s)]
    sigma = float(np.median(sigmas)) if sigmas else None
    return float(np.median([e.baseline_m for e in evidence])), "learned", sigma
