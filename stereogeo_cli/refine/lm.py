"""Levenberg–Marquardt fit of one camera's focal length and gravity to its perspective fields.

Parameters θ = (gravity on the unit sphere S², log f). Residuals per field sample:
``r_up = up_pred - up(θ)`` (2-D) and ``r_lat = sin(lat_pred) - sin(lat(θ))``. The cost is the mean over
samples of ``c_up·ρ(|r_up|²) + c_lat·ρ(r_lat²)`` with confidences c and GeoCalib's scaled Huber ρ on the
squared residual. Steps that raise the cost are rejected (GeoCalib accepts every step).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from stereogeo_cli.geometry.camera import ResizeCrop, focal_from_vfov, principal_point, vfov_from_focal
from stereogeo_cli.geometry.fields import fields_and_jacobian_factors, up_and_sin_latitude
from stereogeo_cli.geometry.gravity import (
    gravity_from_roll_pitch,
    retract_on_sphere,
    roll_pitch_from_gravity,
    tangent_basis,
)
from stereogeo_cli.refine.levenberg import Settings, covariance, levenberg_marquardt
from stereogeo_cli.settings import resolve

default_conf = {
    "max_iterations": 30,  # LM steps, accepted or rejected
    "lambda_init": 0.1,  # initial damping of δ = -(H + λ·D)⁻¹ g (D: the IRLS curvature's diagonal)
    "lambda_max": 1e8,  # give up once a step cannot lower the cost even this damped
    "huber_scale": 0.01,  # residual size where the Huber loss turns from quadratic to linear
    "relative_tolerance": 1e-7,  # stop when an accepted step lowers the cost by less than this share
    # Newton steps with the Huber loss's own curvature once a kept step lowers the cost by less than this
    # share (refine/levenberg.py), IRLS steps before
    "curvature_switch": 0.1,
    "max_samples": 3000,  # fields are sub-sampled on a regular grid down to about this many pixels
    "min_vfov_deg": 5.0,  # log f is clamped so the vFoV stays within these bounds
    "max_vfov_deg": 150.0,
    # "fields": roll/pitch read off the fields, focal by a 1-D search; "level": level, f = 0.7·max(w, h)
    "init": "fields",
    "init_vfov_grid_deg": (15, 25, 35, 45, 55, 65, 80, 95, 110, 130),  # candidates for the focal search
    # multiplies the 1-sigma figures (network errors are spatially correlated): one factor, or three for
    # (roll, pitch, vFoV)
    "sigma_inflation": 1.0,
}


def parse_sigma_inflation(text: str, what: str = "sigma inflation") -> float | tuple[float, float, float]:
    """A model's ``sigma_inflation`` (or ``photo_sigma_scale``) metadata: one factor ``"38"`` or three
    ``"37.8,43.1,33.2"`` for roll, pitch and vFoV. Raises ValueError unless every factor is a positive
    number."""
    try:
        values = tuple(float(part) for part in str(text).split(","))
    except ValueError:
        values = ()
    if len(values) not in (1, 3) or not all(np.isfinite(v) and v > 0 for v in values):
        raise ValueError(f"{what} must be one or three positive numbers (roll,pitch,vfov), got {text!r}")
    return values[0] if len(values) == 1 else values


@dataclass
class CameraFit:
    """One camera's refined parameters and their uncertainty: the focal length, gravity and the covariance
    of θ = (δ_pitch, δ_roll·cos(pitch), log f). Roll, pitch, vFoV and the 1-sigma figures are derived from
    these (properties), so a new focal, gravity or covariance moves them all."""

    width: int
    height: int
    focal_px: float
    gravity_up: np.ndarray  # [3] unit world-UP in camera coordinates
    covariance: np.ndarray  # [3 x 3] of θ = (δ_pitch, δ_roll·cos(pitch), log f)
    cost: float
    iterations: int
    converged: bool
    history: list[float] = field(default_factory=list)  # cost after every accepted step

    @property
    def roll_deg(self) -> float:
        return float(np.degrees(roll_pitch_from_gravity(self.gravity_up)[0]))

    @property
    def pitch_deg(self) -> float:
        return float(np.degrees(roll_pitch_from_gravity(self.gravity_up)[1]))

    @property
    def vfov_deg(self) -> float:
        return float(np.degrees(vfov_from_focal(self.focal_px, self.height)))

    @property
    def sigma(self) -> dict[str, float]:
        """The 1-sigma figures: ``focal_px``, ``vfov_deg``, ``roll_deg``, ``pitch_deg``."""
        pitch = float(roll_pitch_from_gravity(self.gravity_up)[1])
        return _sigmas(self.covariance, self.focal_px, self.height, pitch)

    def with_focal(self, focal: float, width: int | None = None, height: int | None = None) -> CameraFit:
        """This fit with another focal (and image size); the relative sigma of the focal is kept."""
        width, height = width or self.width, height or self.height
        return replace(self, width=width, height=height, focal_px=focal)

    def with_gravity(self, gravity: np.ndarray, covariance: np.ndarray) -> CameraFit:
        """This fit with another gravity and covariance of θ (e.g. after evidence from the other camera), the
        focal kept."""
        g = np.asarray(gravity, dtype=float) / np.linalg.norm(gravity)
        return replace(self, gravity_up=g, covariance=np.asarray(covariance, dtype=float))

    def with_focal_sigma(self, sigma_rel: float) -> CameraFit:
        """This fit with the relative 1-sigma of its focal length set (a focal length held at a value
        combined from other evidence, with that value's sigma): the focal length then owes nothing to this
        fit's gravity, so their cross terms are 0."""
        cov = np.array(self.covariance, dtype=float)
        cov[2, :] = cov[:, 2] = 0.0
        cov[2, 2] = sigma_rel**2
        return self.with_gravity(self.gravity_up, cov)

    def with_new_gravity(self, gravity: np.ndarray, gravity_covariance: np.ndarray) -> CameraFit:
        """This fit with a gravity found from other evidence (e.g. the vertical line segments) and its [2 x 2]
        covariance of (δ_pitch, δ_roll·cos(pitch)), uncorrelated with the focal length, which stays."""
        cov = np.array(self.covariance, dtype=float)
        cov[:2, :] = cov[:, :2] = 0.0
        cov[:2, :2] = gravity_covariance
        return self.with_gravity(gravity, cov)

    def in_original_pixels(self, rc: ResizeCrop) -> CameraFit:
        """This fit, made on a resized and cropped image (e.g. the network input), in the original's pixels.

        Roll and pitch are unchanged (the crop keeps the principal point at the centre); the focal scales
        by the resize; the vFoV follows the original height (a crop changes it).
        """
        return self.with_focal(rc.focal_to_input(self.focal_px), *rc.in_size)

    def to_dict(self) -> dict:
        return {
            "width": self.width,
            "height": self.height,
            "focal_px": self.focal_px,
            "vfov_deg": self.vfov_deg,
            "roll_deg": self.roll_deg,
            "pitch_deg": self.pitch_deg,
            "gravity_up": [float(v) for v in self.gravity_up],
            "sigma": self.sigma,
            "cost": self.cost,
            "iterations": self.iterations,
            "converged": self.converged,
        }


def vfov_sigma_deg(focal: float, height: float, log_focal_sigma: float) -> float:
    """1-sigma of the vFoV in degrees from that of log f: |d vFoV / d log f| = h·f / (f² + h²/4)."""
    return float(np.degrees(height * focal / (focal * focal + height * height / 4.0) * log_focal_sigma))


def _sigmas(cov: np.ndarray, focal: float, height: float, pitch: float) -> dict[str, float]:
    """The 1-sigma figures (pixels and degrees) of a covariance of θ = (δ_pitch, δ_roll·cos(pitch), log f)."""
    sig = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return {
        "focal_px": float(focal * sig[2]),
        "vfov_deg": vfov_sigma_deg(focal, height, sig[2]),
        "roll_deg": float(np.degrees(sig[1] / max(np.cos(pitch), 1e-9))),
        "pitch_deg": float(np.degrees(sig[0])),
    }


def combine_focal(focal: float, sigma: float, prior_focal: float, prior_sigma: float) -> tuple[float, float]:
    """Two focal estimates with 1-sigmas (pixels) combined in log f by inverse variance: (focal, sigma).

    A non-finite or non-positive ``sigma`` leaves the prior alone."""
    s_prior = prior_sigma / prior_focal
    weights, logs = [1.0 / s_prior**2], [math.log(prior_focal)]
    if math.isfinite(sigma) and sigma > 0:
        weights.append((focal / sigma) ** 2)
        logs.append(math.log(focal))
    combined = math.exp(float(np.dot(weights, logs)) / sum(weights))
    return combined, combined / math.sqrt(sum(weights))


def huber(s: np.ndarray, scale: float) -> np.ndarray:
    """Scaled Huber ρ(s) on squared residuals s: s below scale², 2·scale·√s − scale² above."""
    a2 = scale * scale
    return np.where(s <= a2, s, 2.0 * scale * np.sqrt(np.maximum(s, a2)) - a2)


def huber_weight(s: np.ndarray, scale: float) -> np.ndarray:
    """ρ'(s) of :func:`huber`: 1 below scale², scale/√s above (the IRLS weight)."""
    return scale / np.sqrt(np.maximum(s, scale * scale))


def _sample_grid(height: int, width: int, max_samples: int | None) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices of a regular sub-grid with about ``max_samples`` cells, centred."""
    if not max_samples or height * width <= max_samples:
        return np.arange(height), np.arange(width)
    stride = np.sqrt(height * width / max_samples)
    rows = np.unique(np.round(np.arange(stride / 2 - 0.5, height, stride)).astype(int).clip(0, height - 1))
    cols = np.unique(np.round(np.arange(stride / 2 - 0.5, width, stride)).astype(int).clip(0, width - 1))
    return rows, cols


class _Problem:
    """Residuals, cost and normal equations of one camera on N field samples."""

    def __init__(self, x, y, up, sin_lat, c_up, c_lat, cx, cy, scale, focal_prior, gravity_prior):
        self.x, self.y, self.cx, self.cy, self.scale = x, y, cx, cy, scale
        self.up, self.sin_lat, self.c_up, self.c_lat = up, sin_lat, c_up, c_lat
        self.n = float(len(x))
        self.focal_prior = focal_prior  # (log f0, sigma of log f) or None
        self.gravity_prior = gravity_prior  # (g0 [3], sigma in radians) or None

    @classmethod
    def of(cls, field_samples, line_up, centre, scale, focal_prior, gravity_prior) -> _Problem:
        """The problem of the field samples (x, y, up, latitude, c_up, c_lat) and, where given, the vertical
        line segments' up samples ``line_up`` (x, y, up, weight; no latitude)."""
        samples = field_samples
        if line_up is not None:
            lx, ly, lu, lw = (np.asarray(a, dtype=float) for a in line_up)
            zeros = np.zeros(len(lx))
            more = (lx, ly, lu.reshape(-1, 2), zeros, lw, zeros)
            samples = tuple(np.concatenate(pair) for pair in zip(samples, more, strict=True))
        x, y, up, lat, c_up, c_lat = samples
        return cls(x, y, up, np.sin(lat), c_up, c_lat, *centre, scale, focal_prior, gravity_prior)

    def covariance(self, g: np.ndarray, log_f: float, free: np.ndarray, inflation) -> np.ndarray:
        """The robust (sandwich) covariance of the M-estimator at (g, log f), H⁻¹·M·H⁻¹ with M = Σ gₙgₙᵀ
        (unlike s²·H⁻¹ it stays honest where the Huber weights and confidences make residuals unequal),
        widened by ``inflation`` (one factor, or three for roll, pitch and vFoV)."""
        bread, _, _, meat = self.normal_equations(g, log_f, near=True, meat=True)
        roll_s, pitch_s, vfov_s = np.broadcast_to(np.asarray(inflation, dtype=float), (3,))
        scale = np.array([pitch_s, roll_s, vfov_s])  # in the order of the parameters: pitch, roll, log f
        return covariance(bread, meat, free) * np.outer(scale, scale)

    def _prior_cost(self, g: np.ndarray, log_f: float) -> float:
        cost = 0.0
        if self.focal_prior is not None:
            cost += ((log_f - self.focal_prior[0]) / self.focal_prior[1]) ** 2
        if self.gravity_prior is not None:
            cost += float(np.sum((g - self.gravity_prior[0]) ** 2)) / self.gravity_prior[1] ** 2
        return cost / self.n

    def cost(self, g: np.ndarray, log_f: float) -> float:
        up, sin_lat = up_and_sin_latitude(g, np.exp(log_f), self.x, self.y, self.cx, self.cy)
        r_up = self.up - up
        r_lat = self.sin_lat - sin_lat
        rho_up = huber(np.einsum("ij,ij->i", r_up, r_up), self.scale)
        rho_lat = huber(r_lat * r_lat, self.scale)
        data = (np.dot(self.c_up, rho_up) + np.dot(self.c_lat, rho_lat)) / self.n
        return float(data) + self._prior_cost(g, log_f)

    def normal_equations(self, g: np.ndarray, log_f: float, near: bool = True, meat: bool = False):
        """H [3 x 3], the gradient [3] (both ×N/2) and the damping's diagonal [3] of the cost, and with
        ``meat`` Σ gₙgₙᵀ over the samples' gradients (the sandwich covariance's, H⁻¹·meat·H⁻¹), else None.

        H is the Gauss–Newton Hessian with the IRLS weights or, ``near`` the minimum, with the Huber loss's
        own curvature (refine/levenberg.py): where the loss is linear it has none along the residual, so H
        keeps the part of an up sample's Jacobian across its residual there, and nothing of a latitude
        sample's. The damping's scale is always the IRLS curvature's (near the minimum too, a sample whose
        residual crosses into the linear part must not let a step run along it).
        """
        up, sin_lat, perp, k, J_lat = fields_and_jacobian_factors(
            g, np.exp(log_f), self.x, self.y, self.cx, self.cy
        )
        r_up = self.up - up
        r_lat = self.sin_lat - sin_lat
        s_up = np.einsum("ij,ij->i", r_up, r_up)
        s_lat = r_lat * r_lat
        w_up = self.c_up * huber_weight(s_up, self.scale)
        w_lat = self.c_lat * huber_weight(s_lat, self.scale)
        # d up / dθ = perp·kᵀ with |perp| = 1, so Jᵀ W J = Σ w k kᵀ and Jᵀ W r = Σ w (perp·r) k.
        # The residual is prediction - model, so its Jacobian is -J.
        r_perp = np.einsum("ij,ij->i", perp, r_up)
        wk = k * w_up[:, None]
        wJ_lat = J_lat * w_lat[:, None]
        grad = -(wk.T @ r_perp + wJ_lat.T @ r_lat)
        damping = np.einsum("ij,ij->j", wk, k) + np.einsum("ij,ij->j", wJ_lat, J_lat)
        if near:
            along = r_perp**2 / np.maximum(s_up, 1e-300)  # (r̂·perp)², the share of J along the residual
            across = np.where(s_up > self.scale**2, 1.0 - along, 1.0)
            H = (wk * across[:, None]).T @ k + (wJ_lat * (s_lat <= self.scale**2)[:, None]).T @ J_lat
        else:
            H = wk.T @ k + wJ_lat.T @ J_lat
        M = None
        if meat:
            per_sample = wk * r_perp[:, None] + wJ_lat * r_lat[:, None]
            M = per_sample.T @ per_sample
        if self.focal_prior is not None:
            info = np.zeros((3, 3))
            info[2, 2] = 1.0 / self.focal_prior[1] ** 2
            H += info
            damping += np.diag(info)
            grad[2] += (log_f - self.focal_prior[0]) * info[2, 2]
            if meat:  # a prior is one more observation with its own variance
                M += info
        if self.gravity_prior is not None:
            B = tangent_basis(g)
            info = np.zeros((3, 3))
            info[:2, :2] = B.T @ B / self.gravity_prior[1] ** 2
            H += info
            damping += np.diag(info)
            grad[:2] += B.T @ (g - self.gravity_prior[0]) / self.gravity_prior[1] ** 2
            if meat:
                M += info
        return H, grad, damping, M


def _parse_focal_prior(prior):
    """A focal prior is a value in pixels (known: held fixed) or (value, sigma) in pixels (soft)."""
    if prior is None:
        return None, None
    if np.ndim(prior) == 0:
        return float(prior), None
    value, sigma = prior
    return float(value), float(sigma)


def _parse_gravity_prior(prior):
    """A gravity prior is an up vector [3] (known: held fixed) or (up [3], sigma in radians) (soft)."""
    if prior is None:
        return None, None
    if isinstance(prior, tuple) and len(prior) == 2 and np.ndim(prior[1]) == 0:
        g = np.asarray(prior[0], dtype=float)
        return g / np.linalg.norm(g), float(prior[1])
    g = np.asarray(prior, dtype=float)
    return g / np.linalg.norm(g), None


def weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """The value below which half the total weight lies."""
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cum, 0.5 * cum[-1])])


