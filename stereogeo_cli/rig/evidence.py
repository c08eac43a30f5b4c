"""What one calibrated pair tells about its rig, in one form for every command that combines pairs."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

EMPTY = np.zeros((0, 2))


@dataclass
class PairEvidence:
    """One pair's readings of its rig (pixels, unit vectors; matches [N x 2] pixels).

    The focal lengths are the pair's estimation (``focal_sigma``: the fit's own 1-sigma, not widened as the
    report widens it), and where an EXIF tag or a given focal length took part, the fields' own reading
    with that prior kept apart in ``focal_prior``: a rig counts one camera's tag once, and widens the
    combination of its pairs once (:func:`stereogeo_cli.rig.combine.reported_focal_sigma_rel`). A focal
    length combined with the image's straight edges is the pair's own reading (each pair's edges are another
    scene's). The other sigmas are the report's (degrees; the baseline's relative).
    """

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
    # per camera the EXIF (or given) prior (focal, sigma) in pixels that the pair's focal took in, or None
    focal_prior: tuple[tuple[float, float] | None, tuple[float, float] | None] = (None, None)
    # the reported 1-sigma of each camera's gravity (the mean of roll's and pitch's, degrees), of R and of
    # T's direction (degrees), and of the baseline (relative; None: not measured)
    sigma_gravity_deg: tuple[float, float] = (math.inf, math.inf)
    sigma_rotation_deg: float = math.inf
    sigma_direction_deg: float = math.inf
    sigma_baseline_rel: float | None = None
    lens: bool = False  # a radial lens term was fitted on either camera

    @property
    def gravity(self) -> tuple[np.ndarray, np.ndarray]:
        return self.gravity_left, self.gravity_right

    @property
    def T(self) -> np.ndarray:
        """The translation at the pair's own baseline (metres)."""
        return self.t_direction * self.baseline_m

    @classmethod
    def from_result(cls, result, matches: bool = True) -> PairEvidence:
        """The evidence of a :class:`~stereogeo_cli.pipeline.CalibrationResult` (``matches``: keep its
        feature matches, which ``--same-rig`` pools)."""
        focal, sigma, prior = [], [], []
        for fit, source in zip((result.left, result.right), result.focal_sources, strict=True):
            if source is None or not math.isfinite(source.fields_sigma_px) or source.source == "lines":
                focal.append(fit.focal_px)
                sigma.append(fit.sigma["focal_px"])
                prior.append(None)
            else:  # the fields' own reading, scaled by what the matches did to the combined focal
                scale = fit.focal_px / source.combined_focal_px
                focal.append(source.fields_focal_px * scale)
                sigma.append(source.fields_sigma_px * scale)
                prior.append((source.focal_px, source.sigma_px))
        c = result.calibration
        reported = (c.sigma_left or {}, c.sigma_right or {})
        pose = c.extra_report.get("pose") or {}
        found = result.matches if matches else None
        return cls(
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
            baseline_m=c.baseline_m,
            matches_left=EMPTY if found is None else np.asarray(found.left, dtype=float),
            matches_right=EMPTY if found is None else np.asarray(found.right, dtype=float),
            distortion=tuple(result.pose.distortion),
            sigma_gravity_deg=tuple(
                float(np.nanmean([s.get("roll_deg") or math.nan, s.get("pitch_deg") or math.nan]))
                for s in reported
            ),
            sigma_rotation_deg=pose.get("sigma_rotation_deg") or math.inf,
            sigma_direction_deg=pose.get("sigma_direction_deg") or math.inf,
            sigma_baseline_rel=pose.get("sigma_baseline_rel"),
            lens=bool(np.any(c.D_left != 0) or np.any(c.D_right != 0)),
        )
