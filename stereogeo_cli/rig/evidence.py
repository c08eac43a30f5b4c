"""What one calibrated pair tells about its rig, in one form for every command that combines pairs."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stereogeo_cli.fuse.assemble import CameraEstimate

EMPTY = np.zeros((0, 2))


@dataclass
class PairEvidence:
    """One pair's readings of its rig (pixels, unit vectors; matches [N x 2] pixels).

    Each camera (left, right) is a :class:`~stereogeo_cli.fuse.assemble.CameraEstimate`: its focal length
    is the pair's estimation (``sigma["focal_px"]``: the fit's own 1-sigma, not widened as the report widens
    it), and where an EXIF tag or a given focal length took part, the fields' own reading with that prior
    kept apart in ``focal_prior``: a rig counts one camera's tag once, and widens the combination of its
    pairs once (:func:`stereogeo_cli.rig.combine.reported_focal_sigma_rel`). A focal length combined with the
    image's straight edges is the pair's own reading (each pair's edges are another scene's). Its
    ``sigma["gravity_deg"]`` is the reported 1-sigma of its gravity (the mean of roll's and pitch's) and its
    ``division_k`` the fusion's lens, for the refined focal length. The rig's sigmas are the report's
    (degrees; the baseline's relative, None: not measured).
    """

    cameras: tuple[CameraEstimate, CameraEstimate]
    R: np.ndarray
    t_direction: np.ndarray
    pose_source: str
    baseline_m: float
    matches_left: np.ndarray
    matches_right: np.ndarray
    sigma_rotation_deg: float = math.inf
    sigma_direction_deg: float = math.inf
    sigma_baseline_rel: float | None = None
    lens: bool = False  # a radial lens term was fitted on either camera

    @property
    def gravity(self) -> tuple[np.ndarray, np.ndarray]:
        return self.cameras[0].gravity_up, self.cameras[1].gravity_up

    @property
    def T(self) -> np.ndarray:
        """The translation at the pair's own baseline (metres)."""
        return self.t_direction * self.baseline_m

    @classmethod
    def from_result(cls, result, matches: bool = True) -> PairEvidence:
        """The evidence of a :class:`~stereogeo_cli.pipeline.CalibrationResult` (``matches``: keep its
        feature matches, which ``--same-rig`` pools)."""
        c = result.calibration
        pose = c.extra_report.get("pose") or {}
        found = result.matches if matches else None
        cameras = []
        fits = result.left, result.right
        for fit, source, reported, k in zip(fits, result.focal_sources, (c.sigma_left, c.sigma_right),
                                            result.pose.distortion, strict=True):  # fmt: skip
            focal, sigma, prior = fit.focal_px, fit.sigma["focal_px"], None
            if source is not None and math.isfinite(source.fields_sigma_px) and source.source != "lines":
                # the fields' own reading, scaled by what the matches did to the combined focal
                scale = fit.focal_px / source.combined_focal_px
                focal, sigma = source.fields_focal_px * scale, source.fields_sigma_px * scale
                prior = (source.focal_px, source.sigma_px)
            angles = [(reported or {}).get(key) or math.nan for key in ("roll_deg", "pitch_deg")]
            gravity = float(np.nanmean(angles))
            cameras.append(CameraEstimate(
                focal, fit.width, fit.height, np.asarray(fit.gravity_up, dtype=float),
                {"focal_px": sigma, "gravity_deg": gravity}, division_k=float(k), focal_prior=prior,
            ))  # fmt: skip
        return cls(
            cameras=(cameras[0], cameras[1]),
            R=np.asarray(result.pose.R, dtype=float),
            t_direction=np.asarray(result.pose.t_direction, dtype=float),
            pose_source=result.pose.source,
            baseline_m=c.baseline_m,
            matches_left=EMPTY if found is None else np.asarray(found.left, dtype=float),
            matches_right=EMPTY if found is None else np.asarray(found.right, dtype=float),
            sigma_rotation_deg=pose.get("sigma_rotation_deg") or math.inf,
            sigma_direction_deg=pose.get("sigma_direction_deg") or math.inf,
            sigma_baseline_rel=pose.get("sigma_baseline_rel"),
            lens=bool(np.any(c.D_left != 0) or np.any(c.D_right != 0)),
        )
