"""Two views from one centre: a pair whose matches a rotation alone explains.

Two crops of one panorama, a camera turned on a tripod, or a rig whose scene lies so far away that its
baseline moves no match: every match then obeys ``x_right ~ K_right · R · K_left⁻¹ · x_left``, a homography
of a special kind. An essential matrix means nothing there: its t is noise, and the rotation fitted with
it leans on that noise. Worse, a rotation is what tells the focal lengths: the rays of one camera land on
the other's pixels through both focal lengths, which a translation does not do.

**Recognised** by Torr's geometric robust information criterion (GRIC, Torr 1998), which weighs a model's
robust residuals against the dimension of what it explains: a match lies on a 2-dimensional variety of the
4-dimensional space of matches under a rotation, a 3-dimensional one under an essential matrix. For n
matches with noise σ, GRIC = Σ min(e²/σ², λ₃·(4 − d)) + λ₁·d·n + λ₂·k, with e each match's distance from
the model's variety, d its dimension, k the model's parameters, λ₁ = ln 4, λ₂ = ln 4n and λ₃ = 2. The
model with the lower GRIC is kept. A rotation's e² is half the squared transfer error (both pixels are
noisy); the essential matrix's is the squared Sampson error.

**Fitted**: R, the two cameras' log focal scales (those not held) and the right principal point's shift from
the image centre, minimising the robust transfer error with the pose priors (gravity shared by the cameras,
the pose head's rotation) and a zero-mean prior on the shift (``principal_point_sigma`` of the image's size
per axis, for each camera: √2 of it for their difference). What a rotation tells of the focal lengths
depends on where the principal points really are: a small turn moves every pixel by about the same amount,
and a principal point a few pixels off does the same. So the rotation's read of the focal lengths is the
fit's information on them with R and the shift marginalised (a Schur complement), with a floor for what a
pinhole rotation does not model; it is combined with the fields' read (the caller's prior covariance) by
their information. R is fitted again at the combined focal lengths with the principal points at the
centres, as everywhere in the calibration, and its covariance takes in theirs. A turn about the optical
axis, or none (the evaluation's pair of a photo and its crop), tells nothing of them: the fields' read
stands.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from stereogeo_cli.geometry.rotation import closest_rotation, rotation_from_axis_angle
from stereogeo_cli.refine.levenberg import Settings, levenberg_marquardt
from stereogeo_cli.settings import resolve

default_conf = {
    "start_threshold_px": 3.0,  # RANSAC threshold of the homography the fit may start from, pixels
    "transfer_scale_px": 1.0,  # Huber scale of the transfer error, pixels (as the fusion's Sampson scale)
    "iterations": 15,  # Levenberg–Marquardt steps tried per fit (as the fusion's)
    # the 1-sigma (log f) of the weak prior that keeps the rotation's own read of a focal length defined
    # where the turn says nothing of it; far wider than any read it is combined with
    "free_focal_sigma": 1.0,
    # added in quadrature to the 1-sigma of the rotation's read of a focal length: what the pinhole rotation
    # does not model (a lens's distortion reads as a focal length; a rolling shutter)
    "focal_floor": 0.02,
    "gric_lambda3": 2.0,  # Torr's cap on a match's robust residual, per dimension it is off the model by
}

_DATA_DIM = 4  # a match: two pixels
_ROTATION_DIM = 2  # the variety a rotation (a homography) leaves a match on
_ESSENTIAL_DIM = 3


def gric(squared: np.ndarray, dimension: int, parameters: int, lambda3: float) -> float:
    """Torr's GRIC of a model from its matches' squared distances in units of the noise (module
    docstring): the lower, the better the model explains the matches for its size."""
    n = len(squared)
    capped = np.minimum(squared, lambda3 * (_DATA_DIM - dimension))
    return float(np.sum(capped) + math.log(_DATA_DIM) * dimension * n + math.log(_DATA_DIM * n) * parameters)


def essential_gric(
    sampson_px: np.ndarray, noise_px: float, parameters: int, conf: dict | None = None
) -> float:
    """GRIC of an essential matrix (with ``parameters`` in all: its 5 and what was refined with it) from its
    matches' Sampson errors in pixels."""
    conf = resolve(default_conf, conf)
    squared = (np.asarray(sampson_px) / noise_px) ** 2
    return gric(squared, _ESSENTIAL_DIM, parameters, conf["gric_lambda3"])


