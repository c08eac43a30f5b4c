"""The rig's relative pose: essential matrix from matches, refined jointly with gravity and the pose head.

Convention (fixed): ``X_right = R @ X_left + T``, T in metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from stereogeo_cli.fuse.matches import Matches
from stereogeo_cli.geometry.epipolar import fundamental_matrix
from stereogeo_cli.geometry.gravity import (
    couple_rotation_to_gravity,
    gravity_angle,
    retract_on_sphere,
    tangent_basis,
)
from stereogeo_cli.geometry.rotation import axis_angle_from_rotation, rotation_error, rotation_from_axis_angle

default_conf = {
    "min_matches": 20,  # fewer matches than this: the pose head and gravity alone
    "min_inliers": 15,  # fewer essential-matrix inliers than this: the pose head and gravity alone
    "ransac_threshold_px": 1.0,  # MAGSAC threshold on the epipolar error, pixels
    "ransac_confidence": 0.9999,
    "sampson_scale_px": 1.0,  # Huber scale of the Sampson error in the joint refinement, pixels
    "min_noise_px": 0.25,  # floor of the estimated match noise (keeps the data from swamping the priors)
    "iterations": 15,  # Gauss–Newton/LM steps of the joint refinement
    "prior_rotation_sigma_deg": 5.0,  # 1-sigma of the pose head's rotation
    "prior_direction_sigma_deg": 15.0,  # 1-sigma of the pose head's translation direction
}


@dataclass
class RelativePose:
    """Rotation [3 x 3], unit translation direction [3], and how they were obtained."""

    R: np.ndarray
    t_direction: np.ndarray
    source: str  # "matches" or "pose_head"
    matches_found: int = 0
    inliers: int = 0
    sigma_rotation_deg: float = float("inf")
    sigma_direction_deg: float = float("inf")
    gravity_error_deg: float | None = None  # angle between R·g_left and g_right after the fusion
    focal_scale: tuple[float, float] = (1.0, 1.0)  # refined focal / given focal, per camera
    notes: list[str] = field(default_factory=list)

    def translation(self, baseline_m: float) -> np.ndarray:
        """T [3] in metres for a baseline |T| in metres."""
        return self.t_direction * float(baseline_m)


def _normalise(points: np.ndarray, K: np.ndarray) -> np.ndarray:
    homogeneous = np.column_stack([points, np.ones(len(points))])
    out = homogeneous @ np.linalg.inv(K).T
    return out[:, :2] / out[:, 2:]


def sampson_errors(F: np.ndarray, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Signed Sampson errors [N] in pixels of matches left, right [N x 2] under F (x_rightᵀ F x_left = 0)."""
    pl = np.column_stack([left, np.ones(len(left))])
    pr = np.column_stack([right, np.ones(len(right))])
    Fl = pl @ F.T
    Ftr = pr @ F
    algebraic = np.sum(pr * Fl, axis=1)
    denom = Fl[:, 0] ** 2 + Fl[:, 1] ** 2 + Ftr[:, 0] ** 2 + Ftr[:, 1] ** 2
    return algebraic / np.sqrt(np.maximum(denom, 1e-300))


