"""Quaternions in TUM order ``(qx, qy, qz, qw)`` and TUM pose rows ``tx ty tz qx qy qz qw``."""
from __future__ import annotations

import math

import numpy as np

from .se3 import make_pose


def rotmat_from_quat_xyzw(q: np.ndarray) -> np.ndarray:
    """Rotation matrix (..., 3, 3) of a (not necessarily unit) quaternion (..., 4) in xyzw order."""
    q = np.asarray(q, dtype=np.float64)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(n < 1e-12):
        raise ValueError("zero-length quaternion")
    x, y, z, w = np.moveaxis(q / n, -1, 0)
    out = np.empty(q.shape[:-1] + (3, 3))
    out[..., 0, 0] = 1 - 2 * (y * y + z * z)
    out[..., 0, 1] = 2 * (x * y - z * w)
    out[..., 0, 2] = 2 * (x * z + y * w)
    out[..., 1, 0] = 2 * (x * y + z * w)
    out[..., 1, 1] = 1 - 2 * (x * x + z * z)
    out[..., 1, 2] = 2 * (y * z - x * w)
    out[..., 2, 0] = 2 * (x * z - y * w)
    out[..., 2, 1] = 2 * (y * z + x * w)
    out[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return out


def quat_xyzw_from_rotmat(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (..., 4), xyzw, with ``qw >= 0``, of rotation matrices (..., 3, 3)."""
    R = np.asarray(R, dtype=np.float64)
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    # Shepperd: candidates from each diagonal element, pick the best conditioned.
    cand = np.stack([
        1 + m00 + m11 + m22,
        1 + m00 - m11 - m22,
        1 - m00 + m11 - m22,
        1 - m00 - m11 + m22,
    ], axis=-1)
    k = np.argmax(cand, axis=-1)
    s = np.sqrt(np.maximum(np.take_along_axis(cand, k[..., None], -1)[..., 0], 1e-300)) * 2
    r = R
    q0 = np.stack([(r[..., 2, 1] - r[..., 1, 2]) / s, (r[..., 0, 2] - r[..., 2, 0]) / s,
                   (r[..., 1, 0] - r[..., 0, 1]) / s, s / 4], -1)
    q1 = np.stack([s / 4, (r[..., 0, 1] + r[..., 1, 0]) / s, (r[..., 0, 2] + r[..., 2, 0]) / s,
                   (r[..., 2, 1] - r[..., 1, 2]) / s], -1)
    q2 = np.stack([(r[..., 0, 1] + r[..., 1, 0]) / s, s / 4, (r[..., 1, 2] + r[..., 2, 1]) / s,
                   (r[..., 0, 2] - r[..., 2, 0]) / s], -1)
    q3 = np.stack([(r[..., 0, 2] + r[..., 2, 0]) / s, (r[..., 1, 2] + r[..., 2, 1]) / s, s / 4,
                   (r[..., 1, 0] - r[..., 0, 1]) / s], -1)
    q = np.select([k[..., None] == 0, k[..., None] == 1, k[..., None] == 2], [q0, q1, q2], q3)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(q[..., 3:4] < 0, -q, q)
    return q


def quat_xyzw_one(R) -> tuple[float, float, float, float]:
    """:func:`quat_xyzw_from_rotmat` of one 3x3 matrix in Python floats: the same operations in the same
    order, so the same bits, without numpy's per-call overhead (about 10x faster for one pose: the
    trajectory is written one line per frame)."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = ((float(v) for v in row) for row in R)
    cand = (1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22)
    k = max(range(4), key=cand.__getitem__)           # the first largest, as argmax
    s = math.sqrt(max(cand[k], 1e-300)) * 2
    if k == 0:
        q = ((m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s, s / 4)
    elif k == 1:
        q = (s / 4, (m01 + m10) / s, (m02 + m20) / s, (m21 - m12) / s)
    elif k == 2:
        q = ((m01 + m10) / s, s / 4, (m12 + m21) / s, (m02 - m20) / s)
    else:
        q = ((m02 + m20) / s, (m12 + m21) / s, s / 4, (m10 - m01) / s)
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    q = tuple(v / n for v in q)
    return tuple(-v for v in q) if q[3] < 0 else q


def pose_from_tum(row: np.ndarray) -> np.ndarray:
    """4x4 pose(s) from ``tx ty tz qx qy qz qw`` rows (..., 7)."""
    row = np.asarray(row, dtype=np.float64)
    return make_pose(rotmat_from_quat_xyzw(row[..., 3:7]), row[..., :3])


def tum_from_pose(T: np.ndarray) -> np.ndarray:
    """``tx ty tz qx qy qz qw`` rows (..., 7) of pose(s) (..., 4, 4)."""
    T = np.asarray(T, dtype=np.float64)
    return np.concatenate([T[..., :3, 3], quat_xyzw_from_rotmat(T[..., :3, :3])], axis=-1)
