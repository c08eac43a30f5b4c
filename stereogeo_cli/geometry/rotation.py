"""Rotations: quaternions (w, x, y, z), matrices, axis-angle and the angles between them."""

from __future__ import annotations

import math

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix [3 x 3] of v [3]: skew(v) @ w == cross(v, w)."""
    x, y, z = np.asarray(v, dtype=float).tolist()
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def rotation_from_axis_angle(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation vector [3] (axis × angle in radians) → matrix [3 x 3] (in plain floats, as
    :func:`quaternion_from_rotation`)."""
    x, y, z = np.asarray(rotvec, dtype=float).tolist()
    angle = math.sqrt(x * x + y * y + z * z)
    if angle < 1e-12:
        return np.array([[1.0, -z, y], [z, 1.0, -x], [-y, x, 1.0]])
    x, y, z = x / angle, y / angle, z / angle
    s, c = math.sin(angle), 1.0 - math.cos(angle)
    # I + sin·K + (1 − cos)·K² with K = [axis]ₓ, K² = axis·axisᵀ − I
    return np.array(
        [
            [1.0 + c * (x * x - 1.0), -s * z + c * x * y, s * y + c * x * z],
            [s * z + c * x * y, 1.0 + c * (y * y - 1.0), -s * x + c * y * z],
            [-s * y + c * x * z, s * x + c * y * z, 1.0 + c * (z * z - 1.0)],
        ]
    )


def axis_angle_from_rotation(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rotation_from_axis_angle` (via the quaternion, stable near 0 and π)."""
    w, x, y, z = quaternion_from_rotation(R).tolist()
    s = math.sqrt(x * x + y * y + z * z)
    if s < 1e-12:
        return np.array([2.0 * x, 2.0 * y, 2.0 * z])
    scale = 2.0 * math.atan2(s, w) / s
    return np.array([x * scale, y * scale, z * scale])


def quaternion_to_rotation(q: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) [... x 4] → rotation matrix [... x 3 x 3] (normalised first)."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    R = np.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        axis=-1,
    )  # fmt: skip
    return R.reshape(q.shape[:-1] + (3, 3))


def quaternion_from_rotation(R: np.ndarray) -> np.ndarray:
    """Rotation matrix [3 x 3] → unit quaternion (w, x, y, z) with w ≥ 0 (Shepperd's method; in plain floats:
    the fits call it at every step, and numpy's small-array calls cost more than the arithmetic)."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = np.asarray(R, dtype=float).tolist()
    trace = r00 + r11 + r22
    candidates = (trace, r00, r11, r22)
    k = candidates.index(max(candidates))  # the first of equal ones, as numpy's argmax
    if k == 0:
        w = 0.5 * math.sqrt(max(1.0 + trace, 0.0))
        q = [w, (r21 - r12) / (4 * w), (r02 - r20) / (4 * w), (r10 - r01) / (4 * w)]
    else:
        rows = ((r00, r01, r02), (r10, r11, r12), (r20, r21, r22))
        i = k - 1
        j, m = (i + 1) % 3, (i + 2) % 3
        s = 0.5 * math.sqrt(max(1.0 + rows[i][i] - rows[j][j] - rows[m][m], 0.0))
        q = [0.0] * 4
        q[1 + i] = s
        q[0] = (rows[m][j] - rows[j][m]) / (4 * s)
        q[1 + j] = (rows[j][i] + rows[i][j]) / (4 * s)
        q[1 + m] = (rows[m][i] + rows[i][m]) / (4 * s)
    norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    sign = 1.0 if q[0] >= 0 else -1.0
    return np.array([sign * v / norm for v in q])


def rotation_angle(R: np.ndarray) -> float:
    """Angle in radians of a rotation matrix [3 x 3] (stable for small angles)."""
    return float(np.linalg.norm(axis_angle_from_rotation(R)))


def rotation_error(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle in radians of the rotation taking R_b to R_a (the relative-rotation error)."""
    return rotation_angle(np.asarray(R_a) @ np.asarray(R_b).T)


def closest_rotation(M: np.ndarray) -> np.ndarray:
    """The rotation nearest to M [3 x 3] in the Frobenius norm (SVD projection onto SO(3))."""
    U, _, Vt = np.linalg.svd(np.asarray(M, dtype=float))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def rotation_between_vectors(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The minimal rotation [3 x 3] taking direction a [3] onto direction b [3]."""
    a = np.asarray(a, dtype=float) / np.linalg.norm(a)
    b = np.asarray(b, dtype=float) / np.linalg.norm(b)
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(a @ b)
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        # opposite vectors: half-turn about any axis perpendicular to a
        helper = np.eye(3)[int(np.argmin(np.abs(a)))]
        perp = np.cross(a, helper)
        return rotation_from_axis_angle(perp / np.linalg.norm(perp) * np.pi)
    return rotation_from_axis_angle(axis / s * np.arctan2(s, c))
