"""The rig's relative pose: essential matrix from matches, refined jointly with gravity and the pose head;
or, where a rotation explains the matches better, two views from one centre (``fuse/one_centre.py``).

Convention (fixed): ``X_right = R @ X_left + T``, T in metres.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import cv2
import numpy as np

from stereogeo_cli.fuse.matches import Matches
from stereogeo_cli.fuse.one_centre import essential_gric, fit_rotation
from stereogeo_cli.geometry.camera import corner_radius, division_limit, undistort_division, vfov_from_focal
from stereogeo_cli.geometry.epipolar import essential_matrix, fundamental_matrix
from stereogeo_cli.geometry.gravity import (
    couple_rotation_to_gravity,
    gravity_angle,
    retract_on_sphere,
    tangent_basis,
)
from stereogeo_cli.geometry.rotation import (
    axis_angle_from_rotation,
    rotation_angle,
    rotation_error,
    rotation_from_axis_angle,
    skew,
)
from stereogeo_cli.refine.levenberg import Settings, levenberg_marquardt
from stereogeo_cli.settings import resolve

default_conf = {
    "min_matches": 20,  # fewer matches than this: the pose head and gravity alone
    "min_inliers": 15,  # fewer essential-matrix inliers than this: the pose head and gravity alone
    # ... and where each image has at least this many features, the two views share (almost) nothing: the
    # cameras look apart, unlike the near-parallel rigs the pose head learnt, and its R is reported with the
    # sigma of a guess, the cameras' mean horizontal field of view (_pose_head_alone)
    "unshared_min_features": 500,
    "ransac_threshold_px": 1.0,  # MAGSAC threshold on the epipolar error, pixels
    "ransac_confidence": 0.9999,
    # where MAGSAC's essential matrix misses its own inliers, ask RANSAC too (essential_pose); off: OpenCV's
    # plain findEssentialMat + recoverPose, as the evaluation's baselines are
    "essential_second_opinion": True,
    "sampson_scale_px": 1.0,  # Huber scale of the Sampson error in the joint refinement, pixels
    "min_noise_px": 0.25,  # floor of the estimated match noise (keeps the data from swamping the priors)
    "iterations": 15,  # Gauss–Newton/LM steps of the joint refinement
    "prior_rotation_sigma_deg": 5.0,  # 1-sigma of the pose head's rotation
    "prior_direction_sigma_deg": 15.0,  # 1-sigma of the pose head's translation direction
    # A "turned" rig: the matches, fitted without the pose head, turn the cameras this many degrees or more
    # apart (five times the renders' largest toe-in), and with the head they still do or fit it worse by
    # turned_rig_min_gain (robust cost in noise² units: chi-square with the head's 3 dof, p 1e-3). There the
    # two focal lengths' common scale is refined with the pose (where the caller gives its sigma), and the
    # pose head is left out where it reads the rotation head_gate_sigmas of its sigmas away (_turned_rig;
    # docs/refine.md, "Turned rigs")
    "turned_rig_deg": 20.0,
    "turned_rig_min_gain": 16.3,
    "head_gate_sigmas": 4.0,
    # also fit R with T's direction held at the pose head's: in a far scene the matches leave the direction
    # in a shallow valley, and their score, not the refinement's slide, chooses (_head_direction_held)
    "head_direction_held": True,
    # The sign of t: a point votes (in front of both cameras or behind) where its two rays meet at more than
    # sign_min_parallax_deg and than sign_rotation_sigmas of the rotation's largest 1-sigma, the two focal
    # lengths' common scale taken in; the votes decide where at least sign_min_points cast them and at least
    # sign_min_share of them agree, else the pose head's sign (_Joint.signed; docs/refine.md, "The sign of T")
    "sign_min_parallax_deg": 1.0,
    "sign_rotation_sigmas": 3.0,
    "sign_min_points": 10,
    "sign_min_share": 0.8,
    "distortion": True,  # fit one radial (division-model) distortion parameter per camera to the matches
    "distortion_sigma": 0.2,  # 1-sigma of the zero-mean prior on it (normalised coordinates)
    "distortion_max_pincushion": 0.0,  # largest pincushion stretch k·r² at the image corner (0: barrel only)
    "distortion_min_inliers": 50,  # fewer inliers than this: no distortion fitted
    "distortion_min_gain": 20.0,  # robust cost (noise² units) k must save to be kept (χ², 2 dof: p 5e-5)
    # robust cost (noise² units) a free focal ratio must save over equal focal lengths to be kept; 0: never
    # hold them equal. χ² with 1 dof would say 10 (p 1.5e-3), but real matches carry errors the camera model
    # does not (a lens fitted with one term, principal points off the centre) that a free ratio soaks up:
    # 30 kept the renders' medians (800 pairs) and held two real rigs equal that 10 did not
    # (docs/refine.md, "The fusion's allowances")
    "equal_focal_max_gain": 30.0,
    # 1-sigma of a raw camera's principal point from the image centre, per axis, as a share of the image's
    # width / height: the pose's sigmas take it in (it moves R by the two cameras' difference over f). The
    # two raw rigs of the real test sets (the chessboard set, EuRoC) have theirs 1.4-2.9 % apart per axis
    # (RMS 2.1 %, so 1.5 % each; docs/refine.md, "The fusion's allowances").
    "principal_point_sigma": 0.015,
    # recognise two views from one centre (a rotation explains the matches better than an essential
    # matrix, by GRIC) and fit them as such: R and the focal lengths from the rotation (fuse/one_centre.py)
    "one_centre": True,
    "one_centre_min_noise_px": 0.02,  # the floor of the match noise the two are compared at (GRIC)
    "one_centre_conf": {},  # overrides of stereogeo_cli.fuse.one_centre.default_conf
}


@dataclass(frozen=True)
class FusionStart:
    """A fusion's choices on its matches, for a fusion of the same matches with other focal lengths (the
    pipeline's second one, after the vanishing points moved them by a few percent): its pose (R, t), its
    inliers, and what it decided: a turned rig, the pose head left out (with its ``notes``), a lens fitted,
    the two focal lengths held equal, its noise scale and its lens. The matches decided these, and they do
    not change; tested again on focal lengths a few percent apart, the choices came out the same on 34 of 37
    pairs of renders and real sets. The second fusion refines once from them instead of running the
    essential matrix, every start and every test again (docs/refine.md, "Vanishing points"). On a turned
    rig it runs them all again and keeps only the verdict on the rig (turned, the head left out): there the
    common focal scale is refined with the pose, a fit with more than one minimum that other focal lengths
    can send elsewhere (the car set's R 19.6° → 26.3° from the first one's start)."""

    R: np.ndarray
    t: np.ndarray
    mask: np.ndarray
    turned: bool
    head_out: bool
    radial: bool
    equal: bool
    notes: tuple[str, ...]
    k: tuple[float, float]  # its lens (division-model k), in the normalised coordinates of its focal lengths
    focal_px: tuple[float, float]  # ... which are these (the given K's times its focal scales)
    noise_px: float  # its scale of the match noise (the robust loss's unit)
    one_centre: bool = False  # its matches were explained by a rotation alone (fuse/one_centre.py)


@dataclass
class RelativePose:
    """Rotation [3 x 3], unit translation direction [3], and how they were obtained."""

    R: np.ndarray
    t_direction: np.ndarray
    # "matches" (an essential matrix), "rotation" (views from one centre: fuse/one_centre.py) or "pose_head"
    source: str
    matches_found: int = 0
    inliers: int = 0
    sigma_rotation_deg: float = float("inf")
    sigma_direction_deg: float = float("inf")
    gravity_error_deg: float | None = None  # angle between R·g_left and g_right (the fields' gravity)
    focal_scale: tuple[float, float] = (1.0, 1.0)  # refined focal / given focal, per camera
    # the 1-sigma of the two focal lengths' common log scale where the matches refined it (None: not refined,
    # the fields' sigma stands)
    sigma_common_focal: float | None = None
    # the relative 1-sigma of the two focal lengths' common scale that the sigmas above take in: the fields'
    # (0 where a focal length was held), or on a turned rig the images' read with the camera bias
    sigma_focal_considered: float = 0.0
    # the matches turn the cameras far apart (fuse_relative_pose's turned_rig_deg): a rig unlike the renders,
    # where the pose head was left out if it disagreed
    turned: bool = False
    # the two focal lengths were held equal (the matches could not tell their ratio from 1; without matches,
    # pipeline.hold_alike_focals: the fields read them alike)
    equal_focals: bool = False
    # radial distortion per camera: the division-model k (undistorted = distorted / (1 + k·r²)) in the
    # normalised coordinates of the refined K, and its 1-sigma (0 and inf: not fitted)
    distortion: tuple[float, float] = (0.0, 0.0)
    sigma_distortion: tuple[float, float] = (float("inf"), float("inf"))
    # where the sign of t came from: "matches" (points in front of both cameras, with parallax) or "pose_head"
    # (a far scene: the head learnt rigs whose right camera is on the right, as the file names say)
    sign_source: str = "pose_head"
    notes: list[str] = field(default_factory=list)
    # what a fusion of the same matches with other focal lengths starts from (None: from the pose head)
    start: FusionStart | None = None
    # two views from one centre (source "rotation"): the relative 1-sigma of each camera's focal length as the
    # rotation alone reads it (None: held, or read as nothing), which focal_scale combines with the given
    # one's; None for every other pose
    focal_read_sigma_rel: tuple[float | None, float | None] | None = None

    def translation(self, baseline_m: float) -> np.ndarray:
        """T [3] in metres for a baseline |T| in metres."""
        return self.t_direction * float(baseline_m)


def _normalise(points: np.ndarray, K: np.ndarray) -> np.ndarray:
    out = _homogeneous(points) @ np.linalg.inv(K).T
    return out[:, :2] / out[:, 2:]


def ray_angles(normalised_left: np.ndarray, normalised_right: np.ndarray, R: np.ndarray) -> np.ndarray:
    """The angle (radians) [N] between each match's two rays, given as normalised image points [N x 2] of
    each camera, with ``X_right = R @ X_left + T``."""
    ray_l = _homogeneous(normalised_left)
    ray_r = _homogeneous(normalised_right) @ R  # Rᵀ·ray, left frame
    cos = np.sum(ray_l * ray_r, axis=1) / np.linalg.norm(ray_l, axis=1) / np.linalg.norm(ray_r, axis=1)
    return np.arccos(np.clip(cos, -1.0, 1.0))


def sampson_errors(F: np.ndarray, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Signed Sampson errors [N] in pixels of matches left, right [N x 2] under F (x_rightᵀ F x_left = 0)."""
    return _sampson(F, _homogeneous(left), _homogeneous(right))[0]