@dataclass
class RotationFit:
    """A pair fitted as two views from one centre."""

    R: np.ndarray  # [3 x 3], X_right = R @ X_left
    log_scales: np.ndarray  # [2] each camera's refined focal length over its given one, in log
    scale_cov: np.ndarray  # [2 x 2] their covariance (0 rows and columns for a held focal length)
    rotation_cov: np.ndarray  # [3 x 3] of R's small-angle error, radians², the focal lengths' taken in
    gric: float  # of the rotation at its own read of the focal lengths
    inliers: np.ndarray  # [N] bool, transfer error within 3 noise sigmas (√2 σ per pixel)
    # [2] the 1-sigma of what the rotation alone reads of each log focal scale, the floor included (inf: it
    # reads nothing; a held one's is inf too)
    read_sigma: np.ndarray


class _Transfer:
    """The robust transfer error of the matches under x = (R, log scales [2], shift [2]), plus the priors:
    the pose's (gravity, the pose head), a prior on the free log scales, and with ``shift_sigma`` [2] the
    right principal point's shift from its centre in pixels (the two cameras' offsets: a difference), free
    with that zero-mean prior (None: held at 0)."""

    def __init__(self, left, right, K_left, K_right, noise_px, free, prior_residuals, scale_prior, conf,
                 shift_sigma=None):  # fmt: skip
        self.left, self.right = left, right
        self.K_left, self.K_right = K_left, K_right
        self.free = free  # which log scales move
        self.shift_sigma = shift_sigma
        self.size = 3 + int(free.sum()) + (0 if shift_sigma is None else 2)
        self.unit = math.sqrt(2.0) * noise_px  # a transfer error's 1-sigma per pixel axis
        self.huber_k = conf["transfer_scale_px"] / noise_px
        self.prior_residuals = prior_residuals
        self.scale_prior = scale_prior  # the inverse square root of the free log scales' covariance (mean 0)
        self.rays = (np.c_[left, np.ones(len(left))]) @ np.linalg.inv(K_left).T  # at the given focal

    def predicted(self, x) -> np.ndarray:
        """Each left pixel carried into the right image [N x 2]."""
        R, scales, shift = x
        rays = self.rays * np.array([math.exp(-scales[0]), math.exp(-scales[0]), 1.0])
        X = rays @ R.T
        z = np.where(np.abs(X[:, 2]) < 1e-12, 1e-12, X[:, 2])
        f = self.K_right[0, 0] * math.exp(scales[1]), self.K_right[1, 1] * math.exp(scales[1])
        centre = self.K_right[:2, 2] + shift
        return np.c_[f[0] * X[:, 0] / z + centre[0], f[1] * X[:, 1] / z + centre[1]]

    def transfer(self, x) -> np.ndarray:
        """[N x 2] transfer errors in units of their 1-sigma."""
        return (self.right - self.predicted(x)) / self.unit

    def priors(self, x) -> np.ndarray:
        R, scales, shift = x
        parts = [self.prior_residuals(R)]
        if self.scale_prior is not None:
            parts.append(self.scale_prior @ scales[self.free])
        if self.shift_sigma is not None:
            parts.append(shift / self.shift_sigma)
        return np.concatenate(parts)

    def residuals(self, x) -> np.ndarray:
        return np.concatenate([self.transfer(x).ravel(), self.priors(x)])

    def moved(self, x, step: np.ndarray):
        R, scales, shift = x
        scales = scales.copy()
        n = int(self.free.sum())
        scales[self.free] += step[3 : 3 + n]
        if self.shift_sigma is not None:
            shift = shift + step[3 + n : 5 + n]
        return rotation_from_axis_angle(step[:3]) @ R, scales, shift

    def weights(self, x) -> np.ndarray:
        """Huber weights on each match's transfer error (its 2-vector's length), the priors weighing 1."""
        length = np.linalg.norm(self.transfer(x), axis=1)
        w = np.where(length <= self.huber_k, 1.0, self.huber_k / np.maximum(length, 1e-12))
        return np.concatenate([np.repeat(w, 2), np.ones(len(self.priors(x)))])

    def cost(self, x) -> float:
        length = np.linalg.norm(self.transfer(x), axis=1)
        k = self.huber_k
        data = np.where(length <= k, length**2, 2 * k * length - k * k)
        priors = self.priors(x)
        return float(np.sum(data) + priors @ priors)

    def hessian(self, x) -> np.ndarray:
        """The Gauss–Newton Hessian (Huber weights) over the step's coordinates."""
        return self.normal_equations(x)[0]

    def jacobian(self, x) -> np.ndarray:
        """∂residuals/∂step [2N + P x size]: the transfer errors' analytically (rotation update ω with
        R ← exp(ω)·R, the free log scales, the shift), the priors' by central differences."""
        R, scales, shift = x
        n = len(self.left)
        rays = self.rays * np.array([math.exp(-scales[0]), math.exp(-scales[0]), 1.0])
        X = rays @ R.T
        z = np.where(np.abs(X[:, 2]) < 1e-12, 1e-12, X[:, 2])
        f = np.array([self.K_right[0, 0], self.K_right[1, 1]]) * math.exp(scales[1])
        projected = X[:, :2] / z[:, None]

        def through_projection(dX: np.ndarray) -> np.ndarray:  # dX [N x 3] → d(predicted pixel) [N x 2]
            return f * (dX[:, :2] - projected * dX[:, 2:3]) / z[:, None]

        columns = []
        for axis in range(3):  # d(exp(ω)·X)/dω_axis = e_axis × X
            e = np.zeros(3)
            e[axis] = 1.0
            columns.append(through_projection(np.cross(e, X)))
        free = np.flatnonzero(self.free)
        for side in free:
            if side == 0:  # the left rays' x, y shrink with the left focal length
                columns.append(through_projection(-(rays * np.array([1.0, 1.0, 0.0])) @ R.T))
            else:
                columns.append(f * projected)
        if self.shift_sigma is not None:
            columns += [np.tile([1.0, 0.0], (n, 1)), np.tile([0.0, 1.0], (n, 1))]
        J_data = -np.stack([c.reshape(-1) for c in columns], axis=1) / self.unit  # error = right − predicted
        # the priors: the pose's on R by central differences; the scales' and the shift's are linear
        pose = []
        for axis in range(3):
            step = np.zeros(3)
            step[axis] = 1e-6
            turned = [self.prior_residuals(rotation_from_axis_angle(sign * step) @ R) for sign in (1.0, -1.0)]
            pose.append((turned[0] - turned[1]) / 2e-6)
        on_R = len(pose[0])
        J_priors = np.zeros((len(self.priors(x)), self.size))
        J_priors[:on_R, :3] = np.stack(pose, axis=1)
        row, column = on_R, 3
        if self.scale_prior is not None:
            J_priors[row : row + len(free), column : column + len(free)] = self.scale_prior
            row += len(free)
        column += len(free)
        if self.shift_sigma is not None:
            J_priors[row : row + 2, column : column + 2] = np.diag(1.0 / self.shift_sigma)
        return np.vstack([J_data, J_priors])

    def normal_equations(self, x):
        J = self.jacobian(x)
        r, w = self.residuals(x), self.weights(x)
        return J.T @ (J * w[:, None]), J.T @ (w * r)


