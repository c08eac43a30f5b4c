"""Perspective fields (up-vector and latitude) of a pinhole camera, and their analytic Jacobians.

With normalised coordinates ``(u, v) = ((x - cx)/f, (y - cy)/f)`` and up vector g [3]:

- up:       ``up(x, y) = normalize((g_x, g_y) - g_z·(u, v))``  (unit 2-vector in image axes)
- latitude: ``lat(x, y) = asin(g · normalize(u, v, 1))``       (radians, 0 on the horizon)

Jacobians are taken with respect to θ = (δ₁, δ₂, log f), where δ is the tangent step of gravity on the
sphere in the basis of :func:`stereogeo_cli.geometry.gravity.tangent_basis`.
"""

from __future__ import annotations

import numpy as np

from stereogeo_cli.geometry.camera import principal_point
from stereogeo_cli.geometry.gravity import tangent_basis


def pixel_grid(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Integer pixel-centre coordinates (x, y), each [H x W]."""
    return np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))


def _normalised(x: np.ndarray, y: np.ndarray, focal: float, cx: float, cy: float):
    return (np.asarray(x, dtype=float) - cx) / focal, (np.asarray(y, dtype=float) - cy) / focal


def up_at(
    gravity: np.ndarray, focal: float, x: np.ndarray, y: np.ndarray, cx: float, cy: float
) -> np.ndarray:
    """Up-vector field [... x 2] at pixel coordinates x, y [...]."""
    u, v = _normalised(x, y, focal, cx, cy)
    a = np.stack([gravity[0] - gravity[2] * u, gravity[1] - gravity[2] * v], axis=-1)
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def latitude_at(
    gravity: np.ndarray, focal: float, x: np.ndarray, y: np.ndarray, cx: float, cy: float
) -> np.ndarray:
    """Latitude field in radians [...] at pixel coordinates x, y [...]."""
    u, v = _normalised(x, y, focal, cx, cy)
    s = (gravity[0] * u + gravity[1] * v + gravity[2]) / np.sqrt(u * u + v * v + 1.0)
    return np.arcsin(np.clip(s, -1.0, 1.0))


def up_field(gravity: np.ndarray, focal: float, width: int, height: int) -> np.ndarray:
    """Up-vector field [H x W x 2] of a whole image with the principal point at (w/2, h/2)."""
    x, y = pixel_grid(width, height)
    return up_at(np.asarray(gravity, dtype=float), focal, x, y, *principal_point(width, height))


def latitude_field(gravity: np.ndarray, focal: float, width: int, height: int) -> np.ndarray:
    """Latitude field [H x W] in radians of a whole image with the principal point at (w/2, h/2)."""
    x, y = pixel_grid(width, height)
    return latitude_at(np.asarray(gravity, dtype=float), focal, x, y, *principal_point(width, height))


def up_and_sin_latitude(
    gravity: np.ndarray, focal: float, x: np.ndarray, y: np.ndarray, cx: float, cy: float
) -> tuple[np.ndarray, np.ndarray]:
    """Up field [N x 2] and sine of the latitude [N] at pixel coordinates x, y [N] (the refiner's model)."""
    gx, gy, gz = np.asarray(gravity, dtype=float).tolist()
    u, v = _normalised(x, y, focal, cx, cy)
    a_x, a_y = gx - gz * u, gy - gz * v
    inverse_norm = 1.0 / np.sqrt(a_x * a_x + a_y * a_y)
    up = np.stack([a_x * inverse_norm, a_y * inverse_norm], axis=-1)
    sin_lat = (gx * u + gy * v + gz) / np.sqrt(u * u + v * v + 1.0)
    return up, sin_lat


def fields_and_jacobians(
    gravity: np.ndarray, focal: float, x: np.ndarray, y: np.ndarray, cx: float, cy: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Fields at N pixels and their Jacobians with respect to θ = (δ₁, δ₂, log f).

    Args:
        gravity: unit up vector [3]; focal: pixels; x, y: pixel coordinates [N]; cx, cy: principal point.
    Returns:
        up [N x 2], sin_latitude [N], d up / dθ [N x 2 x 3], d sin(latitude) / dθ [N x 3].
        The latitude enters as its sine, which is what the refiner's residual uses.
    """
    up, sin_lat, perp, k, J_lat = fields_and_jacobian_factors(gravity, focal, x, y, cx, cy)
    return up, sin_lat, perp[:, :, None] * k[:, None, :], J_lat


def fields_and_jacobian_factors(
    gravity: np.ndarray, focal: float, x: np.ndarray, y: np.ndarray, cx: float, cy: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """As :func:`fields_and_jacobians`, with the up Jacobian in its rank-one form d up / dθ = perp·kᵀ.

    Returns up [N x 2], sin_latitude [N], perp [N x 2] (the unit normal of up), k [N x 3], and
    d sin(latitude) / dθ [N x 3]. The refiner uses the factors: |perp| = 1 makes JᵀJ = k·kᵀ.
    """
    g = np.asarray(gravity, dtype=float)
    (b00, b01), (b10, b11), (b20, b21) = tangent_basis(g).tolist()  # the basis B [3 x 2], as floats
    gx, gy, gz = g.tolist()
    u, v = _normalised(x, y, focal, cx, cy)

    # up = a/|a| with a = (g_x - g_z·u, g_y - g_z·v). For a 2-vector, I - up·upᵀ = perp·perpᵀ with
    # perp = (-up_y, up_x), so d up = perp · (perpᵀ d a) / |a|: a rank-one Jacobian per pixel.
    a_x, a_y = gx - gz * u, gy - gz * v
    inverse_norm = 1.0 / np.sqrt(a_x * a_x + a_y * a_y)
    up_x, up_y = a_x * inverse_norm, a_y * inverse_norm
    up = np.stack([up_x, up_y], axis=-1)
    perp = np.stack([-up_y, up_x], axis=-1)
    perp_uv = up_x * v - up_y * u
    k = np.empty((len(u), 3))
    # perpᵀ d a / d g = (perp_x, perp_y, -perp·(u, v)), times B; d(u, v)/d log f = -(u, v)
    k[:, 0] = (b10 * up_x - b00 * up_y - b20 * perp_uv) * inverse_norm
    k[:, 1] = (b11 * up_x - b01 * up_y - b21 * perp_uv) * inverse_norm
    k[:, 2] = gz * perp_uv * inverse_norm

    # sin(lat) = g · ray, ray = p/|p|, p = (u, v, 1); d ray / d log f = (I - ray·rayᵀ)(-u, -v, 0)/|p|
    inverse_p = 1.0 / np.sqrt(u * u + v * v + 1.0)
    g_uv = gx * u + gy * v
    sin_lat = (g_uv + gz) * inverse_p
    J_lat = np.empty((len(u), 3))
    J_lat[:, 0] = (b00 * u + b10 * v + b20) * inverse_p
    J_lat[:, 1] = (b01 * u + b11 * v + b21) * inverse_p
    ray_uv = (u * u + v * v) * inverse_p  # ray · (u, v, 0)
    J_lat[:, 2] = (sin_lat * ray_uv - g_uv) * inverse_p
    return up, sin_lat, perp, k, J_lat