def _homogeneous(points: np.ndarray) -> np.ndarray:
    """Pixel points [N x 2] as homogeneous ones [N x 3] (third coordinate 1)."""
    out = np.ones((len(points), 3))
    out[:, :2] = points
    return out


def _sampson(F: np.ndarray, pl: np.ndarray, pr: np.ndarray, dF: np.ndarray | None = None):
    """Sampson errors s = a / √D [N] of homogeneous points ``pl``, ``pr`` [N x 3] (a = x_rᵀ F x_l; D = the
    squared first two entries of F x_l and Fᵀ x_r), and with ``dF`` [P x 3 x 3] (F's derivatives with
    respect to P parameters) the errors' derivatives [N x P] with respect to those parameters."""
    Fl = pl @ F.T
    Ftr = pr @ F
    algebraic = np.einsum("ni,ni->n", pr, Fl)
    denom = np.maximum(
        np.einsum("ni,ni->n", Fl[:, :2], Fl[:, :2]) + np.einsum("ni,ni->n", Ftr[:, :2], Ftr[:, :2]), 1e-300
    )
    root = np.sqrt(denom)
    errors = algebraic / root
    if dF is None:
        return errors, None
    # per parameter p: ∂a = x_rᵀ·dF_p·x_l; ∂D = 2 Σ_{i<2} ((F x_l)_i (dF_p x_l)_i + (Fᵀ x_r)_i (dF_pᵀ x_r)_i)
    n, count = len(errors), len(dF)
    dF_l = (pl @ dF.reshape(-1, 3).T).reshape(n, count, 3)  # dF_p·x_l
    dFt_r = (pr @ dF.transpose(0, 2, 1).reshape(-1, 3).T).reshape(n, count, 3)  # dF_pᵀ·x_r
    d_algebraic = np.einsum("npi,ni->np", dF_l, pr)
    d_denom = 2.0 * (
        np.einsum("npi,ni->np", dF_l[:, :, :2], Fl[:, :2])
        + np.einsum("npi,ni->np", dFt_r[:, :, :2], Ftr[:, :2])
    )
    return errors, d_algebraic / root[:, None] - 0.5 * (errors / denom)[:, None] * d_denom


def essential_pose(matches: Matches, K_left: np.ndarray, K_right: np.ndarray, conf: dict | None = None):
    """R, unit t and the inlier mask from matches via MAGSAC and the cheirality check, or None.

    MAGSAC now and then returns an essential matrix that its own inliers do not fit (OpenCV 5 on one
    Middlebury pair: a median epipolar error of 6 px over inliers taken at 1 px). The median error of those
    inliers then becomes the fusion's noise scale, and a noise 20 times too large widens the pose's sigmas
    as much. Where the inliers' median error is over twice the threshold, or MAGSAC gives no pose, plain
    RANSAC is run too and the matrix that more matches fit within the threshold is kept (conf
    ``essential_second_opinion``; off, this is OpenCV's findEssentialMat + recoverPose and nothing else).
    """
    conf = resolve(default_conf, conf)
    if len(matches) < 5:
        return None
    nl, nr = _normalise(matches.left, K_left), _normalise(matches.right, K_right)
    focal = 0.5 * (K_left[0, 0] + K_right[0, 0])
    threshold_px = conf["ransac_threshold_px"]
    best = None
    methods = (cv2.USAC_MAGSAC, cv2.RANSAC) if conf["essential_second_opinion"] else (cv2.USAC_MAGSAC,)
    for method in methods:
        E, mask = cv2.findEssentialMat(
            nl, nr, np.eye(3), method=method, prob=conf["ransac_confidence"], threshold=threshold_px / focal
        )
        if E is None or E.shape != (3, 3) or mask is None:
            continue
        # distanceThresh: with short baselines most points lie far away in units of |t|; keep them all
        count, R, t, pose_mask, _ = cv2.recoverPose(
            E, nl, nr, np.eye(3), distanceThresh=1e9, mask=mask.copy()
        )
        inliers = (pose_mask.ravel() > 0) & (mask.ravel() > 0)
        if count < 5:
            continue
        t = t.ravel() / np.linalg.norm(t)
        F = fundamental_matrix(K_left, K_right, R, t)
        errors = np.abs(sampson_errors(F, matches.left, matches.right))
        support = int(np.sum(errors < threshold_px))
        if best is None or support > best[0]:
            best = (support, R, t, inliers)
        if np.median(errors[inliers]) <= 2.0 * threshold_px:
            break  # the matrix fits its own inliers: no second opinion needed
    return None if best is None else best[1:]


def _pull_towards_gravity(R, gravity_left, gravity_right, gravity_sigma, conf) -> np.ndarray:
    """The pose head's rotation moved towards agreement with gravity, as far as the two sigmas say.

    The full move (``couple_rotation_to_gravity``) makes R·g_left = g_right; with both uncertain, the
    inverse-variance share of it is taken: σ_head² / (σ_head² + σ_gravity²).
    """
    sigma_head = np.radians(conf["prior_rotation_sigma_deg"])
    share = sigma_head**2 / (sigma_head**2 + gravity_sigma**2)
    coupled = couple_rotation_to_gravity(R, gravity_left, gravity_right)
    return rotation_from_axis_angle(share * axis_angle_from_rotation(coupled @ R.T)) @ R


def _gravity_error_deg(R, gravity_left, gravity_right) -> float:
    return float(np.degrees(gravity_angle(R @ gravity_left, gravity_right)))


def _rotation_residual(R: np.ndarray, R_ref: np.ndarray) -> np.ndarray:
    return axis_angle_from_rotation(R @ R_ref.T)


def _log_jacobian(phi: np.ndarray) -> np.ndarray:
    """∂ log(exp([δ]ₓ)·Q) / ∂δ at δ = 0 for Q = exp([φ]ₓ): the inverse left Jacobian of SO(3),
    I − ½[φ]ₓ + (1/θ² − (1 + cos θ) / (2θ sin θ))·[φ]ₓ²."""
    theta = float(np.linalg.norm(phi))
    P = skew(phi)
    if theta < 1e-6:
        return np.eye(3) - 0.5 * P + P @ P / 12.0
    c = 1.0 / theta**2 - (1.0 + np.cos(theta)) / (2.0 * theta * np.sin(theta))
    return np.eye(3) - 0.5 * P + c * (P @ P)