def initial_estimate(
    up: np.ndarray,
    latitude: np.ndarray,
    c_up: np.ndarray,
    c_lat: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    width: int,
    height: int,
    *,
    gravity: np.ndarray | None = None,
    focal: float | None = None,
    conf: dict | None = None,
) -> tuple[np.ndarray, float]:
    """A start for the refiner read off the fields: (up vector [3], focal in pixels).

    At the principal point up = normalize(g_x, g_y) and latitude = pitch, whatever the focal: roll and
    pitch are the confidence-weighted medians over the central 20 % of the image. The focal is then
    the best of a few vFoV candidates by the refiner's own cost. Arrays are the N field samples
    (up [N x 2], the others [N]); a known ``gravity`` or ``focal`` is kept.
    """
    conf = resolve(default_conf, conf)
    cx, cy = principal_point(width, height)
    if gravity is None:
        near = (np.abs(x - cx) < 0.1 * width + 1) & (np.abs(y - cy) < 0.1 * height + 1)
        if np.sum(c_up[near]) <= 0 or np.sum(c_lat[near]) <= 0:
            near = np.ones_like(x, dtype=bool)
        roll = np.arctan2(-up[near, 0], -up[near, 1])
        # circular median: unwrap around the weighted mean direction first
        mean_dir = np.arctan2(np.sum(c_up[near] * np.sin(roll)), np.sum(c_up[near] * np.cos(roll)))
        roll = mean_dir + np.angle(np.exp(1j * (roll - mean_dir)))
        roll0 = weighted_median(roll, c_up[near] + 1e-12)
        pitch0 = weighted_median(latitude[near], c_lat[near] + 1e-12)
        gravity = gravity_from_roll_pitch(roll0, pitch0)
    if focal is None:
        problem = _Problem(x, y, up, np.sin(latitude), c_up, c_lat, cx, cy, conf["huber_scale"], None, None)
        candidates = np.log(focal_from_vfov(np.radians(np.asarray(conf["init_vfov_grid_deg"])), height))
        focal = float(np.exp(min(candidates, key=lambda lf: problem.cost(gravity, lf))))
    return np.asarray(gravity, dtype=float), float(focal)


