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
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from stereogeo_cli.batch.discovery import PairEntry
from stereogeo_cli.batch.run import PairJob, PairOutcome, RigEvidence, _Progress, _run_pass
from stereogeo_cli.errors import CalibrationFailed, StereoGeoError
from stereogeo_cli.io.text import plural
from stereogeo_cli.pipeline import calibrator_conf, with_rotation_noted

POOL_THRESHOLD_PX = 2.0  # a match joins the same-rig pool if its Sampson error under its pair's pose is below
FOCAL_REJECT_SIGMAS = 3.0  # same-rig: focal estimates this many sigmas from the weighted median are dropped
# same-rig: the share of one pair's focal variance that every pair of the rig has in common. The network's
# error on one camera is mostly a bias of that camera (the same lens, the same kind of scene), which no
# number of pairs averages away and which the pairs' scatter cannot show; 1 keeps the combined focal
# length's sigma at least a typical pair's (docs/batch.md, "Same rig")
FOCAL_COMMON_SHARE = 1.0


@dataclass(frozen=True)
class FocalEstimate:
    """A combined focal length in pixels, its 1-sigma, and which inputs were used."""

    focal_px: float
    sigma_px: float
    used: np.ndarray  # [N] bool


def combine_focals(focals: Sequence[float], sigmas: Sequence[float]) -> FocalEstimate:
    """Robust inverse-variance combination of focal estimates [N] (pixels) with 1-sigmas [N], in log f.

    Centre: the median (not weighted: a pair with a small but wrong sigma must not own it). Rejected:
    estimates more than 3·max(σᵢ, 1.4826·MAD) from it. Result: the weighted mean (w = 1/σ²) of the rest;
    its sigma is √(1/Σw) times the Birge ratio √(χ²/(k-1)) when that exceeds 1 (the estimates scatter more
    than their sigmas say), and at least √FOCAL_COMMON_SHARE times the median sigma of the pairs used (the
    error they have in common does not average away). A missing or non-finite sigma counts as the largest
    finite one (or 100 % when there is none).
    """
    f = np.asarray(focals, dtype=float)
    s = np.asarray(sigmas, dtype=float) / f  # sigma of log f
    if f.size == 0 or not np.all(np.isfinite(f) & (f > 0)):
        raise ValueError("focal estimates must be positive and finite")
    finite = np.isfinite(s) & (s > 0)
    s = np.where(finite, s, np.max(s[finite]) if finite.any() else 1.0)
    s = np.maximum(s, 1e-6)
    x, w = np.log(f), 1.0 / s**2
    centre = float(np.median(x))
    spread = 1.4826 * float(np.median(np.abs(x - centre)))
    used = np.abs(x - centre) <= FOCAL_REJECT_SIGMAS * np.maximum(s, spread)
    xu, wu = x[used], w[used]
    mean = float(np.sum(wu * xu) / np.sum(wu))
    sigma = math.sqrt(1.0 / float(np.sum(wu)))
    if used.sum() > 1:
        birge = math.sqrt(float(np.sum(wu * (xu - mean) ** 2)) / (used.sum() - 1))
        sigma *= max(1.0, birge)
    sigma = max(sigma, math.sqrt(FOCAL_COMMON_SHARE) * float(np.median(s[used])))
    focal = math.exp(mean)
    return FocalEstimate(focal, focal * sigma, used)


def chordal_mean(rotations: Sequence[np.ndarray]) -> np.ndarray:
    """The rotation nearest (Frobenius) to the mean of rotations [N x 3 x 3]."""
    from stereogeo_cli.geometry import closest_rotation

    return closest_rotation(np.sum(np.asarray(rotations, dtype=float), axis=0))