def fuse_relative_pose(
    matches: Matches,
    K_left: np.ndarray,
    K_right: np.ndarray,
    *,
    gravity_left: np.ndarray | None = None,
    gravity_right: np.ndarray | None = None,
    gravity_sigma_rad: float | None = None,
    prior_R: np.ndarray | None = None,
    prior_t: np.ndarray | None = None,
    focal_sigma_rel: tuple[float | None, float | None] = (None, None),
    common_focal_sigma_rel: float | None = None,
    distortion_evidence: tuple[tuple[float, float] | None, tuple[float, float] | None] = (None, None),
    lens_seen: tuple[bool, bool] = (False, False),
    conf: dict | None = None,
    again: FusionStart | None = None,
) -> RelativePose:
    """Relative pose from matches, gravity and the pose head, each weighted by its uncertainty.

    Args:
        matches: pixel matches in the two images (undistorted pixels).
        K_left, K_right: [3 x 3] intrinsics (the refined ones).
        gravity_left, gravity_right: up vectors [3] of each camera, with ``gravity_sigma_rad`` the 1-sigma
            of the angle between R·g_left and g_right expected from their errors (both cameras').
        prior_R, prior_t: the pose head's rotation [3 x 3] and translation [3] (any scale), or None.
        focal_sigma_rel: the relative 1-sigma of each camera's focal length in K (None: known, held).
            The ratio of the two focals is refined with the pose, each camera taking a share of the
            correction in proportion to its variance; ``focal_scale`` in the result says how far each moved.
        common_focal_sigma_rel: the relative 1-sigma of both focal lengths together (how far the fields' read
            of the camera can be off, a camera's bias included), or None. Given, and with both focal lengths
            free, their common scale is refined with the pose too: the matches of a rig whose cameras turn
            against each other see it (a rotation maps the rays of one camera onto the other's pixels through
            both focal lengths); on a near-parallel rig they do not, and it stays at the fields' read.
        distortion_evidence: per camera, a (k, 1-sigma) of its division-model k in the normalised coordinates
            of its K read from other evidence (the image's straight edges, ``refine/plumb.py``), or None.
            It weighs in the test of whether a lens is fitted at all (a chi-square of how much better it
            likes the fitted k than none); the k itself is the matches'.
        lens_seen: per camera, whether that evidence shows a lens beyond doubt: a raw camera, whose principal
            point widens the pose's sigmas as where a lens is fitted, even where the matches fit none.
        again: the ``start`` of an earlier fusion of the same matches (with other K): one refinement from
            its pose, on its inliers, with its choices (:class:`FusionStart`), instead of the essential
            matrix, the starts and the tests; on a turned rig all of them, with its verdict on the rig.
    Returns:
        A :class:`RelativePose`. With enough matches: the essential-matrix pose refined on its inliers
        (robust Sampson error) with soft gravity coupling (R·g_left = g_right) and the pose head as a
        prior. Otherwise the pose head, rotated by the least amount that makes it agree with gravity.
    """
    conf = resolve(default_conf, conf)
    has_gravity = gravity_left is not None and gravity_right is not None and gravity_sigma_rad
    given = _Given(
        matches, K_left, K_right, gravity_left if has_gravity else None, gravity_right, gravity_sigma_rad,
        prior_R, prior_t, focal_sigma_rel, common_focal_sigma_rel, distortion_evidence, lens_seen, conf,
    )  # fmt: skip
    verdict = None  # a turned rig's: the full fusion again, its verdict on the rig kept (FusionStart)
    if again is not None and again.turned:
        verdict, again = again, None
    initial = _initial_pose(given, again)
    # (a fusion ``again`` keeps the first one's verdict: its refined inliers may be fewer than RANSAC's)
    if initial is None or (again is None and initial[2].sum() < conf["min_inliers"]):
        inliers = 0 if initial is None else int(initial[2].sum())
        return _pose_head_alone(
            matches, inliers, prior_R, prior_t, given.gravity_left, gravity_right, gravity_sigma_rad, conf,
            (K_left, K_right),
        )  # fmt: skip
    return _fuse_matches(given, initial, again, verdict)


@dataclass
class _Given:
    """What :func:`fuse_relative_pose` is given: the matches and the two K, gravity (``gravity_left`` None:
    no gravity coupling), the pose head's R and t, the focal lengths' relative 1-sigmas, the other evidence
    of the lenses and the conf (its arguments of the same names)."""

    matches: Matches
    K_left: np.ndarray
    K_right: np.ndarray
    gravity_left: np.ndarray | None
    gravity_right: np.ndarray | None
    gravity_sigma: float | None
    prior_R: np.ndarray | None
    prior_t: np.ndarray | None
    focal_sigma_rel: tuple[float | None, float | None]
    common_focal_sigma_rel: float | None
    distortion_evidence: tuple[tuple[float, float] | None, tuple[float, float] | None]
    lens_seen: tuple[bool, bool]
    conf: dict


def _initial_pose(given: _Given, again: FusionStart | None):
    """Where the fusion starts: the pose (R, unit t) and inlier mask of an earlier fusion (``again``), else
    the essential matrix's (:func:`essential_pose`); None where there are too few matches or no pose."""
    if again is not None:
        return again.R, again.t, again.mask
    if len(given.matches) >= given.conf["min_matches"]:
        return essential_pose(given.matches, given.K_left, given.K_right, given.conf)
    return None


def _fuse_matches(given: _Given, initial, again: FusionStart | None, verdict: FusionStart | None):
    """The pose from enough matches, starting from ``initial`` (R, t, inlier mask): whether the rig is
    turned and the pose head left out (an earlier fusion's ``verdict``, or ``again``'s, or the matches'),
    then the chosen fit (``again``: with an earlier fusion's choices), or two views from one centre where a
    rotation explains the matches better."""
    conf, (R0, t0, mask0) = given.conf, initial
    split, scale_sigma, common = _focal_split(given.focal_sigma_rel, given.common_focal_sigma_rel)
    R_p = _head_rotation(given)
    noise = _match_noise(given, R0, t0, mask0) if again is None else again.noise_px
    with_head = _head_priors(given)
    without_head = replace(with_head, R=None, t=None)
    notes: list[str] = []
    if verdict is not None or again is not None:
        turned, head_out = _earlier_verdict(verdict, again, notes)
    else:
        joints = (
            _joint(given, noise, without_head, common, scale_sigma),
            _joint(given, noise, with_head, None, scale_sigma),
        )
        turned, head_out = _turned_rig(joints, R0, t0, mask0, R_p, split, conf, notes)
    common = common if turned else None
    priors = without_head if head_out else with_head
    found, has_gravity = len(given.matches), given.gravity_left is not None
    if again is not None and again.one_centre:
        return _one_centre(
            given.matches, given.K_left, given.K_right, noise, R0, priors, given.focal_sigma_rel,
            given.common_focal_sigma_rel, conf, found, has_gravity, head_out,
        )  # fmt: skip
    joint = _joint(given, noise, priors, common, scale_sigma)
    if again is None:
        best, used_split, k_bounds = _choose(
            joint, R0, t0, mask0, R_p, priors.R, priors.t, split, given.distortion_evidence
        )
    else:
        best, used_split, k_bounds = _fit_again(joint, again, R0, t0, mask0, split)
    raw = k_bounds is not None or any(given.lens_seen)
    pose = _pose_from_fit(joint, best, used_split, k_bounds, given.focal_sigma_rel, raw)
    if again is None and conf["one_centre"]:
        one = _rotation_if_better(given, best, used_split, common, k_bounds, priors, head_out)
        if one is not None:
            return one
    pose.matches_found, pose.turned, pose.notes = found, turned, notes
    pose.equal_focals = used_split is not split
    pose.start = FusionStart(
        pose.R, pose.t_direction, best.mask, turned, head_out, k_bounds is not None, pose.equal_focals,
        tuple(notes), pose.distortion,
        (float(given.K_left[1, 1] * pose.focal_scale[0]), float(given.K_right[1, 1] * pose.focal_scale[1])),
        noise,
    )  # fmt: skip
    if has_gravity:
        pose.gravity_error_deg = _gravity_error_deg(pose.R, given.gravity_left, given.gravity_right)
    return pose


def _focal_split(focal_sigma_rel, common_focal_sigma_rel) -> tuple[_Split | None, float, float | None]:
    """How the fit treats the two focal lengths: the :class:`_Split` of a correction of their ratio (None:
    both held), the relative 1-sigma of their common scale where the fit holds it (0: known), and the
    common scale's 1-sigma where the fit may refine it (on a turned rig; None: held)."""
    # The ratio of the two focal lengths is refined with the pose: the matches fix it well on any rig, while
    # the absolute focal is unobservable on near-parallel rigs and absorbs lens distortion (its common scale
    # is refined only on a turned rig: _turned_rig).
    var = [0.0 if (v is None or not np.isfinite(v) or v <= 0) else float(v) ** 2 for v in focal_sigma_rel]
    split = None if sum(var) <= 0 else _Split(var[0] / sum(var), var[1] / sum(var), float(np.sqrt(sum(var))))
    # how far the common scale of two free focal lengths, held in the fit, can be off: the images' read with
    # the camera bias where given (the sign of t takes it in: _Joint.signed)
    scale_sigma = 0.0 if min(var) <= 0 else common_focal_sigma_rel or float(np.mean(np.sqrt(var)))
    common = None
    if split is not None and all(v > 0 for v in var) and common_focal_sigma_rel:
        common = float(common_focal_sigma_rel)
    return split, scale_sigma, common


def _head_rotation(given: _Given) -> np.ndarray | None:
    """The pose head's rotation made consistent with gravity (as given without gravity; None: no head)."""
    if given.prior_R is None:
        return None
    if given.gravity_left is None:
        return given.prior_R
    return couple_rotation_to_gravity(given.prior_R, given.gravity_left, given.gravity_right)


def _match_noise(given: _Given, R0, t0, mask0) -> float:
    """The scale of the match noise (pixels): the robust spread (1.4826 × the median absolute value) of the
    Sampson errors of the inliers ``mask0`` under the pose (R0, t0), at least ``min_noise_px``."""
    F = fundamental_matrix(given.K_left, given.K_right, R0, t0)
    errors0 = sampson_errors(F, given.matches.left, given.matches.right)
    return max(1.4826 * float(np.median(np.abs(errors0[mask0]))), given.conf["min_noise_px"])