def refine_camera(
    up: np.ndarray,
    latitude: np.ndarray,
    up_confidence: np.ndarray | None = None,
    latitude_confidence: np.ndarray | None = None,
    *,
    focal_prior=None,
    gravity_prior=None,
    image_size: tuple[int, int] | None = None,
    pixel_xy: tuple[np.ndarray, np.ndarray] | None = None,
    focal_init: float | None = None,
    gravity_init: np.ndarray | None = None,
    line_up: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None,
    samples: FieldSamples | None = None,
    conf: dict | None = None,
) -> CameraFit:
    """Fit focal length and gravity to one camera's perspective fields.

    Args:
        up: [H x W x 2] predicted up-vector field (unit 2-vectors, image axes x right, y down).
        latitude: [H x W] predicted latitude in radians.
        up_confidence, latitude_confidence: [H x W] weights in [0, 1] (default: all ones).
        focal_prior: known focal in pixels (held fixed), or (focal, sigma) in pixels (a soft prior).
        gravity_prior: known up vector [3] (held fixed), or (up [3], sigma in radians) (a soft prior).
        image_size: (width, height) of the image the fields describe; default (W, H). The principal
            point is at (width/2, height/2).
        pixel_xy: pixel coordinates (x [H x W], y [H x W]) of every field cell in that image, when the
            fields are not one cell per pixel (e.g. a network's stride-4 output); default the pixel grid.
        focal_init, gravity_init: a start (e.g. from the pose head); otherwise per ``conf["init"]``.
        line_up: more up-direction samples besides the fields' (x [N], y [N], unit up [N x 2], weight [N]),
            e.g. vertical line segments (``refine/lines.py``); they do not take part in the start.
        samples: :func:`field_samples` of these fields and ``conf`` where the caller has them already (a
            camera is fitted several times over: with a held focal length, with its vertical segments).
        conf: overrides of :data:`default_conf`.
    Returns:
        A :class:`CameraFit` in the pixels of ``image_size``.
    """
    conf = resolve(default_conf, conf)
    latitude = np.asarray(latitude, dtype=float)
    width, height = (latitude.shape[1], latitude.shape[0]) if image_size is None else image_size
    cx, cy = principal_point(width, height)
    if samples is None:
        samples = field_samples(up, latitude, up_confidence, latitude_confidence, pixel_xy, conf)
    cu, cl = samples[4:]

    focal_value, focal_sigma = _parse_focal_prior(focal_prior)
    gravity_value, gravity_sigma = _parse_gravity_prior(gravity_prior)
    fix_focal = focal_value is not None and focal_sigma is None
    fix_gravity = gravity_value is not None and gravity_sigma is None
    problem = _Problem.of(
        samples, line_up, (cx, cy), conf["huber_scale"],
        None if focal_sigma is None else (np.log(focal_value), focal_sigma / focal_value),
        None if gravity_sigma is None else (gravity_value, gravity_sigma),
    )  # fmt: skip

    log_f_bounds = _log_focal_bounds(height, conf)
    g = gravity_init if gravity_init is not None else gravity_value
    log_f = focal_init if focal_init is not None else focal_value
    g, log_f = _start(g, log_f, samples, width, height, conf)
    log_f = float(np.clip(log_f, *log_f_bounds))

    free = np.array([not fix_gravity, not fix_gravity, not fix_focal])
    usable = bool(np.any(cu > 0) or np.any(cl > 0))
    fit = _fit(problem, (g, log_f), free, fix_gravity, log_f_bounds, usable, conf)
    g, log_f = fit.x
    return CameraFit(
        width=int(width),
        height=int(height),
        focal_px=float(np.exp(log_f)),
        gravity_up=g,
        covariance=_fit_covariance(problem, g, log_f, free, usable, conf),
        cost=fit.cost,
        iterations=fit.iterations,
        converged=fit.converged,
        history=fit.history,
    )