def _start(matches, K_left, K_right, R_essential: np.ndarray, problem: _Transfer, conf) -> np.ndarray:
    """The better start of the essential matrix's R and the rotation nearest the RANSAC homography."""
    starts = [R_essential]
    if len(matches.left) >= 4:
        H, _ = cv2.findHomography(matches.left, matches.right, cv2.RANSAC, conf["start_threshold_px"])
        if H is not None and np.all(np.isfinite(H)):
            M = np.linalg.inv(K_right) @ H @ K_left
            det = np.linalg.det(M)
            if abs(det) > 1e-12:
                starts.append(closest_rotation(M / np.cbrt(det)))
    return min(starts, key=lambda R: problem.cost((R, np.zeros(2), np.zeros(2))))


def fit_rotation(
    matches,
    K_left: np.ndarray,
    K_right: np.ndarray,
    noise_px: float,
    R_start: np.ndarray,
    prior_residuals: Callable[[np.ndarray], np.ndarray],
    focal_prior_cov: np.ndarray,
    held: tuple[bool, bool],
    principal_point_sigma: float,
    min_noise_px: float,
    conf: dict | None = None,
) -> RotationFit:
    """The pair fitted as two views from one centre (module docstring).

    Args:
        matches: pixel matches (``left``, ``right`` [N x 2]).
        K_left, K_right: the given intrinsics (principal points at the image centres).
        noise_px: the matches' noise (the essential matrix's: the two models are compared at one noise).
        R_start: the essential matrix's rotation (one of the starts).
        prior_residuals: R ↦ the pose priors' residuals in units of their sigmas (gravity, the pose head).
        focal_prior_cov: [2 x 2] covariance of the fields' read of the two log focal lengths.
        held: per camera, whether its focal length is held (given).
        principal_point_sigma: 1-sigma of a principal point from the image centre, per axis, as a share of
            the image's width and height.
        min_noise_px: the floor of the noise the covariances are computed at (the fusion's).
    """
    conf = resolve(default_conf, conf)
    left, right = np.asarray(matches.left, float), np.asarray(matches.right, float)
    free = ~np.asarray(held, dtype=bool)
    n = int(free.sum())
    settings = Settings(max_iterations=conf["iterations"], lambda_init=1e-3, relative_tolerance=1e-6)
    weak = np.eye(n) / conf["free_focal_sigma"] if n else None
    size = np.array([2.0 * (K_right[0, 2] + 0.5), 2.0 * (K_right[1, 2] + 0.5)])
    shift_sigma = math.sqrt(2.0) * principal_point_sigma * size

    def problem(noise, scales: bool, prior, shift: bool) -> _Transfer:
        """The transfer problem with the free log scales moving (or none) under ``prior``, and the
        principal point's shift free (or held at 0)."""
        moving = free if scales else np.zeros(2, dtype=bool)
        shift = shift and principal_point_sigma > 0  # principal points known exactly: held
        return _Transfer(left, right, K_left, K_right, noise, moving, prior_residuals, prior, conf,
                         shift_sigma if shift else None)  # fmt: skip

    zero = np.zeros(2)
    # 1. the rotation's own read of the free log scales, the principal points free within their prior
    reading = problem(noise_px, True, weak, True)
    R0 = _start(matches, K_left, K_right, R_start, reading, conf)
    fit = levenberg_marquardt(
        (R0, zero, zero), reading.cost, reading.normal_equations, reading.moved, settings
    )
    value, noise_px = _gric_and_own_noise(reading, fit.x, noise_px, n, min_noise_px, conf)
    combined, scale_cov, read_sigma = np.zeros(2), np.zeros((2, 2)), np.full(2, np.inf)
    if n:
        H = problem(noise_px, True, weak, True).hessian(fit.x)
        read_cov = _read_covariance(H, n, conf)
        # 2. combined with the fields' read (mean 0) by their information
        combined, scale_cov, read_sigma = _combined_with_fields(read_cov, fit.x[1], free, focal_prior_cov)
    # 3. R again at the combined focal lengths, the principal points at the centres as everywhere in the
    # calibration; its covariance takes in the focal lengths'
    fitting = problem(noise_px, False, None, False)
    start = (fit.x[0], combined, zero)
    fit = levenberg_marquardt(start, fitting.cost, fitting.normal_equations, fitting.moved, settings)
    R = fit.x[0]
    both = problem(noise_px, True, np.zeros((n, n)), False)  # the free scales as columns, no prior
    rotation_cov = _rotation_covariance(both.hessian((R, combined, zero)), scale_cov, free, n)
    inliers = np.linalg.norm(fitting.transfer(fit.x), axis=1) <= 3.0
    return RotationFit(R, combined, scale_cov, rotation_cov, value, inliers, read_sigma)