def _head_priors(given: _Given) -> _Priors:
    """The priors of the joint refinement with the pose head: gravity coupling, the head's rotation and
    translation direction with their conf sigmas."""
    conf = given.conf
    sigmas = np.radians(conf["prior_rotation_sigma_deg"]), np.radians(conf["prior_direction_sigma_deg"])
    return _Priors(
        given.gravity_left, given.gravity_right, given.gravity_sigma, given.prior_R, given.prior_t, *sigmas
    )


def _joint(given: _Given, noise: float, priors: _Priors, common: float | None, scale_sigma: float) -> _Joint:
    """The joint refinement of the given matches at the match ``noise``, with these priors."""
    return _Joint(
        given.matches, given.K_left, given.K_right, noise, priors, common, given.prior_t, given.conf,
        scale_sigma,
    )  # fmt: skip


def _earlier_verdict(verdict: FusionStart | None, again: FusionStart | None, notes: list[str]):
    """Whether the rig is turned and whether the pose head is left out, as an earlier fusion decided: a
    turned rig's ``verdict`` (turned), else ``again``'s; its notes are added to ``notes``."""
    if verdict is not None:
        notes.extend(verdict.notes)
        return True, verdict.head_out
    notes.extend(again.notes)
    return again.turned, again.head_out


def _rotation_if_better(given: _Given, best: _Fit, used_split, common, k_bounds, priors, head_out: bool):
    """The pair as two views from one centre (:func:`_one_centre`) where a rotation explains its matches
    better than the chosen fit's refined essential matrix (by GRIC), else None."""
    conf = given.conf
    # the rotation and the refined essential matrix compared at the noise of the more general model, the
    # refined essential matrix's (the raw one's can be far too wide), and not at the fusion's floor: a far
    # scene's parallax can lie below the floor and still tell a rig from a rotation
    sampson_noise = max(
        1.4826 * float(np.median(np.abs(best.errors[best.mask]))), conf["one_centre_min_noise_px"]
    )
    params = 5 + (used_split is not None) + (common is not None) + 2 * (k_bounds is not None)
    gric_essential = essential_gric(best.errors, sampson_noise, params, conf["one_centre_conf"])
    return _one_centre(
        given.matches, given.K_left, given.K_right, sampson_noise, best.state.R, priors,
        given.focal_sigma_rel, given.common_focal_sigma_rel, conf, len(given.matches),
        given.gravity_left is not None, head_out, gric_essential,
    )  # fmt: skip


def _one_centre(
    matches,
    K_left,
    K_right,
    noise,
    R_start,
    priors,
    focal_sigma_rel,
    common,
    conf,
    found,
    has_gravity,
    head_out,
    gric_essential: float | None = None,
) -> RelativePose | None:
    """The pair as two views from one centre (``fuse/one_centre.py``) where a rotation explains its matches
    better than the essential matrix does (a lower GRIC than ``gric_essential``; None: an earlier fusion
    decided so), else None. Its t is the pose head's (the matches see no baseline), with the prior's sigma."""
    held = tuple(v is None or not np.isfinite(v) or v <= 0 for v in focal_sigma_rel)
    own = np.array([0.0 if h else float(v) for v, h in zip(focal_sigma_rel, held, strict=True)])
    cov = np.diag(own**2)
    if common and not any(held):  # the fields' bias on the camera, common to both reads
        cov += max(common**2 - own.mean() ** 2, 0.0)
    rotation_priors = _Priors(
        priors.gravity_left, priors.gravity_right, priors.gravity_sigma, priors.R, None,
        priors.rotation_sigma, priors.direction_sigma,
    )  # fmt: skip
    fit = fit_rotation(
        matches, K_left, K_right, noise, R_start, lambda R: rotation_priors.residuals(R, None), cov, held,
        conf["principal_point_sigma"], conf["min_noise_px"], conf["one_centre_conf"],
    )  # fmt: skip
    if gric_essential is not None and fit.gric >= gric_essential:
        return None
    t = np.array([-1.0, 0.0, 0.0]) if priors.t is None else np.asarray(priors.t, float)
    scales = np.exp(fit.log_scales)
    sigmas = np.sqrt(np.diag(fit.scale_cov))
    free = [float(s) for s, h in zip(sigmas, held, strict=True) if not h]
    turn = math.degrees(rotation_angle(fit.R))
    pose = RelativePose(
        R=fit.R, t_direction=t / np.linalg.norm(t), source="rotation", matches_found=found,
        inliers=int(fit.inliers.sum()),
        sigma_rotation_deg=float(np.degrees(np.sqrt(np.trace(fit.rotation_cov)))),
        sigma_direction_deg=float(conf["prior_direction_sigma_deg"]),
        focal_scale=(float(scales[0]), float(scales[1])),
        focal_read_sigma_rel=tuple(
            None if h or not r <= 1.0 else float(r) for r, h in zip(fit.read_sigma, held, strict=True)
        ),  # (over 1 in log f, a factor e: it reads nothing)
        sigma_focal_considered=float(np.mean(free)) if free else 0.0,
        notes=[
            f"the matches are explained by a rotation alone ({turn:.1f}°): two views from one centre, or a "
            "scene too far for the baseline to show; t is the pose head's"
        ],
    )  # fmt: skip
    pose.start = FusionStart(
        pose.R, pose.t_direction, fit.inliers, False, head_out, False, False, (), (0.0, 0.0),
        (float(K_left[1, 1] * scales[0]), float(K_right[1, 1] * scales[1])), noise, one_centre=True,
    )  # fmt: skip
    if has_gravity:
        pose.gravity_error_deg = _gravity_error_deg(pose.R, priors.gravity_left, priors.gravity_right)
    return pose


def _choose(joint: _Joint, R0, t0, mask0, R_p, head_R, head_t, split, distortion_evidence):
    """The fusion's choices on its matches: the best of its starts, whether a lens is fitted and whether the
    two focal lengths are held equal. Returns the chosen fit, its split and its k bounds (None: no lens)."""
    starts = [(R0, t0)] if head_R is None or head_t is None else _starts(R0, t0, R_p, head_t)
    fits = [joint.fit(_State(R, t, 0.0, 0.0, (0.0, 0.0)), mask0, None, split) for R, t in starts]
    if head_R is not None and head_t is not None and joint.conf["head_direction_held"]:
        held = _head_direction_held(joint, R_p, head_t, mask0, split)
        fits += [] if held is None else [held]
    best = min(fits, key=lambda candidate: candidate.score)
    k_bounds = _distortion_bounds(joint.K_left, joint.K_right, joint.conf)
    radial = k_bounds is not None and _lens_shows(joint, best, split, k_bounds, distortion_evidence)
    if radial:
        best = joint.fit(best.state, best.mask, k_bounds, split)
    k_bounds = k_bounds if radial else None
    best, used_split = _held_equal_focals(joint, best, split, k_bounds)
    return best, used_split, k_bounds


def _fit_again(joint: _Joint, again: FusionStart, R0, t0, mask0, split):
    """A fusion ``again``: one fit from the earlier fusion's pose and inliers, with its choices (a lens or
    none, equal focal lengths or not) and its lens carried into the given K's normalised coordinates.
    Returns the fit, its split and its k bounds (None: no lens)."""
    K_left, K_right = joint.K_left, joint.K_right
    k_bounds = _distortion_bounds(K_left, K_right, joint.conf) if again.radial else None
    equal = again.equal and split is not None
    used_split, d = _equal_split(split, K_left, K_right) if equal else (split, 0.0)
    k = (0.0, 0.0)
    if k_bounds is not None:  # the first fusion's lens, in the given K's normalised coordinates
        k = tuple(
            float(np.clip(again.k[i] * (K[1, 1] / again.focal_px[i]) ** 2, *k_bounds[i]))
            for i, K in enumerate((K_left, K_right))
        )
    best = joint.fit(_State(R0, t0, d, 0.0, k), mask0, k_bounds, used_split, keep_k=True)
    return best, used_split, k_bounds


def _head_direction_held(joint: _Joint, R_p, t_p, mask0, split) -> _Fit | None:
    """A candidate fit with T's direction held at the pose head's (its prior made a constraint) and R
    refined from the head's, made consistent with gravity (``R_p``); None where it goes astray.

    On a short rig before a far scene the matches leave T's direction in a long, shallow valley: released
    from the head's direction, the refinement slides down the Huber cost to wherever the matches' small
    systematic errors lead it (a rendered street: 80° from the truth), while their capped robust cost, the
    fits' score, likes the head's direction better. Its covariance is the free problem's at the held
    solution (the constraint is not knowledge)."""
    t_p = np.asarray(t_p, dtype=float) / np.linalg.norm(t_p)
    held = replace(joint, priors=replace(joint.priors, t=t_p, direction_sigma=1e-5))
    fit = held.fit(_State(R_p, t_p, 0.0, 0.0, (0.0, 0.0)), mask0, None, split)
    hessian = joint.problem(fit.mask, split, None).hessian(fit.state)
    if not (np.isfinite(fit.score) and np.all(np.isfinite(hessian))):
        return None
    return replace(fit, hessian=lambda: hessian)