def _log_focal_bounds(height: int, conf: dict) -> tuple[float, float]:
    """The (lowest, highest) log f the fit may take: the focal lengths of the widest and the narrowest
    vFoV allowed (``conf["max_vfov_deg"]``, ``conf["min_vfov_deg"]``) at this image height."""
    log_f_min = float(np.log(focal_from_vfov(np.radians(conf["max_vfov_deg"]), height)))
    log_f_max = float(np.log(focal_from_vfov(np.radians(conf["min_vfov_deg"]), height)))
    return log_f_min, log_f_max


def _fit(problem: _Problem, start, free: np.ndarray, fix_gravity: bool, log_f_bounds, usable: bool, conf):
    """The Levenberg–Marquardt fit of (gravity, log f) from ``start``: gravity moves on the unit sphere
    (unless held), log f within ``log_f_bounds``, only the ``free`` parameters step, and no step is taken
    where no sample weighs anything (not ``usable``)."""
    log_f_min, log_f_max = log_f_bounds

    def retract(state, step):
        g, log_f = state
        g_new = retract_on_sphere(g, step[:2]) if not fix_gravity else g
        return g_new, float(np.clip(log_f + step[2], log_f_min, log_f_max))

    settings = Settings(
        max_iterations=conf["max_iterations"] if usable else 0, lambda_init=conf["lambda_init"],
        lambda_max=conf["lambda_max"], relative_tolerance=conf["relative_tolerance"],
        curvature_switch=conf["curvature_switch"],
    )  # fmt: skip
    return levenberg_marquardt(
        start, lambda s: problem.cost(*s), lambda s, near: problem.normal_equations(*s, near=near),
        retract, settings, free,
    )  # fmt: skip


