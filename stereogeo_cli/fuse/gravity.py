"""Gravity shared by both cameras: each camera's gravity updated with the other camera's, seen through R.

Both cameras of a rig see the same world-up, so ``g_right = R·g_left``. The refiner gives each camera its
own estimate with a covariance over θ = (δ_pitch, δ_roll·cos(pitch), log f). Once the fusion knows R (to a
fraction of a degree where there are matches), the right camera's up vector mapped by Rᵀ is a second
measurement of the left camera's, and the other way round. Each camera's gravity becomes the
inverse-variance weighted mean of the two, on the sphere:

- the measurement's covariance is the other camera's gravity covariance carried into this camera's tangent
  plane, plus R's own isotropic uncertainty;
- the weights ignore that the two cameras' field errors are correlated (they look at much the same scene),
  which keeps each estimate between the two; a correlation-aware update extrapolates beyond them when
  one camera is much surer than the other, and was worse on the validation renders;
- the reported covariance does count the correlation ρ (cross-covariance ρ·(Σ_this + Σ_other)/2): two
  equally good cameras give the average with a variance shrunk by (1 + ρ)/2, not by 2;
- the focal length stays as it is (its covariance with the gravity is carried along).
"""

from __future__ import annotations

import numpy as np

from stereogeo_cli.geometry.gravity import gravity_angle, retract_on_sphere, tangent_basis
from stereogeo_cli.refine.lm import CameraFit


def _log_map(g: np.ndarray, other: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """Tangent coordinates [2] at unit ``g`` of the unit vector ``other`` (exact geodesic length)."""
    v = other - float(g @ other) * g
    norm = np.linalg.norm(v)
    if norm < 1e-15:
        return np.zeros(2)
    return basis.T @ v * (float(gravity_angle(g, other)) / norm)


def _update(fit: CameraFit, seen: np.ndarray, seen_cov: np.ndarray, seen_basis: np.ndarray,
            rotation_var: float, correlation: float) -> CameraFit:  # fmt: skip
    g = np.asarray(fit.gravity_up, dtype=float)
    B = tangent_basis(g)
    P = B.T @ seen_basis  # the other tangent plane's coordinates → this one's
    other = P @ seen_cov @ P.T
    cov = np.asarray(fit.covariance, dtype=float)
    own = cov[:2, :2]
    measured = other + rotation_var * np.eye(2)
    gain = own @ np.linalg.inv(own + measured)  # inverse-variance weights: always between the two
    step = gain @ _log_map(g, seen, B)
    keep = np.eye(2) - gain
    cross = 0.5 * correlation * (own + other)  # the two cameras' gravity errors are correlated
    new_cov = cov.copy()
    shared = keep @ own @ keep.T + gain @ measured @ gain.T + keep @ cross @ gain.T + gain @ cross @ keep.T
    new_cov[:2, :2] = 0.5 * (shared + shared.T)
    new_cov[2, :2] = new_cov[:2, 2] = cov[2, :2] @ (keep + correlation * gain).T
    return fit.with_gravity(retract_on_sphere(g, step, B), new_cov)


def share_gravity(
    left: CameraFit, right: CameraFit, R: np.ndarray, rotation_sigma_rad: float, correlation: float
) -> tuple[CameraFit, CameraFit]:
    """Both cameras' fits, each updated with the other camera's gravity (``X_right = R @ X_left``).

    Args:
        rotation_sigma_rad: R's 1-sigma about any one axis (radians; isotropic).
        correlation: ρ in [0, 1) between the two cameras' gravity errors (measured on validation renders).
    Returns the fits unchanged when a covariance or R's sigma is not finite (nothing to weigh them by).
    """
    R = np.asarray(R, dtype=float)
    covs = [np.asarray(f.covariance, dtype=float)[:2, :2] for f in (left, right)]
    if not (np.isfinite(rotation_sigma_rad) and all(np.isfinite(c).all() for c in covs)):
        return left, right
    if not 0.0 <= correlation < 1.0:
        raise ValueError(f"the cameras' gravity correlation must be in [0, 1), got {correlation}")
    var = float(rotation_sigma_rad) ** 2
    new_left = _update(left, R.T @ right.gravity_up, covs[1], R.T @ tangent_basis(right.gravity_up), var,
                       correlation)  # fmt: skip
    new_right = _update(right, R @ left.gravity_up, covs[0], R @ tangent_basis(left.gravity_up), var,
                        correlation)  # fmt: skip
    return new_left, new_right