def _starts(R0, t0, R_p, t_p) -> list[tuple[np.ndarray, np.ndarray]]:
    """Where the joint refinement starts. Short baselines leave a valley of near-equal epipolar error between
    rotation and translation: it is refined from the essential matrix (R0, t0) and from the pose head (made
    consistent with gravity: R_p, t_p), and the best is kept; the second start only where it could lead
    elsewhere."""
    t_p = np.asarray(t_p, dtype=float) / np.linalg.norm(t_p)
    if rotation_error(R_p, R0) > np.radians(0.5) or np.degrees(gravity_angle(t_p, t0)) > 5.0:
        return [(R0, t0), (R_p, t_p)]
    return [(R0, t0)]


@dataclass
class _Joint:
    """The joint refinement's fixed inputs: the matches, the given K, the match noise (pixels), the priors,
    the common focal scale's sigma (None: not refined), the pose head's t (its sign of t) and the relative
    1-sigma of the two focal lengths' common scale where it is held (0: known)."""

    matches: Matches
    K_left: np.ndarray
    K_right: np.ndarray
    noise: float
    priors: _Priors
    common: float | None
    prior_t: np.ndarray | None
    conf: dict
    focal_sigma: float = 0.0

    def signed(self, state: _State, hessian, mask, split, k_bounds, left, right, K_left, K_right):
        """The fit's t [3] with its sign, and what decided it ("matches" or "pose_head"): the epipolar error
        cannot tell t from -t, the points must lie in front of both cameras (``left``, ``right``: the
        inliers, undistorted, seen through ``K_left``, ``K_right``).

        A point says so only where its two rays meet at an angle that no rotation within the fit's
        uncertainty could close: on a short rig before a far scene, the turn across the baseline and the
        parallax trade against each other, and the matches read that turn through the focal lengths, so its
        uncertainty takes in their common scale (``focal_sigma``; a focal length read 1.6× off turned a 20 cm
        rig's R far enough to put every point behind). Points that disagree say nothing either. Where the
        points do not decide (a far scene), the pose head's sign is taken: the head learnt rigs whose right
        camera is on the right, as the file names say."""
        conf = self.conf
        sigma = self._rotation_sigma(state, hessian, mask, split, k_bounds)
        min_parallax = max(np.radians(conf["sign_min_parallax_deg"]), conf["sign_rotation_sigmas"] * sigma)
        share, count = _in_front_share(state.R, state.t, left, right, K_left, K_right, min_parallax)
        decided = count >= conf["sign_min_points"] and abs(share - 0.5) >= conf["sign_min_share"] - 0.5
        if not decided and self.prior_t is not None:
            return (state.t if state.t @ self.prior_t >= 0 else -state.t), "pose_head"
        return (state.t if share >= 0.5 else -state.t), "matches"

    def _rotation_sigma(self, state: _State, hessian, mask, split, k_bounds) -> float:
        """The rotation's largest 1-sigma (radians) at a fit: its Hessian's, and where the two focal lengths'
        common scale is held, what its uncertainty adds (infinite where the Hessian tells nothing: singular,
        or not finite at a fit gone astray)."""
        try:
            cov = np.linalg.inv(hessian())
            if self.common is None and self.focal_sigma > 0:
                focal = {"focal": self.focal_sigma}
                cov = cov + _consider_covariance(self, state, mask, split, k_bounds, focal)
            if not np.all(np.isfinite(cov[:3, :3])):
                return float("inf")
            return float(np.sqrt(max(float(np.linalg.eigvalsh(cov[:3, :3]).max()), 0.0)))
        except np.linalg.LinAlgError:
            return float("inf")

    def refine(self, state: _State, mask, split, k_bounds):
        """:func:`_refine_pose` on the matches of ``mask``."""
        return _refine_pose(
            state, self.matches.left[mask], self.matches.right[mask], self.K_left, self.K_right, self.noise,
            self.priors, split, k_bounds, self.conf, self.common,
        )  # fmt: skip

    def problem(self, mask, split, k_bounds, K_left=None, K_right=None) -> _PoseProblem:
        """The residuals of the matches of ``mask`` (with other K where given)."""
        return _PoseProblem(
            self.matches.left[mask], self.matches.right[mask],
            self.K_left if K_left is None else K_left, self.K_right if K_right is None else K_right,
            self.noise, self.priors, split, k_bounds, self.conf, self.common,
        )  # fmt: skip

    def fit(self, start: _State, mask, k_bounds, split, keep_k: bool = False) -> _Fit:
        """Two rounds from ``start`` (its k at 0 unless ``keep_k``): refine on the inliers, re-select the
        inliers among all matches, refine again; then the sign of t and the fit's robust score over all
        matches."""
        conf, noise, matches = self.conf, self.noise, self.matches
        state = start if keep_k else start._replace(k=(0.0, 0.0))
        for _ in range(2):
            state, hessian, scales, _ = self.refine(state, mask, split, k_bounds)
            R, t, d, c, k = state
            K_l, K_r = _scaled(self.K_left, scales[0]), _scaled(self.K_right, scales[1])
            left = undistort_division(matches.left, self.K_left, k[0])
            right = undistort_division(matches.right, self.K_right, k[1])
            errors = sampson_errors(fundamental_matrix(K_l, K_r, R, t), left, right)
            mask = np.abs(errors) < max(3.0 * noise, conf["ransac_threshold_px"])
        t, sign_source = self.signed(state, hessian, mask, split, k_bounds, left[mask], right[mask], K_l, K_r)
        focal_terms = 0.0 if split is None else ((d - split.d0) / split.sigma) ** 2
        focal_terms += 0.0 if self.common is None else (c / self.common) ** 2
        k_terms = (k[0] ** 2 + k[1] ** 2) / conf["distortion_sigma"] ** 2
        priors = float(np.sum(self.priors.residuals(R, t) ** 2))
        score = _robust_cost(errors, noise) + priors + focal_terms + k_terms
        return _Fit(score, _State(R, t, d, c, k), scales, hessian, mask, errors, sign_source)


def _distortion_bounds(K_left, K_right, conf) -> tuple | None:
    """The (lower, upper) limits of each camera's division-model k, or None where no lens is fitted.

    Radial distortion bends the epipolar lines (on a stereo rig: vertical disparity growing towards the
    corners), which no pinhole pose explains; one division-model k per camera, held near 0 by a prior where
    the matches do not show it. Bounded below so the model does not fold over inside the image, and above by
    ``distortion_max_pincushion`` (default 0, barrel only): pincushion is rare and mild in real lenses, while
    a free k on few or clustered matches drifted there on undistorted test pairs.
    """
    if not conf["distortion"]:
        return None
    corners = (corner_radius(K_left), corner_radius(K_right))
    return tuple((division_limit(r), conf["distortion_max_pincushion"] / r**2) for r in corners)


def _lens_shows(joint: _Joint, best: _Fit, split, k_bounds, distortion_evidence) -> bool:
    """Whether a lens is fitted: a nested test on the pinhole fit's inliers. Re-refined as a pinhole and with
    the two k free, from the same solution, the robust cost must fall by more than noise would let two extra
    parameters take (few or clustered matches let k absorb outliers or a scene's ambiguity). Evidence of the
    lens from elsewhere (the images' straight edges) counts in the test: the matches of a short rig may bend
    too little on their own where the edges show the lens plainly."""
    if best.mask.sum() < joint.conf["distortion_min_inliers"]:
        return False
    start = best.state._replace(k=(0.0, 0.0))
    pinhole, _, _, pinhole_cost = joint.refine(start, best.mask, split, None)
    radial_fit, _, _, radial_cost = joint.refine(pinhole, best.mask, split, k_bounds)
    gain = pinhole_cost + _lens_evidence(radial_fit.k, distortion_evidence) - radial_cost
    return gain > joint.conf["distortion_min_gain"]


def _held_equal_focals(joint: _Joint, best: _Fit, split, k_bounds) -> tuple[_Fit, tuple | None]:
    """The fit, and the split it used: ``split`` itself, or one that holds the two focal lengths equal.

    Most rigs pair two identical cameras. Where the matches cannot tell the focal ratio from 1 (it trades
    against a forward component of t on a rig looking ahead), both focal lengths are held equal: the same
    nested test as the lens', one parameter fewer. The equal pose pays the fields' own evidence of a ratio.
    (Only for two images of one size: focal lengths in pixels of different sizes are not alike.)
    """
    K_left, K_right = joint.K_left, joint.K_right
    same_size = np.allclose(K_left[:2, 2], K_right[:2, 2])
    if split is None or not same_size or joint.conf["equal_focal_max_gain"] <= 0:
        return best, split
    held, d_equal = _equal_split(split, K_left, K_right)
    equal = joint.fit(best.state._replace(d=d_equal), best.mask, k_bounds, held)
    if equal.score + (d_equal / split.sigma) ** 2 - best.score < joint.conf["equal_focal_max_gain"]:
        return equal, held
    return best, split