def _gric_and_own_noise(reading: _Transfer, x, noise_px: float, n: int, min_noise_px: float, conf):
    """The rotation's GRIC at the fit ``x`` (with ``n`` free log scales) at the noise given, and the noise
    (pixels) its covariances are computed at: the fit's own, floored at ``min_noise_px``."""
    # the model's own best fit decides between it and the essential matrix, at the noise given
    squared = 0.5 * np.sum((reading.transfer(x) * reading.unit / noise_px) ** 2, axis=1)  # noise units
    value = gric(squared, _ROTATION_DIM, 5 + n, conf["gric_lambda3"])
    # its covariances at its own noise (a parallax the rotation leaves unexplained widens it), floored as
    # the fusion's are
    own = float(np.median(np.sqrt(squared))) / math.sqrt(2.0 * math.log(2.0)) * noise_px  # Rayleigh
    return value, max(own, min_noise_px)


def _read_covariance(H: np.ndarray, n: int, conf) -> np.ndarray:
    """The covariance [n x n] of the rotation's own read of the ``n`` free log scales from the reading
    problem's Hessian ``H`` (changed in place): the data's information on them with R and the shift
    marginalised, with the floor for what the pinhole rotation does not model."""
    H[3 : 3 + n, 3 : 3 + n] -= np.eye(n) / conf["free_focal_sigma"] ** 2  # the data's read alone
    # the data's information on the scales, R and the shift marginalised (a Schur complement; R and the
    # shift have priors, so their block is invertible)
    scales, others = np.arange(3, 3 + n), np.r_[0:3, 3 + n : len(H)]
    H_oo = H[np.ix_(others, others)]
    info = H[np.ix_(scales, scales)] - H[np.ix_(scales, others)] @ np.linalg.solve(
        H_oo, H[np.ix_(others, scales)]
    )
    info = 0.5 * (info + info.T)
    # the read's covariance with the floor for what the pinhole rotation does not model
    values, vectors = np.linalg.eigh(info)
    return (vectors / np.maximum(values, 1e-12)) @ vectors.T + np.eye(n) * conf["focal_floor"] ** 2


