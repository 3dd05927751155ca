"""Rotations in numpy: axis-angle <-> matrix, quaternions (wxyz). Batched over leading dims.

The numpy twin of :mod:`trioman.toolkit.rotations` (same names, same rules; docs/design.md,
"Conventions"). Axis-angle vectors are stable for tiny angles (second-order Taylor terms) and near pi.
"""

from __future__ import annotations

import numpy as np

SMALL_ANGLE = 1e-6  # radians: below it, axis-angle conversions use their Taylor expansions
QUAT_NORM_FLOOR = 1e-12  # matrix_to_quat's candidate is normalised with its norm clamped here


def axis_angle_to_matrix(aa: np.ndarray) -> np.ndarray:
    """Rodrigues' formula. aa: [..., 3] (radians) -> [..., 3, 3], same float dtype (float64 if int)."""
    aa = np.asarray(aa)
    if aa.shape[-1:] != (3,):
        raise ValueError(f"axis-angle: expected shape [..., 3], got {aa.shape}")
    dtype = aa.dtype if np.issubdtype(aa.dtype, np.floating) else np.float64
    a = aa.astype(np.float64)
    theta2 = np.sum(a * a, axis=-1)
    theta = np.sqrt(theta2)
    small = theta < SMALL_ANGLE
    safe = np.where(small, 1.0, theta)
    # sin(t)/t and (1-cos(t))/t^2 with their Taylor expansions for tiny angles.
    a_coef = np.where(small, 1.0 - theta2 / 6.0, np.sin(safe) / safe)
    b_coef = np.where(small, 0.5 - theta2 / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
    x, y, z = a[..., 0], a[..., 1], a[..., 2]
    zero = np.zeros_like(x)
    skew = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1).reshape(a.shape[:-1] + (3, 3))
    eye = np.broadcast_to(np.eye(3), skew.shape)
    R = eye + a_coef[..., None, None] * skew + b_coef[..., None, None] * (skew @ skew)
    return R.astype(dtype, copy=False)


def matrix_to_axis_angle(R: np.ndarray) -> np.ndarray:
    """Inverse of axis_angle_to_matrix, angles in [0, pi]. R: [..., 3, 3] -> [..., 3]."""
    return quat_to_axis_angle(matrix_to_quat(R))


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Rotation matrix -> unit quaternion wxyz with w >= 0 (Shepperd's method). [..., 3, 3] -> [..., 4].

    A near-rotation (e.g. a blend of rotations in LBS) gives the same quaternion as
    trioman.toolkit.rotations.matrix_to_quat: the same candidate, normalised with its norm clamped
    at 1e-12 (an all-zero candidate stays zero, which means the identity).
    """
    R = np.asarray(R, dtype=np.float64)
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    # Four candidate solutions; take the numerically largest denominator per element.
    cand = np.stack(
        [
            np.stack([1 + m00 + m11 + m22, R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1),
            np.stack([R[..., 2, 1] - R[..., 1, 2], 1 + m00 - m11 - m22, R[..., 1, 0] + R[..., 0, 1], R[..., 0, 2] + R[..., 2, 0]], -1),
            np.stack([R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] + R[..., 0, 1], 1 - m00 + m11 - m22, R[..., 2, 1] + R[..., 1, 2]], -1),
            np.stack([R[..., 1, 0] - R[..., 0, 1], R[..., 0, 2] + R[..., 2, 0], R[..., 2, 1] + R[..., 1, 2], 1 - m00 - m11 + m22], -1),
        ],
        axis=-2,
    )  # [..., 4, 4]: row k is 4 q_k * q
    diag = np.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1)
    best = np.argmax(diag, axis=-1)
    q = np.take_along_axis(cand, best[..., None, None], axis=-2)[..., 0, :]
    q = q / np.maximum(np.linalg.norm(q, axis=-1, keepdims=True), QUAT_NORM_FLOOR)
    return np.where(q[..., :1] < 0, -q, q)


def quat_to_axis_angle(q: np.ndarray) -> np.ndarray:
    """Unit quaternion wxyz -> axis-angle with angle in [0, pi]. [..., 4] -> [..., 3]."""
    q = np.asarray(q, dtype=np.float64)
    q = np.where(q[..., :1] < 0, -q, q)
    w, v = q[..., 0], q[..., 1:]
    s = np.linalg.norm(v, axis=-1)
    angle = 2.0 * np.arctan2(s, w)
    small = s < SMALL_ANGLE
    # angle / sin(angle/2) -> 2 / w (1 + s^2/(6 w^2)...) for tiny s.
    scale = np.where(small, 2.0 / np.maximum(w, SMALL_ANGLE), angle / np.where(small, 1.0, s))
    return v * scale[..., None]


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Quaternion wxyz (normalised here; a zero quaternion is the identity) -> [..., 3, 3]."""
    q = np.asarray(q, dtype=np.float64)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(n > 0, q / np.where(n > 0, n, 1.0), np.array([1.0, 0.0, 0.0, 0.0]))
    w, x, y, z = np.moveaxis(q, -1, 0)
    R = np.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        axis=-1,
    )
    return R.reshape(q.shape[:-1] + (3, 3))