def _equal_split(split: _Split, K_left, K_right) -> tuple[_Split, float]:
    """``split`` holding the two focal lengths equal, and the ratio d that makes them so."""
    d_equal = float(np.log(K_right[1, 1] / K_left[1, 1]))  # f_l·exp(w_l·d) = f_r·exp(-w_r·d)
    return split._replace(sigma=1e-6, d0=d_equal), d_equal


def _pose_from_fit(joint: _Joint, best: _Fit, split, k_bounds, focal_sigma_rel, raw: bool) -> RelativePose:
    """The pose of the chosen fit with its covariance: the Hessian's, plus what the matches cannot see,
    which widens the pose's covariance without moving it: the two cameras' common focal scale (the fields'
    sigma; held focal lengths have none; a common scale that was refined is in the Hessian already) and, for
    ``raw`` cameras (a lens fitted, ``k_bounds``, or seen in the images' straight edges), the principal
    points, which the camera model puts at the image centres."""
    (R, t, _, _, k), scales = best.state, best.scales
    cov = np.linalg.inv(best.hessian())
    sigma_common = None
    if joint.common is not None:  # c sits after the rotation (3), the direction (2) and the ratio d
        sigma_common = _with_common_scale_as_read(cov, 6, joint.common)
    known = [v is None or not np.isfinite(v) or v <= 0 for v in focal_sigma_rel]
    considered = {
        "focal": 0.0 if any(known) or joint.common else 0.5 * float(focal_sigma_rel[0] + focal_sigma_rel[1])
    }
    if raw:
        considered["principal_point"] = joint.conf["principal_point_sigma"]
    cov = cov + _consider_covariance(joint, best.state, best.mask, split, k_bounds, considered)
    distortion, sigma_distortion = (0.0, 0.0), (float("inf"), float("inf"))
    if k_bounds is not None:
        # k in the refined K's normalised coordinates: r' = r·f/f', so k' = k·(f'/f)²
        grow = (np.exp(2 * scales[0]), np.exp(2 * scales[1]))
        distortion = (float(k[0] * grow[0]), float(k[1] * grow[1]))
        sigma_distortion = (float(np.sqrt(cov[-2, -2]) * grow[0]), float(np.sqrt(cov[-1, -1]) * grow[1]))
    return RelativePose(
        R=R, t_direction=t, source="matches", inliers=int(best.mask.sum()), sign_source=best.sign_source,
        sigma_rotation_deg=float(np.degrees(np.sqrt(np.trace(cov[:3, :3])))),
        sigma_direction_deg=float(np.degrees(np.sqrt(np.trace(cov[3:5, 3:5])))),
        focal_scale=(float(np.exp(scales[0])), float(np.exp(scales[1]))),
        sigma_common_focal=sigma_common,
        sigma_focal_considered=considered["focal"] if joint.common is None else joint.common,
        distortion=distortion, sigma_distortion=sigma_distortion,
    )  # fmt: skip


def _with_common_scale_as_read(cov: np.ndarray, i: int, sigma: float) -> float:
    """A turned rig's covariance (changed in place) with the variance of its common focal scale (parameter
    ``i``) raised to ``sigma``², the images' read with the camera bias: the matches of such a rig lie in a
    narrow strip at the inner image edges, and their 1-sigma of the scale is far narrower than its errors
    (docs/refine.md, "Turned rigs"). Every parameter moves with the scale by its regression on it,
    cov[:, i] / cov[i, i], and takes in that share of the extra variance (Gaussian conditioning: the rest
    of the covariance is what the matches tell for a given scale). Returns the matches' own 1-sigma of it."""
    variance = float(cov[i, i])
    if np.isfinite(variance) and 0 < variance < sigma**2:
        slope = cov[:, i] / variance
        cov += np.outer(slope, slope) * (sigma**2 - variance)
    return float(np.sqrt(variance))


def _pose_head_alone(
    matches, inliers, prior_R, prior_t, gravity_left, gravity_right, gravity_sigma_rad, conf, Ks
) -> RelativePose:
    """Too few matches for the relative pose: the pose head's, rotated by the least amount that makes it
    agree with gravity (``gravity_left`` None: no gravity).

    Where both images are textured (``unshared_min_features``) and still match too little, the two cameras
    see different parts of the scene: a rig whose cameras look apart (a car's surround cameras), unlike the
    near-parallel rigs the pose head learnt, whose R it reads tens of degrees off (a car's back and back-left
    cameras, 71° apart: 71° off). Its sigma then is the cameras' mean horizontal field of view (``Ks``, the
    principal points at the image centres), about how far apart two cameras that share no view must look."""
    if prior_R is None or prior_t is None:
        raise ValueError("too few matches for the relative pose and no pose-head prior to fall back on")
    found = len(matches)
    notes = [f"too few matches ({found} found, {inliers} inliers): pose from the pose head and gravity"]
    sigma_rotation = float(conf["prior_rotation_sigma_deg"])
    if min(matches.features) >= conf["unshared_min_features"]:
        fov = np.degrees(np.mean([vfov_from_focal(K[0, 0], 2.0 * K[0, 2]) for K in Ks]))  # horizontal
        sigma_rotation = max(sigma_rotation, float(fov))
        notes.append(
            f"the two views share almost nothing ({found} of {min(matches.features)} features match): the "
            f"cameras may look apart, unlike the rigs the pose head learnt, and its R is a guess "
            f"(± {sigma_rotation:.0f}°)"
        )
    has_gravity = gravity_left is not None
    R = (
        _pull_towards_gravity(prior_R, gravity_left, gravity_right, gravity_sigma_rad, conf)
        if has_gravity
        else prior_R
    )
    t = np.asarray(prior_t, dtype=float)
    return RelativePose(
        R=R, t_direction=t / np.linalg.norm(t), source="pose_head", matches_found=found, inliers=inliers,
        sigma_rotation_deg=sigma_rotation,
        sigma_direction_deg=float(conf["prior_direction_sigma_deg"]),
        gravity_error_deg=_gravity_error_deg(R, gravity_left, gravity_right) if has_gravity else None,
        notes=notes,
    )  # fmt: skip


def _turned_rig(joints, R0, t0, mask0, head_R, split, conf, notes: list[str]) -> tuple[bool, bool]:
    """Whether the rig is turned, and whether the pose head is left out (with a note in ``notes``).

    A turned rig: its cameras turn tens of degrees apart. The two focal lengths' common scale shows in its
    matches (a rotation maps one camera's rays onto the other's pixels through both), and is refined with
    the pose there; on a near-parallel rig the epipolar geometry does not depend on it, and a free scale
    drifts with the noise and the priors. The pose head learnt rigs whose cameras turn a few degrees at
    most, and its sigmas hold there; on a turned rig that it reads (``head_R``, made consistent with
    gravity) far from the matches, its prior would pull the pose (and the focal lengths with it) towards a
    rig it knows: it is left out.

    The matches decide, each fitted twice: without the pose head (``joints[0]``: gravity and the common
    scale) from the essential matrix (R0, t0), and with it (``joints[1]``) from its best start. The rig is
    turned where the first fit turns the cameras ``turned_rig_deg`` apart and the head cannot bring them
    back: the second fit turns them as far, or the matches fit it worse by ``turned_rig_min_gain`` (their
    robust cost in noise² units; a rig the head reads right fits as well near it). So a few inliers in the
    narrow strip two turned cameras share can reject the head, and an essential matrix turned by a wrong
    focal length or a near-degenerate scene cannot.
    """
    if float(np.degrees(rotation_angle(R0))) < conf["turned_rig_deg"]:
        return False, False
    alone, kept = joints
    free = alone.fit(_State(R0, t0, 0.0, 0.0, (0.0, 0.0)), mask0, None, split)
    if float(np.degrees(rotation_angle(free.state.R))) < conf["turned_rig_deg"]:
        return False, False
    if head_R is None:
        return True, False
    prior_t = kept.priors.t
    starts = [(R0, t0)] if prior_t is None else _starts(R0, t0, head_R, prior_t)
    held = min(
        (kept.fit(_State(R, t, 0.0, 0.0, (0.0, 0.0)), mask0, None, split) for R, t in starts),
        key=lambda candidate: candidate.score,
    )
    gain = _robust_cost(held.errors, kept.noise) - _robust_cost(free.errors, alone.noise)
    if (
        float(np.degrees(rotation_angle(held.state.R))) < conf["turned_rig_deg"]
        and gain < conf["turned_rig_min_gain"]
    ):
        return False, False
    apart = float(np.degrees(rotation_error(head_R, R0)))
    if apart <= conf["head_gate_sigmas"] * conf["prior_rotation_sigma_deg"]:
        return True, False
    notes.append(
        f"the pose head's rotation is {apart:.0f}° from the matches' (a rig unlike those it learnt): "
        "pose from the matches and gravity"
    )
    return True, True