def essential_pose(matches: Matches, K_left: np.ndarray, K_right: np.ndarray, conf: dict | None = None):
    """R, unit t and the inlier mask from matches via MAGSAC and the cheirality check, or None."""
    conf = {**default_conf, **(conf or {})}
    if len(matches) < 5:
        return None
    nl, nr = _normalise(matches.left, K_left), _normalise(matches.right, K_right)
    focal = 0.5 * (K_left[0, 0] + K_right[0, 0])
    E, mask = cv2.findEssentialMat(
        nl, nr, np.eye(3), method=cv2.USAC_MAGSAC, prob=conf["ransac_confidence"],
        threshold=conf["ransac_threshold_px"] / focal,
    )  # fmt: skip
    if E is None or E.shape != (3, 3) or mask is None:
        return None
    # distanceThresh: with short baselines most points lie far away in units of |t|; keep them all
    count, R, t, pose_mask, _ = cv2.recoverPose(E, nl, nr, np.eye(3), distanceThresh=1e9, mask=mask.copy())
    inliers = (pose_mask.ravel() > 0) & (mask.ravel() > 0)
    if count < 5:
        return None
    return R, t.ravel() / np.linalg.norm(t), inliers


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
    conf: dict | None = None,
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
    Returns:
        A :class:`RelativePose`. With enough matches: the essential-matrix pose refined on its inliers
        (robust Sampson error) with soft gravity coupling (R·g_left = g_right) and the pose head as a
        prior. Otherwise the pose head, rotated by the least amount that makes it agree with gravity.
    """
    conf = {**default_conf, **(conf or {})}
    has_gravity = gravity_left is not None and gravity_right is not None and gravity_sigma_rad
    notes: list[str] = []
    found = len(matches)
    initial = essential_pose(matches, K_left, K_right, conf) if found >= conf["min_matches"] else None
    if initial is None or initial[2].sum() < conf["min_inliers"]:
        if prior_R is None or prior_t is None:
            raise ValueError("too few matches for the relative pose and no pose-head prior to fall back on")
        inliers = 0 if initial is None else int(initial[2].sum())
        notes.append(
            f"too few matches ({found} found, {inliers} inliers): pose from the pose head and gravity"
        )
        R = (
            _pull_towards_gravity(prior_R, gravity_left, gravity_right, gravity_sigma_rad, conf)
            if has_gravity
            else prior_R
        )
        t = np.asarray(prior_t, dtype=float)
        return RelativePose(
            R=R, t_direction=t / np.linalg.norm(t), source="pose_head", matches_found=found, inliers=inliers,
            sigma_rotation_deg=float(conf["prior_rotation_sigma_deg"]),
            sigma_direction_deg=float(conf["prior_direction_sigma_deg"]),
            gravity_error_deg=_gravity_error_deg(R, gravity_left, gravity_right) if has_gravity else None,
            notes=notes,
        )  # fmt: skip

    R0, t0, mask0 = initial
    # Only the ratio of the two focal lengths is refined with the pose: the matches fix it well on any rig,
    # while the absolute focal is unobservable on near-parallel rigs and absorbs lens distortion.
    var = [0.0 if (v is None or not np.isfinite(v) or v <= 0) else float(v) ** 2 for v in focal_sigma_rel]
    split = None if sum(var) <= 0 else (var[0] / sum(var), var[1] / sum(var), float(np.sqrt(sum(var))))
    priors = _Priors(
        gravity_left if has_gravity else None, gravity_right, gravity_sigma_rad, prior_R, prior_t,
        np.radians(conf["prior_rotation_sigma_deg"]), np.radians(conf["prior_direction_sigma_deg"]),
    )  # fmt: skip
    errors0 = sampson_errors(fundamental_matrix(K_left, K_right, R0, t0), matches.left, matches.right)
    noise = max(1.4826 * float(np.median(np.abs(errors0[mask0]))), conf["min_noise_px"])
    # Short baselines leave a valley of near-equal epipolar error between rotation and translation:
    # refine from the essential matrix and from the pose head (made consistent with gravity), keep the best.
    starts = [(R0, t0)]
    if prior_R is not None and prior_t is not None:
        R_p = couple_rotation_to_gravity(prior_R, gravity_left, gravity_right) if has_gravity else prior_R
        t_p = np.asarray(prior_t, dtype=float) / np.linalg.norm(prior_t)
        if rotation_error(R_p, R0) > np.radians(0.5) or np.degrees(gravity_angle(t_p, t0)) > 5.0:
            starts.append((R_p, t_p))  # a second start only where it could lead elsewhere
    best = None
    for R, t in starts:
        mask, d = mask0, 0.0
        # two rounds: refine on the inliers, re-select the inliers among all matches, refine again
        for _ in range(2):
            R, t, d, H, scales = _refine_pose(
                R, t, d, matches.left[mask], matches.right[mask], K_left, K_right, noise, priors, split, conf
            )
            K_l, K_r = _scaled(K_left, scales[0]), _scaled(K_right, scales[1])
            errors = sampson_errors(fundamental_matrix(K_l, K_r, R, t), matches.left, matches.right)
            mask = np.abs(errors) < max(3.0 * noise, conf["ransac_threshold_px"])
        if _in_front_share(R, t, matches.left[mask], matches.right[mask], K_l, K_r) < 0.5:
            t = -t  # the epipolar error cannot tell t from -t; the points must lie in front of the cameras
        focal_terms = 0.0 if split is None else (d / split[2]) ** 2
        score = float(
            np.sum(np.minimum((errors / noise) ** 2, 9.0)) + np.sum(priors.residuals(R, t) ** 2) + focal_terms
        )
        if best is None or score < best[0]:
            best = (score, R, t, scales, H, mask)
    _, R, t, scales, H, inlier_mask = best
    cov = np.linalg.inv(H)
    return RelativePose(
        R=R, t_direction=t, source="matches", matches_found=found, inliers=int(inlier_mask.sum()),
        sigma_rotation_deg=float(np.degrees(np.sqrt(np.trace(cov[:3, :3])))),
        sigma_direction_deg=float(np.degrees(np.sqrt(np.trace(cov[3:5, 3:5])))),
        focal_scale=(float(np.exp(scales[0])), float(np.exp(scales[1]))),

        gravity_error_deg=_gravity_error_deg(R, gravity_left, gravity_right) if has_gravity else None,
        notes=notes,
    )  # fmt: skip


def _in_front_share(R, t, left, right, K_left, K_right) -> float:
    """Share of matches that triangulate in front of both cameras."""
    if len(left) == 0:
        return 1.0
    P_left = np.hstack([np.eye(3), np.zeros((3, 1))])
    P_right = np.hstack([R, t.reshape(3, 1)])
    X = cv2.triangulatePoints(P_left, P_right, _normalise(left, K_left).T, _normalise(right, K_right).T)
    X = X[:3] / X[3]
    depth_left, depth_right = X[2], (R @ X + t.reshape(3, 1))[2]
    return float(np.mean((depth_left > 0) & (depth_right > 0)))


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
            parts.append((t - self.t / np.linalg.norm(self.t)) / self.direction_sigma)
        return np.concatenate(parts)


def _scaled(K: np.ndarray, log_scale: float) -> np.ndarray:
    """K with its focal lengths multiplied by exp(log_scale) (the principal point stays)."""
    K = K.copy()
    K[0, 0] *= np.exp(log_scale)
    K[1, 1] *= np.exp(log_scale)
    return K


def _refine_pose(R, t, d, left, right, K_left, K_right, noise_px, priors: _Priors, split, conf):
    """LM on (rotation update [3], direction tangent [2], and with ``split`` the log focal ratio d):
    robust Sampson errors in units of the match noise, plus the soft gravity coupling, the pose-head
    prior and the refiner's focal ratio, in units of their sigmas.

    ``split`` = (w_left, w_right, sigma_d): the left focal is scaled by exp(w_left·d) and the right one
    by exp(-w_right·d), so each camera takes its share of a ratio correction.
    """
    n_params = 5 if split is None else 6

    def log_scales(d_):
        return (0.0, 0.0) if split is None else (split[0] * d_, -split[1] * d_)

    def residuals(R_, t_, d_):
        s_l, s_r = log_scales(d_)
        F = fundamental_matrix(_scaled(K_left, s_l), _scaled(K_right, s_r), R_, t_)
        ratio = [] if split is None else [d_ / split[2]]
        return np.concatenate([sampson_errors(F, left, right) / noise_px, priors.residuals(R_, t_), ratio])

    def moved(R_, t_, d_, delta):
        return (
            rotation_from_axis_angle(delta[:3]) @ R_,
            retract_on_sphere(t_, delta[3:5], tangent_basis(t_)),
            d_ + (delta[5] if split is not None else 0.0),
        )

    n_data = len(left)
    huber_k = conf["sampson_scale_px"] / noise_px  # Huber threshold in units of the noise
    lam, eps = 1e-3, 1e-7
    H = np.eye(n_params)
    for _ in range(conf["iterations"]):
        r = residuals(R, t, d)
        w = np.ones_like(r)
        data_abs = np.abs(r[:n_data])
        w[:n_data] = np.where(data_abs <= huber_k, 1.0, huber_k / np.maximum(data_abs, 1e-12))
        J = np.empty((len(r), n_params))
        for i in range(n_params):
            e = np.zeros(n_params)
            e[i] = eps
            J[:, i] = (residuals(*moved(R, t, d, e)) - residuals(*moved(R, t, d, -e))) / (2 * eps)
        H = J.T @ (J * w[:, None])
        step = -np.linalg.solve(H + lam * np.diag(np.diag(H) + 1e-12), J.T @ (w * r))
        R_new, t_new, d_new = moved(R, t, d, step)
        r_new = residuals(R_new, t_new, d_new)
        cost, new_cost = float(np.sum(w * r * r)), float(np.sum(w * r_new * r_new))
        if new_cost < cost:
            R, t, d, lam = R_new, t_new, d_new, lam * 0.1
            if cost - new_cost < 1e-6 * cost or np.linalg.norm(step) < 1e-10:
                break
        else:
            lam *= 10
            if lam > 1e6:
                break
    return R, t, d, H, log_scales(d)
