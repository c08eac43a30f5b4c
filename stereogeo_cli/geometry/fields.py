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


def up_at(gravity: np.ndarray, focal: float, x: np.ndarray, y: np.ndarray, cx: float, cy: float) -> np.ndarray:
    """Up-vector field [... x 2] at pixel coordinates x, y [...]."""
    u, v = _normalised(x, y, focal, cx, cy)
    a = np.stack([gravity[0] - gravity[2] * u, gravity[1] - gravity[2] * v], axis=-1)
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def latitude_at(gravity: np.ndarray, focal: float, x: np.ndarray, y: np.ndarray, cx: float, cy: float) -> np.ndarray:
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
    g = np.asarray(gravity, dtype=float)
    B = tangent_basis(g)  # [3 x 2]
    u, v = _normalised(x, y, focal, cx, cy)
    n = u.shape[0]

    # up = a / |a|, a = (g_x - g_z u, g_y - g_z v)
    a = np.stack([g[0] - g[2] * u, g[1] - g[2] * v], axis=-1)
    a_norm = np.linalg.norm(a, axis=-1)
    up = a / a_norm[:, None]
    da_dg = np.zeros((n, 2, 3))
    da_dg[:, 0, 0] = 1.0
    da_dg[:, 1, 1] = 1.0
    da_dg[:, 0, 2] = -u
    da_dg[:, 1, 2] = -v
    da_dlogf = np.stack([g[2] * u, g[2] * v], axis=-1)  # du/dlogf = -u
    proj = (np.eye(2)[None] - up[:, :, None] * up[:, None, :]) / a_norm[:, None, None]
    J_up = np.empty((n, 2, 3))
    J_up[:, :, :2] = proj @ (da_dg @ B)
    J_up[:, :, 2] = np.einsum("nij,nj->ni", proj, da_dlogf)

    # sin(lat) = g · p/|p|, p = (u, v, 1)
    p_norm = np.sqrt(u * u + v * v + 1.0)
    ray = np.stack([u, v, np.ones_like(u)], axis=-1) / p_norm[:, None]
    sin_lat = ray @ g
    J_lat = np.empty((n, 3))
    J_lat[:, :2] = ray @ B
    # d ray / d log f = (I - ray rayᵀ)(-u, -v, 0)/|p|
    dp = np.stack([-u, -v, np.zeros_like(u)], axis=-1)
    dray = (dp - ray * np.sum(ray * dp, axis=-1, keepdims=True)) / p_norm[:, None]
    J_lat[:, 2] = dray @ g
    return up, sin_lat, J_up, J_lat
