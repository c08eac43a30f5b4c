"""``batch-calibrate --same-rig``: one calibration of a rig from all its pairs.

Same rig (``--same-rig``, :func:`calibrate_rig`): one focal length per camera and one R, T from all pairs,
gravity per pair. Pass 1 calibrates each pair alone. Per camera the focal lengths are combined in log f: the
median as a robust centre (one vote per pair: a confidently wrong pair cannot pull it), pairs further than
3·max(σᵢ, 1.4826·MAD) from it rejected, then the inverse-variance weighted mean of the rest (σ inflated by the
Birge ratio when the pairs scatter more than their σ say, and never below a typical pair's σ: the network's
error on one camera is mostly common to all its pairs). Pass 2 re-runs every pair with those focal lengths
held fixed, which re-estimates its gravity and its relative pose with consistent intrinsics. The matches
consistent with a pair's pass-2 pose (Sampson error below :data:`POOL_THRESHOLD_PX`) of all pairs are
concatenated — they share K and R, T, so this is exact — into one relative-pose estimation, with the chordal
mean of the pairs' rotations and the mean of their translation directions as the prior. The baseline is
``--baseline`` or the median of the pairs' learned baselines.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from stereogeo_cli.batch.passes import run_pass
from stereogeo_cli.batch.records import PairJob, PairOutcome
from stereogeo_cli.errors import CalibrationFailed, StereoGeoError
from stereogeo_cli.io.pairs import PairEntry
from stereogeo_cli.io.text import plural
from stereogeo_cli.jobs.progress import PairProgress
from stereogeo_cli.options import calibrator_conf
from stereogeo_cli.pipeline import with_rotation_noted
from stereogeo_cli.rig.combine import (
    FocalWidening,
    chordal_mean,
    pairs_focals,
    reported_focal_sigma_rel,
    widenings,
)
from stereogeo_cli.rig.evidence import PairEvidence
from stereogeo_cli.rig.start import rig_baseline

POOL_THRESHOLD_PX = 2.0  # a match joins the same-rig pool if its Sampson error under its pair's pose is below


def pool_matches(evidence: Sequence[PairEvidence], K_left: np.ndarray, K_right: np.ndarray):
    """All pairs' matches consistent with their own pose (Sampson error < POOL_THRESHOLD_PX) as one Matches.

    The matches are judged after undoing the pair's own lens distortion, and pooled as observed (the joint
    fit estimates the distortion again). Pairs whose pose did not come from matches add nothing. Returns
    (Matches, inliers per pair [N]).
    """
    from stereogeo_cli.fuse import Matches, sampson_errors
    from stereogeo_cli.geometry import fundamental_matrix, intrinsic_matrix, undistort_division

    left, right, counts = [], [], []
    for ev in evidence:
        if ev.pose_source != "matches" or len(ev.matches_left) == 0:
            counts.append(0)
            continue
        F = fundamental_matrix(K_left, K_right, ev.R, ev.t_direction)
        # the pair's lens undone (its k belongs to its own focal; the pixels stay the same pixels)
        seen = [
            undistort_division(points, intrinsic_matrix(focal, *size), k)
            for points, size, focal, k in zip(
                (ev.matches_left, ev.matches_right),
                [(c.width, c.height) for c in ev.cameras],
                [c.focal_px for c in ev.cameras],
                [c.division_k for c in ev.cameras],
                strict=True,
            )
        ]
        keep = np.abs(sampson_errors(F, *seen)) < POOL_THRESHOLD_PX
        left.append(ev.matches_left[keep])
        right.append(ev.matches_right[keep])
        counts.append(int(keep.sum()))
    if not left:
        return Matches(np.zeros((0, 2)), np.zeros((0, 2))), counts
    return Matches(np.concatenate(left), np.concatenate(right)), counts


def _same_sizes(outcomes: Sequence[PairOutcome]) -> None:
    for i, side in enumerate(("left", "right")):
        sizes = {(o.evidence.cameras[i].width, o.evidence.cameras[i].height) for o in outcomes}
        if len(sizes) > 1:
            listed = ", ".join(f"{w}x{h}" for w, h in sorted(sizes))
            raise StereoGeoError(f"--same-rig: the {side} images differ in size ({listed}); one rig has one")


def calibrate_rig(
    first: Sequence[PairOutcome],
    second: Sequence[PairOutcome],
    focals,
    baseline_m: float | None,
    model,
    pinhole: bool = False,
    widenings: tuple[FocalWidening, FocalWidening] = (FocalWidening(), FocalWidening()),
):
    """The joint calibration (a StereoCalibration) from pass-1 and pass-2 outcomes of the same pairs.

    ``focals``: the (left, right) :class:`~stereogeo_cli.rig.combine.FocalEstimate`; ``model``: (file name,
    sha256) for the report; ``pinhole``: fit no lens distortion; ``widenings``: what each camera's focal
    length reports beyond its combined sigma (:class:`~stereogeo_cli.rig.combine.FocalWidening`; its
    ``read_spread`` is a share of the pooled fusion's move of the focal length).
    """
    from stereogeo_cli.fuse import fuse_relative_pose
    from stereogeo_cli.fuse.assemble import CameraEstimate, assemble, focal_sigmas
    from stereogeo_cli.geometry import intrinsic_matrix

    ok = [o for o in second if o.status == "ok"]
    if not ok:
        raise CalibrationFailed("--same-rig: no pair could be calibrated with the combined focal lengths")
    ev = [o.evidence for o in ok]
    sizes = tuple((c.width, c.height) for c in ev[0].cameras)
    K_left, K_right = (intrinsic_matrix(est.focal_px, *size) for est, size in zip(focals, sizes, strict=True))
    pooled, counts = pool_matches(ev, K_left, K_right)
    t_mean = np.sum([e.t_direction for e in ev], axis=0)
    pose = fuse_relative_pose(
        pooled, K_left, K_right, prior_R=chordal_mean([e.R for e in ev]),
        prior_t=t_mean if np.linalg.norm(t_mean) > 1e-9 else ev[0].t_direction,
        conf=calibrator_conf(pinhole).get("fuse"),
        # the focal ratio is refined with the pose, as for a single pair: the lens shows only with it free
        focal_sigma_rel=tuple(est.sigma_px / est.focal_px for est in focals),
    )  # fmt: skip
    focals = tuple(
        replace(est, focal_px=est.focal_px * scale, sigma_px=est.sigma_px * scale)
        for est, scale in zip(focals, pose.focal_scale, strict=True)
    )
    # each camera's gravity is its own in every pair ("pairs"); the focal lengths' sigmas are reported as a
    # single pair's are (Calibrator.reported_sigma and _spread: the scale, the bias and the fusion's move)
    cameras = tuple(
        CameraEstimate(
            est.focal_px,
            width,
            height,
            None,
            focal_sigmas(est.focal_px, height, *reported_focal_sigma_rel(est, widening, moved)),
        )  # fmt: skip
        for est, (width, height), widening, moved in zip(
            focals, sizes, widenings, pose.focal_scale, strict=True
        )
    )
    baseline, scale_source, _ = rig_baseline([o.evidence for o in first if o.status == "ok"], baseline_m)
    notes = [
        f"joint calibration of {plural(len(ok), 'pair')}; gravity per pair in 'pairs'",
        f"focal from {plural(int(focals[0].used.sum()), 'pair')} (left) and "
        f"{plural(int(focals[1].used.sum()), 'pair')} (right)",
    ]
    return assemble(
        cameras, pose, baseline, scale_source, model, list(pose.notes), notes=notes,
        more={"pairs": _pair_gravity(ok, counts, pose)},
    )  # fmt: skip


def _pair_gravity(ok: Sequence[PairOutcome], counts, pose) -> list[dict[str, Any]]:
    """The report's ``pairs``: per pair its pooled matches, each camera's gravity, and how well the rig's R
    carries one camera's gravity onto the other's."""
    from stereogeo_cli.geometry import gravity_angle, roll_pitch_from_gravity

    pairs = []
    for o, n in zip(ok, counts, strict=True):
        e = o.evidence
        entry: dict[str, Any] = {"name": o.name, "pooled_matches": n}
        for side, g in zip(("left", "right"), e.gravity, strict=True):
            roll, pitch = roll_pitch_from_gravity(g)
            entry[f"gravity_{side}"] = [float(v) for v in g]
            entry[f"{side}_roll_deg"], entry[f"{side}_pitch_deg"] = math.degrees(roll), math.degrees(pitch)
        coupling = gravity_angle(pose.R @ e.gravity[0], e.gravity[1])  # how well R·g_left = g_right
        entry["gravity_error_deg"] = math.degrees(float(coupling))
        pairs.append(entry)
    return pairs


# ---------------------------------------------------------------------------------------------- the batch


def same_rig_calibration(outcomes, job: PairJob, workers, calibrator, bar: PairProgress, stop=None):
    """The joint calibration of pass-1 ``outcomes`` (module docstring); None if ``stop`` (a
    :class:`~stereogeo_cli.jobs.interrupt.Stop`) is requested before it is done."""
    start = time.perf_counter()
    ok = [o for o in outcomes if o.status == "ok"]
    if not ok:
        raise CalibrationFailed("--same-rig: no pair was calibrated, so there is nothing to combine")
    _same_sizes(ok)
    focals = pairs_focals([o.evidence for o in ok])
    pair = job.pair.with_focals(focals[0].focal_px, focals[1].focal_px)
    second_job = PairJob(None, job.formats, pair, job.model, job.threads, keep_evidence=True)
    if stop is not None and stop.requested:
        return None
    bar.stage("same rig", len(ok))
    entries = [PairEntry(o.name, o.left, o.right) for o in ok]
    second = run_pass(entries, second_job, workers, calibrator, bar, stop)
    if stop is not None and stop.requested:  # the pass stopped, or may have: the joint fit needs it whole
        return None
    model_info = (ok[0].report or {}).get("model") or {}
    model_id = (model_info.get("file"), model_info.get("sha256"))
    # the rig's focal lengths are reported as a single pair's are: widened for photographs and by the
    # network's bias on a camera unless an EXIF prior took part (Calibrator.reported_sigma)
    widened = widenings(calibrator(), [o.evidence for o in ok])
    rig = calibrate_rig(
        ok, second, focals, job.pair.baseline_m, model_id, pinhole=job.pair.pinhole, widenings=widened
    )
    rig = with_rotation_noted(rig, job.pair.rotate)
    return replace(rig, timing_ms={"total": (time.perf_counter() - start) * 1e3})  # the same-rig stage
