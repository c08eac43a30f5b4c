"""The robust combinations of many pairs' readings of one rig: focal lengths in log f, unit directions
(a world's up), rotations; and the sigma a rig's focal length read from its images reports.

Focal lengths and directions are combined alike: a robust centre (the median: one vote per reading, so a
confidently wrong one cannot own it), readings farther than ``reject`` times their sigma (or the readings'
own spread, 1.4826·MAD, if wider) left out, the inverse-variance weighted mean of the rest, its sigma
widened by the Birge ratio where the readings scatter more than their sigmas say, and kept at least at a
floor: the readings of one rig share much of their error (one camera, one scene), which no number of them
averages away.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from stereogeo_cli.refine.lm import combine_focal
from stereogeo_cli.rig.evidence import PairEvidence

FOCAL_REJECT_SIGMAS = 3.0  # a focal reading this many sigmas from the median is left out
# the share of one pair's focal variance that every pair of the rig has in common. The network's error on
# one camera is mostly a bias of that camera (the same lens, the same kind of scene), which no number of
# pairs averages away and which the pairs' scatter cannot show; 1 keeps the combined focal length's sigma at
# least a typical pair's
FOCAL_COMMON_SHARE = 1.0


@dataclass(frozen=True)
class FocalEstimate:
    """A focal length in pixels and its 1-sigma (pixels; inf where it is not known); where it combines
    readings, which of them were used."""

    focal_px: float
    sigma_px: float
    used: np.ndarray | None = None  # [N] bool


def combine_focals(focals: Sequence[float], sigmas: Sequence[float]) -> FocalEstimate:
    """Robust inverse-variance combination of focal estimates [N] (pixels) with 1-sigmas [N], in log f (the
    module's rule; the floor is √FOCAL_COMMON_SHARE times the median sigma of the readings used). A missing
    or non-finite sigma counts as the largest finite one (or 100 % when there is none)."""
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


def with_prior(fields: FocalEstimate, priors: list[tuple[float, float]]) -> FocalEstimate:
    """The rig's focal from its pairs' fields, combined once with their photos' EXIF focal (the median of
    their priors, with one prior's sigma: the photos of one camera share the error of its tags)."""
    if not priors:
        return fields
    prior = float(np.median([p[0] for p in priors]))
    sigma_rel = float(np.median([p[1] / p[0] for p in priors]))
    focal, sigma = combine_focal(fields.focal_px, fields.sigma_px, prior, prior * sigma_rel)
    return replace(fields, focal_px=focal, sigma_px=sigma)


def pairs_focals(evidence: Sequence[PairEvidence]) -> tuple[FocalEstimate, FocalEstimate]:
    """Each camera's focal length from its pairs: their readings combined (:func:`combine_focals`), then
    with their EXIF priors once (:func:`with_prior`)."""
    return tuple(
        with_prior(
            combine_focals(
                [e.cameras[i].focal_px for e in evidence], [e.cameras[i].sigma["focal_px"] for e in evidence]
            ),
            [e.cameras[i].focal_prior for e in evidence if e.cameras[i].focal_prior is not None],
        )
        for i in (0, 1)
    )


def read_from_images(evidence: Sequence[PairEvidence]) -> tuple[bool, bool]:
    """Per camera: its focal length is the images' read alone (no pair had an EXIF or given prior)."""
    return tuple(not any(e.cameras[i].focal_prior is not None for e in evidence) for i in (0, 1))


@dataclass(frozen=True)
class FocalWidening:
    """What a rig's focal length reports beyond its pairs' combined sigma, as a single pair's does where it
    is read from the images (``Calibrator.reported_sigma``): the sigma scaled by the model's
    ``photo_sigma_scale``, the network's bias on a camera (``camera_bias_sigma``) and a share
    (``read_spread``) of a fusion's move of it added in quadrature. A focal length a prior took part in is
    reported as combined (:meth:`none`)."""

    scale: float = 1.0
    bias: float = 0.0
    read_spread: float = 0.0

    @classmethod
    def of(cls, calibrator, from_images: bool) -> FocalWidening:
        """The widening of ``calibrator`` (a :class:`~stereogeo_cli.pipeline.Calibrator`) for a focal length
        read from the images (``from_images``), else none."""
        if not from_images:
            return cls()
        conf = calibrator.conf
        return cls(calibrator.photo_sigma_scale[2], conf["camera_bias_sigma"], conf["read_spread"])


def widenings(calibrator, evidence: Sequence[PairEvidence]) -> tuple[FocalWidening, FocalWidening]:
    """Each camera's :class:`FocalWidening` under ``calibrator`` for a rig of these pairs: a single pair's
    where the focal length is the images' read alone (:func:`read_from_images`), none where a prior took
    part."""
    return tuple(FocalWidening.of(calibrator, own) for own in read_from_images(evidence))


def reported_focal_sigma_rel(estimate: FocalEstimate, widening: FocalWidening, moved: float = 1.0) -> tuple:
    """The relative sigma of ``estimate`` as a rig reports it, and the relative spread added to it in
    quadrature (:func:`stereogeo_cli.fuse.assemble.focal_sigmas` takes the two): ``moved`` is how much a
    fusion scaled the focal length after its pairs were combined."""
    sigma_rel = estimate.sigma_px * widening.scale / estimate.focal_px
    return sigma_rel, math.hypot(widening.bias, widening.read_spread * math.log(moved))


def reported(estimate: FocalEstimate, widening: FocalWidening) -> FocalEstimate:
    """``estimate`` with the sigma a rig reports for it (:func:`reported_focal_sigma_rel`, no fusion's move),
    combined as :func:`stereogeo_cli.fuse.assemble.focal_sigmas` combines the two."""
    sigma_rel, spread = reported_focal_sigma_rel(estimate, widening)
    if spread > 0 and math.isfinite(sigma_rel) and sigma_rel > 0:
        sigma_rel = math.hypot(sigma_rel, spread)
    return replace(estimate, sigma_px=estimate.focal_px * sigma_rel)


def chordal_mean(rotations: Sequence[np.ndarray]) -> np.ndarray:
    """The rotation nearest (Frobenius) to the mean of rotations [N x 3 x 3]."""
    from stereogeo_cli.geometry import closest_rotation

    return closest_rotation(np.sum(np.asarray(rotations, dtype=float), axis=0))


def mean_direction(directions: Sequence[np.ndarray]) -> np.ndarray:
    """The unit mean of directions [N x 3] (each normalised first)."""
    total = np.sum([d / np.linalg.norm(d) for d in directions], axis=0)
    return total / np.linalg.norm(total)


def combine_directions(
    directions: np.ndarray, sigmas: np.ndarray, reject: float, common_factor: float
) -> tuple[np.ndarray, float, np.ndarray]:
    """Unit directions [N x 3] with 1-sigmas [N] (radians) combined by the module's rule: the centre the
    normalised coordinate-wise median, the floor the median sigma of those used over ``common_factor``.
    Returns (the direction [3], its 1-sigma in radians, which were used [N] bool)."""
    centre = np.median(directions, axis=0)
    centre /= np.linalg.norm(centre)
    angles = np.arccos(np.clip(directions @ centre, -1.0, 1.0))
    spread = 1.4826 * float(np.median(angles))
    used = angles <= reject * np.maximum(sigmas, spread)
    w = 1.0 / sigmas[used] ** 2
    mean = np.sum(w[:, None] * directions[used], axis=0)
    mean /= np.linalg.norm(mean)
    sigma = math.sqrt(1.0 / float(np.sum(w)))
    if used.sum() > 1:
        residual = np.arccos(np.clip(directions[used] @ mean, -1.0, 1.0))
        # two tangent components per reading: χ² has 2(k - 1) degrees of freedom
        birge = math.sqrt(float(np.sum(w * residual**2)) / (2 * (used.sum() - 1)))
        sigma *= max(1.0, birge)
    return mean, max(sigma, float(np.median(sigmas[used])) / common_factor), used