def pool_matches(evidence: Sequence[RigEvidence], K_left: np.ndarray, K_right: np.ndarray):
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
                (ev.size_left, ev.size_right),
                ev.focal,
                ev.distortion,
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
    for side in ("left", "right"):
        sizes = {getattr(o.evidence, f"size_{side}") for o in outcomes}
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
    focal_sigma_scale: tuple[float, float] = (1.0, 1.0),
    focal_bias_sigma: tuple[float, float] = (0.0, 0.0),
    read_spread: tuple[float, float] = (0.0, 0.0),
):
    """The joint calibration (a StereoCalibration) from pass-1 and pass-2 outcomes of the same pairs.

    ``focals``: the (left, right) :class:`FocalEstimate`; ``model``: (file name, sha256) for the report;
    ``pinhole``: fit no lens distortion; ``focal_sigma_scale``: what each focal length's reported sigma is
    widened by (the model's photo_sigma_scale, as a single pair's is: ``Calibrator.reported_sigma``);
    ``focal_bias_sigma``: the relative sigma added to it in quadrature (the network's bias on a camera, for a
    focal length read from the images: the pipeline's ``camera_bias_sigma``); ``read_spread``: per camera, the
    share of the pooled fusion's move of its focal length added in quadrature too (the pipeline's
    ``read_spread`` for a focal length read from the images, as ``Calibrator._spread``; 0 otherwise).
    """
    from stereogeo_cli.fuse import fuse_relative_pose
    from stereogeo_cli.fuse.assemble import CameraEstimate, assemble, focal_sigmas
    from stereogeo_cli.geometry import intrinsic_matrix

    ok = [o for o in second if o.status == "ok"]
    if not ok:
        raise CalibrationFailed("--same-rig: no pair could be calibrated with the combined focal lengths")
    ev = [o.evidence for o in ok]
    sizes = ev[0].size_left, ev[0].size_right
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
            focal_sigmas(
                est.focal_px,
                height,
                est.sigma_px * widen / est.focal_px,
                math.hypot(bias, spread * math.log(moved)),
            ),
        )  # fmt: skip
        for est, (width, height), widen, bias, spread, moved in zip(
            focals, sizes, focal_sigma_scale, focal_bias_sigma, read_spread, pose.focal_scale, strict=True
        )
    )
    if baseline_m is not None:
        baseline, scale_source = float(baseline_m), "baseline"
    else:
        baseline = float(np.median([o.evidence.baseline_m for o in first if o.status == "ok"]))
        scale_source = "learned"
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
        for side, g in (("left", e.gravity_left), ("right", e.gravity_right)):
            roll, pitch = roll_pitch_from_gravity(g)
            entry[f"gravity_{side}"] = [float(v) for v in g]
            entry[f"{side}_roll_deg"], entry[f"{side}_pitch_deg"] = math.degrees(roll), math.degrees(pitch)
        coupling = gravity_angle(pose.R @ e.gravity_left, e.gravity_right)  # how well R·g_left = g_right
        entry["gravity_error_deg"] = math.degrees(float(coupling))
        pairs.append(entry)
    return pairs


# ---------------------------------------------------------------------------------------------- the batch


def _with_exif_prior(fields: FocalEstimate, priors: list[tuple[float, float]]) -> FocalEstimate:
    """The rig's focal from its pairs' fields, combined once with their photos' EXIF focal (the median of
    their priors, with one prior's sigma: the photos of one camera share the error of its tags)."""
    from stereogeo_cli.refine import combine_focal

    if not priors:
        return fields
    prior = float(np.median([p[0] for p in priors]))
    sigma_rel = float(np.median([p[1] / p[0] for p in priors]))
    focal, sigma = combine_focal(fields.focal_px, fields.sigma_px, prior, prior * sigma_rel)
    return replace(fields, focal_px=focal, sigma_px=sigma)


def same_rig_calibration(outcomes, job: PairJob, workers, calibrator, bar: _Progress, baseline_m, stop=None):
    """The joint calibration of pass-1 ``outcomes`` (module docstring); None if ``stop`` (a
    :class:`~stereogeo_cli.batch.interrupt.Stop`) is requested before it is done."""
    start = time.perf_counter()
    ok = [o for o in outcomes if o.status == "ok"]
    if not ok:
        raise CalibrationFailed("--same-rig: no pair was calibrated, so there is nothing to combine")
    _same_sizes(ok)
    focals = tuple(
        _with_exif_prior(
            combine_focals([o.evidence.focal[i] for o in ok], [o.evidence.focal_sigma[i] for o in ok]),
            [o.evidence.focal_prior[i] for o in ok if o.evidence.focal_prior[i] is not None],
        )
        for i in (0, 1)
    )
    second_job = PairJob(
        None, job.formats, job.baseline_m, job.model, job.threads,
        focal_left=focals[0].focal_px, focal_right=focals[1].focal_px, keep_evidence=True,
        pinhole=job.pinhole, lines=job.lines, exif=job.exif, rotate=job.rotate,
    )  # fmt: skip
    if stop is not None and stop.requested:
        return None
    bar.stage("same rig", len(ok))
    entries = [PairEntry(o.name, o.left, o.right) for o in ok]
    second = _run_pass(entries, second_job, workers, calibrator, bar, stop)
    if stop is not None and stop.requested:  # the pass stopped, or may have: the joint fit needs it whole
        return None
    model_info = (ok[0].report or {}).get("model") or {}
    model_id = (model_info.get("file"), model_info.get("sha256"))
    # the rig's focal lengths are reported as a single pair's are: widened for photographs and by the
    # network's bias on a camera unless an EXIF prior took part (Calibrator.reported_sigma)
    photo, bias = calibrator().photo_sigma_scale[2], calibrator().conf["camera_bias_sigma"]
    from_images = [not any(o.evidence.focal_prior[i] is not None for o in ok) for i in (0, 1)]
    scale = tuple(photo if own else 1.0 for own in from_images)
    rig = calibrate_rig(
        ok, second, focals, baseline_m, model_id, pinhole=job.pinhole, focal_sigma_scale=scale,
        focal_bias_sigma=tuple(bias if own else 0.0 for own in from_images),
        read_spread=tuple(calibrator().conf["read_spread"] if own else 0.0 for own in from_images),
    )  # fmt: skip
    rig = with_rotation_noted(rig, job.rotate)
    return replace(rig, timing_ms={"total": (time.perf_counter() - start) * 1e3})  # the same-rig stage