def _robust_cost(errors: np.ndarray, noise: float) -> float:
    """The matches' robust cost: squared Sampson errors in noise units, each capped at 9 (3 noise)."""
    return float(np.sum(np.minimum((errors / noise) ** 2, 9.0)))


def _lens_evidence(k, distortion_evidence) -> float:
    """How much better other evidence of the lens (per camera (k, 1-sigma) or None) likes the distortion
    ``k`` than none: the drop of its chi-square from k = 0 to k."""
    evidence = 0.0
    for k_side, given in zip(k, distortion_evidence, strict=True):
        if given is not None and np.isfinite(given[1]) and given[1] > 0:
            evidence += (given[0] ** 2 - (k_side - given[0]) ** 2) / given[1] ** 2
    return float(evidence)


def _consider_covariance(joint: _Joint, state: _State, mask, split, k_bounds, sigmas: dict) -> np.ndarray:
    """The covariance the pose inherits from parameters held at a guess (a "consider" covariance):
    S·Σc·Sᵀ with S = −H⁻¹·JᵀW·J_c the estimate's sensitivity to them at the solution ``state`` (fitted on
    the matches of ``mask``).

    ``sigmas``: ``focal`` (1-sigma of the log of both focal lengths together) and, if present,
    ``principal_point`` (1-sigma of each camera's principal point along each axis, as a share of the image's
    width and height, from its centre).
    """
    K_left, K_right = joint.K_left, joint.K_right

    def problem(K_l, K_r):
        return joint.problem(mask, split, k_bounds, K_l, K_r)

    base = problem(K_left, K_right)
    r, J = base.jacobian(state)
    w = base.weights(r)
    H = J.T @ (J * w[:, None])
    moves, sigma = [], []  # (K_left, K_right) moved by ± a step, and the 1-sigma in units of the step
    if sigmas.get("focal", 0.0) > 0:
        step = 1e-4
        moves.append(lambda h: (_scaled(K_left, h * step), _scaled(K_right, h * step)))
        sigma.append(sigmas["focal"] / step)
    if sigmas.get("principal_point", 0.0) > 0:
        for side in (0, 1):
            K = (K_left, K_right)[side]
            for axis in (0, 1):
                size = 2.0 * K[axis, 2]  # the image's width or height (principal point at the centre)

                def move(h, side=side, axis=axis):
                    Ks = [K_left.copy(), K_right.copy()]
                    Ks[side][axis, 2] += h * 0.01
                    return Ks[0], Ks[1]

                moves.append(move)
                sigma.append(sigmas["principal_point"] * size / 0.01)
    if not moves:
        return np.zeros_like(H)
    J_c = np.stack(
        [(problem(*m(1.0)).residuals(state) - problem(*m(-1.0)).residuals(state)) / 2.0 for m in moves], 1
    )
    try:
        S = -np.linalg.solve(H, J.T @ (w[:, None] * J_c))
    except np.linalg.LinAlgError:
        return np.zeros_like(H)
    return S @ np.diag(np.square(sigma)) @ S.T


class _Split(NamedTuple):
    """How the refinement shares a correction d of the log focal ratio between the two cameras: the left
    focal is scaled by exp(w_left·d), the right one by exp(-w_right·d) (the shares: each camera's variance
    over both); the prior on d is d0 ± sigma (0 ± the fields' ratio sigma; a tiny sigma holds d)."""

    w_left: float
    w_right: float
    sigma: float
    d0: float = 0.0


class _State(NamedTuple):
    """A point of the joint refinement: rotation, unit direction, log focal ratio d, common log focal
    scale c (0 where it is not refined) and the two cameras' division-model k."""

    R: np.ndarray
    t: np.ndarray
    d: float
    c: float
    k: tuple[float, float]


@dataclass
class _Fit:
    """One refined pose: its robust score over all matches, the parameters, the Hessian and the inliers."""

    score: float
    state: _State  # its k in the given K's normalised coordinates
    scales: tuple[float, float]  # log focal scale per camera
    hessian: Callable[[], np.ndarray]  # the whole Gauss–Newton Hessian there (computed when called)
    mask: np.ndarray
    errors: np.ndarray  # every match's Sampson error there, pixels
    sign_source: str = "pose_head"  # what decided the sign of t (_Joint.signed)


def _in_front_share(R, t, left, right, K_left, K_right, min_parallax_rad: float = 0.0) -> tuple[float, int]:
    """Share of matches that triangulate in front of both cameras, among those whose two rays meet at
    more than ``min_parallax_rad``, and how many those are.

    Points near infinity tell nothing about the sign of t: a rotation error of a few hundredths of a degree
    puts them all behind or all in front.
    """
    nl, nr = _normalise(left, K_left), _normalise(right, K_right)
    use = ray_angles(nl, nr, R) > min_parallax_rad
    if not use.any():
        return 1.0, 0
    P_left = np.hstack([np.eye(3), np.zeros((3, 1))])
    P_right = np.hstack([R, t.reshape(3, 1)])
    X = cv2.triangulatePoints(P_left, P_right, nl[use].T, nr[use].T)
    X = X[:3] / X[3]
    depth_left, depth_right = X[2], (R @ X + t.reshape(3, 1))[2]
    return float(np.mean((depth_left > 0) & (depth_right > 0))), int(use.sum())


@dataclass
class _Priors:
    gravity_left: np.ndarray | None  # None: no gravity coupling
    gravity_right: np.ndarray | None
    gravity_sigma: float | None
    R: np.ndarray | None
    t: np.ndarray | None
    rotation_sigma: float
    direction_sigma: float

    def residuals(self, R: np.ndarray, t: np.ndarray) -> np.ndarray:
        """The prior terms in units of their sigmas: gravity coupling, pose-head rotation and direction."""
        parts = [np.zeros(0)]
        if self.gravity_left is not None:
            parts.append((R @ self.gravity_left - self.gravity_right) / self.gravity_sigma)
        if self.R is not None:
            parts.append(_rotation_residual(R, self.R) / self.rotation_sigma)
        if self.t is not None:
            # against ±t, whichever is nearer: the epipolar error cannot tell the sign, the points in front
            # of the cameras decide it after the refinement, and a flipped t must not look far from the prior
            prior = self.t / np.linalg.norm(self.t)
            parts.append((t * (1.0 if t @ prior >= 0 else -1.0) - prior) / self.direction_sigma)
        return np.concatenate(parts)


def _scaled(K: np.ndarray, log_scale: float) -> np.ndarray:
    """K with its focal lengths multiplied by exp(log_scale) (the principal point stays)."""
    K = K.copy()
    with np.errstate(over="ignore"):  # a trial step far out: an infinite cost, and the step is not taken
        K[0, 0] *= np.exp(log_scale)
        K[1, 1] *= np.exp(log_scale)
    return K


