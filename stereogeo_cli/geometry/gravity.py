"""Gravity as the world-UP direction in camera coordinates (x right, y down, z forward).

``g = (-sin(roll)·cos(pitch), -cos(roll)·cos(pitch), sin(pitch))``; a level camera has g = (0, -1, 0),
pitch > 0 looks up. Angles are radians unless a name ends in ``_deg``.
"""

from __future__ import annotations

import math

import numpy as np


def gravity_from_roll_pitch(roll: np.ndarray | float, pitch: np.ndarray | float) -> np.ndarray:
    """Up vector(s) [... x 3] from roll and pitch in radians."""
    roll, pitch = np.asarray(roll, dtype=float), np.asarray(pitch, dtype=float)
    cp = np.cos(pitch)
    return np.stack([-np.sin(roll) * cp, -np.cos(roll) * cp, np.sin(pitch)], axis=-1)


def roll_pitch_from_gravity(gravity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(roll, pitch) in radians from up vector(s) [... x 3] (normalised first)."""
    g = np.asarray(gravity, dtype=float)
    g = g / np.linalg.norm(g, axis=-1, keepdims=True)
    pitch = np.arcsin(np.clip(g[..., 2], -1.0, 1.0))
    roll = np.arctan2(-g[..., 0], -g[..., 1])
    return roll, pitch


def tangent_basis(gravity: np.ndarray) -> np.ndarray:
    """An orthonormal basis [3 x 2] of the plane tangent to the unit sphere at ``gravity`` [3].

    The first column is d g / d pitch and the second is (d g / d roll) / cos(pitch), so the tangent
    coordinates are (pitch, roll·cos(pitch)) to first order. Away from the poles (|pitch| < 90°) the
    basis is smooth; at a pole any orthonormal pair is returned. (In plain floats: the fits call it at every
    step, and numpy's small-array calls cost more than the arithmetic.)
    """
    x, y, z = np.asarray(gravity, dtype=float).tolist()
    length = math.sqrt(x * x + y * y + z * z)
    x, y, z = x / length, y / length, z / length
    norm = math.sqrt(x * x + y * y)  # of the horizontal part
    if norm < 1e-12:  # looking straight up or down
        return np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])
    # g = (-sin r cos p, -cos r cos p, sin p): d/dp = (sin r sin p, cos r sin p, cos p)
    hx, hy = x / norm, y / norm  # = (-sin r, -cos r)
    # columns: d g / d pitch, and (-cos r, sin r, 0) = (d g / d roll) / cos p
    return np.array([[-hx * z, hy], [-hy * z, -hx], [norm, 0.0]])


def retract_on_sphere(gravity: np.ndarray, delta: np.ndarray, basis: np.ndarray | None = None) -> np.ndarray:
    """Move a unit vector [3] along the sphere by the tangent step ``delta`` [2] (exponential map; in plain
    floats, as :func:`tangent_basis`)."""
    (b00, b01), (b10, b11), (b20, b21) = (tangent_basis(gravity) if basis is None else basis).tolist()
    d1, d2 = np.asarray(delta, dtype=float).tolist()
    step = (b00 * d1 + b01 * d2, b10 * d1 + b11 * d2, b20 * d1 + b21 * d2)
    angle = math.sqrt(step[0] * step[0] + step[1] * step[1] + step[2] * step[2])
    if angle < 1e-15:
        return np.asarray(gravity, dtype=float).copy()
    c, s = math.cos(angle), math.sin(angle) / angle
    gx, gy, gz = np.asarray(gravity, dtype=float).tolist()
    return np.array([c * gx + s * step[0], c * gy + s * step[1], c * gz + s * step[2]])


def gravity_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle in radians between direction vectors [... x 3]."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    cross = np.linalg.norm(np.cross(a, b), axis=-1)
    return np.arctan2(cross, np.sum(a * b, axis=-1))


def gravity_coupling_error(R: np.ndarray, gravity_left: np.ndarray, gravity_right: np.ndarray) -> float:
    """Angle in radians between ``R @ g_left`` and ``g_right``: 0 for a rig consistent with gravity."""
    return float(gravity_angle(np.asarray(R) @ gravity_left, gravity_right))


def couple_rotation_to_gravity(
    R: np.ndarray, gravity_left: np.ndarray, gravity_right: np.ndarray
) -> np.ndarray:
    """The rotation closest to ``R`` (geodesic angle) that maps ``g_left`` exactly onto ``g_right``.

    Every such rotation R' has R·R'ᵀ taking g_right to R·g_left, so its angle from R is at least the
    coupling error; the minimal rotation Q taking R·g_left onto g_right attains it with R' = Q·R.
    """
    from stereogeo_cli.geometry.rotation import rotation_between_vectors

    a = np.asarray(R, dtype=float) @ gravity_left
    Q = rotation_between_vectors(a, gravity_right)
    return Q @ R
