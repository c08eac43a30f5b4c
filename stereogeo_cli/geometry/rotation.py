"""Rotations: quaternions (w, x, y, z), matrices, axis-angle and the angles between them."""

from __future__ import annotations

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix [3 x 3] of v [3]: skew(v) @ w == cross(v, w)."""
    x, y, z = np.asarray(v, dtype=float)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def rotation_from_axis_angle(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation vector [3] (axis × angle in radians) → matrix [3 x 3]."""
    rotvec = np.asarray(rotvec, dtype=float)
    angle = np.linalg.norm(rotvec)
    if angle < 1e-12:
        return np.eye(3) + skew(rotvec)
    K = skew(rotvec / angle)
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def axis_angle_from_rotation(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rotation_from_axis_angle` (via the quaternion, stable near 0 and π)."""
    q = quaternion_from_rotation(R)
    w, xyz = q[0], q[1:]
    s = np.linalg.norm(xyz)
    if s < 1e-12:
        return 2.0 * xyz
    angle = 2.0 * np.arctan2(s, w)
    return xyz / s * angle


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
    """Rotation matrix [3 x 3] → unit quaternion (w, x, y, z) with w ≥ 0 (Shepperd's method)."""
    R = np.asarray(R, dtype=float)
    trace = np.trace(R)
    diag = np.diag(R)
    k = int(np.argmax([trace, *diag]))
    if k == 0:
        w = 0.5 * np.sqrt(max(1.0 + trace, 0.0))
        q = np.array(
            [w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w)]
        )
    else:
        i = k - 1
        j, m = (i + 1) % 3, (i + 2) % 3
        s = 0.5 * np.sqrt(max(1.0 + R[i, i] - R[j, j] - R[m, m], 0.0))
        q = np.empty(4)
        q[1 + i] = s
        q[0] = (R[m, j] - R[j, m]) / (4 * s)
        q[1 + j] = (R[j, i] + R[i, j]) / (4 * s)
        q[1 + m] = (R[m, i] + R[i, m]) / (4 * s)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


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