class _PoseProblem:
    """The joint refinement's residuals and Jacobian over a :class:`_State`.

    Residuals: the robust Sampson errors in units of the match noise, then the priors in units of their
    sigmas (gravity coupling, pose-head rotation and direction, the focal ratio d, the common focal scale c,
    the two k). A step is (rotation update [3], direction tangent [2], with ``split`` d, with ``common`` c,
    with ``k_bounds`` the two k).
    """

    eps = 1e-7  # central-difference step of the k columns

    def __init__(
        self, left, right, K_left, K_right, noise_px, priors: _Priors, split, k_bounds, conf, common
    ):
        self.left, self.right, self.K = left, right, (K_left, K_right)
        self.noise_px, self.priors, self.split, self.k_bounds = noise_px, priors, split, k_bounds
        self.common = common
        self.sigma_k = conf["distortion_sigma"]
        self.i_d = 5 if split is not None else None
        self.i_c = 5 + (split is not None) if common is not None else None
        self.n_base = 5 + (split is not None) + (common is not None)
        self.n_params = self.n_base + (0 if k_bounds is None else 2)
        self.n_data = len(left)
        self.huber_k = conf["sampson_scale_px"] / noise_px  # Huber threshold in units of the noise
        # F = M_rᵀ E M_l with M = K⁻¹ of the scaled K: diag(e⁻ˢ, e⁻ˢ, 1)·K⁻¹ (the principal point stays)
        self.inverse = (np.linalg.inv(K_left), np.linalg.inv(K_right))
        self.undistorted: dict = {}

    def log_scales(self, d: float, c: float) -> tuple[float, float]:
        if self.split is None:
            return (c, c)
        return (self.split.w_left * d + c, -self.split.w_right * d + c)

    def inverse_K(self, side: int, log_scale: float) -> np.ndarray:
        return np.diag([np.exp(-log_scale), np.exp(-log_scale), 1.0]) @ self.inverse[side]

    def F(self, state: _State) -> np.ndarray:
        s_l, s_r = self.log_scales(state.d, state.c)
        return fundamental_matrix(_scaled(self.K[0], s_l), _scaled(self.K[1], s_r), state.R, state.t)

    def points(self, side: int, k_side: float) -> np.ndarray:
        """The matches of one side undistorted with k, homogeneous [N x 3] (cached: most evaluations share
        k)."""
        key = (side, k_side)
        if key not in self.undistorted:
            points = undistort_division((self.left, self.right)[side], self.K[side], k_side)
            self.undistorted[key] = _homogeneous(points)
        return self.undistorted[key]

    def moved(self, state: _State, delta) -> _State:
        k = state.k
        if self.k_bounds is not None:
            k = tuple(float(np.clip(k[i] + delta[self.n_base + i], *self.k_bounds[i])) for i in (0, 1))
        return _State(
            rotation_from_axis_angle(delta[:3]) @ state.R,
            retract_on_sphere(state.t, delta[3:5], tangent_basis(state.t)),
            state.d + (delta[self.i_d] if self.i_d is not None else 0.0),
            state.c + (delta[self.i_c] if self.i_c is not None else 0.0),
            k,
        )

    def prior_residuals(self, state: _State) -> np.ndarray:
        ratio = [] if self.split is None else [(state.d - self.split.d0) / self.split.sigma]
        common = [] if self.common is None else [state.c / self.common]
        k = state.k
        k_prior = [] if self.k_bounds is None else [k[0] / self.sigma_k, k[1] / self.sigma_k]
        return np.concatenate([self.priors.residuals(state.R, state.t), ratio, common, k_prior])

    def residuals(self, state: _State) -> np.ndarray:
        sampson = _sampson(self.F(state), self.points(0, state.k[0]), self.points(1, state.k[1]))[0]
        return np.concatenate([sampson / self.noise_px, self.prior_residuals(state)])

    def jacobian(self, state: _State) -> tuple[np.ndarray, np.ndarray]:
        """The residuals and their Jacobian with respect to :meth:`moved`'s step at 0. The Sampson errors'
        derivatives with respect to F chain with F's analytic ones: a rotation step δ moves R to
        exp([δ]ₓ)R, so ∂E/∂δ_i = [t]ₓ[e_i]ₓR; a direction step moves t along its tangent basis b_j, so
        ∂E/∂δ_j = [b_j]ₓR. A camera's k moves its points only (central differences, within its bounds)."""
        R, t, k = state.R, state.t, state.k
        priors, split, n_data, noise = self.priors, self.split, self.n_data, self.noise_px
        s_l, s_r = self.log_scales(state.d, state.c)
        M_l, M_r = self.inverse_K(0, s_l), self.inverse_K(1, s_r)
        E = essential_matrix(R, t)
        F = M_r.T @ E @ M_l
        basis = tangent_basis(t)
        dE = [skew(t) @ skew(e) @ R for e in np.eye(3)] + [skew(basis[:, j]) @ R for j in range(2)]
        dF = [M_r.T @ dE_i @ M_l for dE_i in dE]
        P = np.diag([1.0, 1.0, 0.0])  # a log scale s moves M to diag(e⁻ˢ, e⁻ˢ, 1)·K⁻¹: ∂M/∂s = −P·M
        if split is not None:  # ∂M_l/∂d = −w_l·P·M_l, ∂M_r/∂d = w_r·P·M_r
            dF.append(split.w_right * M_r.T @ P @ E @ M_l - split.w_left * M_r.T @ E @ P @ M_l)
        if self.common is not None:  # ∂M/∂c = −P·M on both sides
            dF.append(-(M_r.T @ P @ E @ M_l) - M_r.T @ E @ P @ M_l)
        sampson, dS = _sampson(F, self.points(0, k[0]), self.points(1, k[1]), np.stack(dF))
        r = np.concatenate([sampson / noise, self.prior_residuals(state)])
        J = np.zeros((len(r), self.n_params))
        J[:n_data, : self.n_base] = dS / noise
        row = n_data  # the priors, in the order of _Priors.residuals and prior_residuals
        if priors.gravity_left is not None:
            J[row : row + 3, :3] = -skew(R @ priors.gravity_left) / priors.gravity_sigma
            row += 3
        if priors.R is not None:
            J[row : row + 3, :3] = _log_jacobian(_rotation_residual(R, priors.R)) / priors.rotation_sigma
            row += 3
        if priors.t is not None:
            sign = 1.0 if t @ priors.t >= 0 else -1.0
            J[row : row + 3, 3:5] = sign * basis / priors.direction_sigma
            row += 3
        if split is not None:
            J[row, self.i_d] = 1.0 / split.sigma
            row += 1
        if self.common is not None:
            J[row, self.i_c] = 1.0 / self.common
            row += 1
        for i in range(self.n_base, self.n_params):  # a camera's k: its points, and its prior
            step = np.zeros(self.n_params)
            step[i] = self.eps
            k_plus, k_minus = self.moved(state, step).k, self.moved(state, -step).k
            side = i - self.n_base
            # over the k actually moved: at a bound one side of the difference is clipped to it
            J[:n_data, i] = (
                _sampson(F, self.points(0, k_plus[0]), self.points(1, k_plus[1]))[0]
                - _sampson(F, self.points(0, k_minus[0]), self.points(1, k_minus[1]))[0]
            ) / ((k_plus[side] - k_minus[side]) * noise)
            J[row + side, i] = 1.0 / self.sigma_k
        return r, J

    def cost(self, state: _State) -> float:
        """Σ ρ(r²): Huber's loss on the Sampson errors (r² within the threshold k, 2k|r| − k² beyond), the
        priors' squares."""
        r = self.residuals(state)
        data, priors = np.abs(r[: self.n_data]), r[self.n_data :]
        k = self.huber_k
        return float(np.sum(np.where(data <= k, data * data, 2 * k * data - k * k)) + priors @ priors)

    def _weighted(self, state: _State) -> tuple[np.ndarray, np.ndarray]:
        """Jᵀ·W·J and Jᵀ·W·r with the Huber weights at ``state``: the Gauss–Newton form of :meth:`cost`."""
        r, J = self.jacobian(state)
        w = self.weights(r)
        return J.T @ (J * w[:, None]), J.T @ (w * r)

    def hessian(self, state: _State) -> np.ndarray:
        """The whole Gauss–Newton Hessian at ``state`` (the covariance's: no k held)."""
        return self._weighted(state)[0]

    def normal_equations(self, state: _State) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_weighted`, for the step: a camera's k that sits at a bound with its gradient pointing
        beyond it is held, its row and column cleared but the diagonal, its gradient 0. A step across the
        bound would be clipped, and the clipped step is not the one the quadratic model promised (the fit
        then rejected every other step and crept)."""
        H, g = self._weighted(state)
        if self.k_bounds is None:
            return H, g
        H, g = H.copy(), g.copy()
        for side, (low, high) in enumerate(self.k_bounds):
            i, k = self.n_base + side, state.k[side]
            if (k >= high and g[i] < 0.0) or (k <= low and g[i] > 0.0):
                diagonal = H[i, i]
                H[i, :], H[:, i], g[i] = 0.0, 0.0, 0.0
                H[i, i] = diagonal
        return H, g

    def weights(self, r: np.ndarray) -> np.ndarray:
        """Huber weights on the Sampson errors; the priors weigh 1."""
        w = np.ones_like(r)
        data_abs = np.abs(r[: self.n_data])
        w[: self.n_data] = np.where(data_abs <= self.huber_k, 1.0, self.huber_k / np.maximum(data_abs, 1e-12))
        return w


def _refine_pose(
    state: _State, left, right, K_left, K_right, noise_px, priors, split, k_bounds, conf, common
):
    """LM on (rotation update [3], direction tangent [2], with ``split`` the log focal ratio d, with
    ``common`` the common log focal scale c, with ``k_bounds`` the two cameras' distortion k): robust
    Sampson errors in units of the match noise, plus the soft gravity coupling, the pose-head prior, the
    refiner's focal ratio, the fields' common focal scale and the zero-mean distortion prior, in units of
    their sigmas (:class:`_PoseProblem`).

    ``split`` (a :class:`_Split`): how each camera takes its share of a ratio correction d, and d's prior.
    ``common``: the 1-sigma of the prior 0 on c, which scales both focal lengths by exp(c) (None: c held at
    the state's). ``state.k`` undistorts the matches in the normalised coordinates of the given K_left,
    K_right; ``k_bounds`` their (lower, upper) limits. Returns the refined state, its whole Gauss–Newton
    Hessian (a function, computed once when first called: the sign of t and the chosen fit's covariance
    need it), the two log focal scales and the reweighted cost Σ w·r² with the Huber weights there (in
    units of the noise and the sigmas; the nested tests of the lens and of equal focal lengths compare it).
    """
    problem = _PoseProblem(left, right, K_left, K_right, noise_px, priors, split, k_bounds, conf, common)
    settings = Settings(
        max_iterations=conf["iterations"], lambda_init=1e-3, lambda_max=1e6, relative_tolerance=1e-6,
        step_tolerance=1e-10,
    )  # fmt: skip
    fit = levenberg_marquardt(state, problem.cost, problem.normal_equations, problem.moved, settings)
    r = problem.residuals(fit.x)
    scales = problem.log_scales(fit.x.d, fit.x.c)
    hessian = functools.cache(lambda: problem.hessian(fit.x))
    return fit.x, hessian, scales, float(np.sum(problem.weights(r) * r * r))