def _combined_with_fields(read_cov: np.ndarray, read_scales: np.ndarray, free: np.ndarray, focal_prior_cov):
    """The rotation's read of the free log scales (``read_scales`` [2], covariance ``read_cov``) combined with
    the fields' read (mean 0, covariance ``focal_prior_cov`` [2 x 2]) by their information: the combined log
    scales [2], their covariance [2 x 2] and the read's 1-sigmas [2] (0, 0 and inf for a held one)."""
    combined, scale_cov, read_sigma = np.zeros(2), np.zeros((2, 2)), np.full(2, np.inf)
    read_info = np.linalg.inv(read_cov)
    posterior = np.linalg.inv(read_info + np.linalg.inv(focal_prior_cov[np.ix_(free, free)]))
    combined[free] = posterior @ (read_info @ read_scales[free])
    scale_cov[np.ix_(free, free)] = posterior
    read_sigma[free] = np.sqrt(np.diag(read_cov))
    return combined, scale_cov, read_sigma


def _rotation_covariance(H: np.ndarray, scale_cov: np.ndarray, free: np.ndarray, n: int) -> np.ndarray:
    """R's covariance [3 x 3] from the Hessian ``H`` over (R, the ``n`` free log scales) at the fit, with
    the scales' covariance ``scale_cov`` taken in (infinite where R's block is singular)."""
    try:
        inverse = np.linalg.inv(H[:3, :3])
    except np.linalg.LinAlgError:
        inverse = np.eye(3) * np.inf
    if not n:
        return inverse
    A = inverse @ H[:3, 3:]
    return inverse + A @ scale_cov[np.ix_(free, free)] @ A.T