def _fit_covariance(problem: _Problem, g, log_f: float, free: np.ndarray, usable: bool, conf) -> np.ndarray:
    """The covariance of θ at the fit: the problem's robust one, widened by ``conf["sigma_inflation"]``;
    without a usable sample, infinite for the free parameters (0 for the held ones)."""
    if usable:
        return problem.covariance(g, log_f, free, conf["sigma_inflation"])
    cov = np.zeros((3, 3))
    cov[np.ix_(free, free)] = np.inf
    return cov


FieldSamples = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def field_samples(up, latitude, up_confidence, latitude_confidence, pixel_xy, conf: dict) -> FieldSamples:
    """The fields sub-sampled on a regular grid of about ``conf["max_samples"]`` cells: (x, y, up [N x 2],
    latitude, c_up, c_lat), unit up vectors, and cells with a non-finite or null up vector weighing 0
    (``conf``: the refiner's, :data:`default_conf` and its overrides)."""
    up, latitude = np.asarray(up, dtype=float), np.asarray(latitude, dtype=float)
    H_, W_ = latitude.shape
    if up.shape != (H_, W_, 2):
        raise ValueError(f"up field must be {H_}x{W_}x2 to match the latitude field, got {up.shape}")
    c_up = np.ones((H_, W_)) if up_confidence is None else np.asarray(up_confidence, dtype=float)
    c_lat = np.ones((H_, W_)) if latitude_confidence is None else np.asarray(latitude_confidence, dtype=float)
    if pixel_xy is None:
        xs, ys = np.meshgrid(np.arange(W_, dtype=float), np.arange(H_, dtype=float))
    else:
        xs, ys = (np.asarray(a, dtype=float) for a in pixel_xy)
    rows, cols = _sample_grid(H_, W_, conf["max_samples"])
    sel = np.ix_(rows, cols)
    x, y = xs[sel].ravel(), ys[sel].ravel()
    up_s = up[sel].reshape(-1, 2)
    norm = np.linalg.norm(up_s, axis=1, keepdims=True)
    up_s = up_s / np.maximum(norm, 1e-12)
    lat_s = latitude[sel].ravel()
    cu, cl = c_up[sel].ravel(), c_lat[sel].ravel()
    valid = np.isfinite(up_s).all(axis=1) & np.isfinite(lat_s) & (norm[:, 0] > 1e-6)
    cu, cl = np.where(valid, cu, 0.0), np.where(valid, cl, 0.0)
    up_s, lat_s = np.where(valid[:, None], up_s, 0.0), np.where(valid, lat_s, 0.0)
    return x, y, up_s, lat_s, cu, cl


def _start(g, focal, field_samples, width, height, conf) -> tuple[np.ndarray, float]:
    """The refiner's start (unit up vector, log f): a given gravity and focal are kept; the missing ones are
    read off the fields (``conf["init"]`` "fields") or taken level with f = 0.7·max(w, h) ("level")."""
    if g is None and conf["init"] != "fields":
        g = np.array([0.0, -1.0, 0.0])
    if focal is None and conf["init"] != "fields":
        focal = 0.7 * max(width, height)
    if g is None or focal is None:
        g, focal = initial_estimate(
            *field_samples[2:], *field_samples[:2], width, height, gravity=g, focal=focal, conf=conf
        )
    g = np.asarray(g, dtype=float)
    return g / np.linalg.norm(g), float(np.log(focal))
