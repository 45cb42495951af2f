"""SE(3): 4x4 matrices, twists ``(v, omega)``; exp, log, inverse, compose, adjoint (batched)."""
from __future__ import annotations

import numpy as np

from .so3 import exp_so3, hat, left_jacobian_so3, log_so3


def make_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Homogeneous matrix from rotation (..., 3, 3) and translation (..., 3)."""
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    out = np.zeros(R.shape[:-2] + (4, 4))
    out[..., :3, :3] = R
    out[..., :3, 3] = t
    out[..., 3, 3] = 1.0
    return out


def exp_se3(xi: np.ndarray) -> np.ndarray:
    """Matrix exponential of the twist ``xi = (v, omega)`` (..., 6) -> (..., 4, 4)."""
    xi = np.asarray(xi, dtype=np.float64)
    v, w = xi[..., :3], xi[..., 3:]
    R = exp_so3(w)
    t = (left_jacobian_so3(w) @ v[..., None])[..., 0]
    return make_pose(R, t)


def log_se3(T: np.ndarray) -> np.ndarray:
    """Twist ``(v, omega)`` of ``T`` (..., 4, 4) -> (..., 6); inverse of :func:`exp_se3`."""
    T = np.asarray(T, dtype=np.float64)
    w = log_so3(T[..., :3, :3])
    V = left_jacobian_so3(w)
    v = np.linalg.solve(V, T[..., :3, 3][..., None])[..., 0]
    return np.concatenate([v, w], axis=-1)


def inverse_se3(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform, exact (R^T, -R^T t)."""
    T = np.asarray(T, dtype=np.float64)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return make_pose(Rt, -(Rt @ T[..., :3, 3][..., None])[..., 0])


def compose(T_a_b: np.ndarray, T_b_c: np.ndarray) -> np.ndarray:
    """``T_a_c = T_a_b @ T_b_c`` (batched by broadcasting)."""
    return np.asarray(T_a_b, dtype=np.float64) @ np.asarray(T_b_c, dtype=np.float64)


def adjoint_se3(T: np.ndarray) -> np.ndarray:
    """6x6 adjoint for twists ``(v, omega)``: ``T exp(xi) T^-1 = exp(Ad_T xi)``."""
    T = np.asarray(T, dtype=np.float64)
    R, t = T[..., :3, :3], T[..., :3, 3]
    out = np.zeros(T.shape[:-2] + (6, 6))
    out[..., :3, :3] = R
    out[..., :3, 3:] = hat(t) @ R
    out[..., 3:, 3:] = R
    return out


def project_to_se3(T: np.ndarray) -> np.ndarray:
    """The nearest rigid transform: rotation part projected onto SO(3) (SVD), last row exact.

    Products of many poses slowly lose orthonormality in floating point; apply this to poses
    that are composed again and again (the system's pose chain).
    """
    T = np.asarray(T, dtype=np.float64)
    U, _, Vt = np.linalg.svd(T[..., :3, :3])
    if T.shape == (4, 4):
        # one pose (the tracking hot path, three per frame): the same values as the batched code below
        # without its array bookkeeping; det(U Vt) is +-1, its sign from the cofactor expansion
        R = U @ Vt
        (a, b, c), (d, e, f), (g, h, i) = R.tolist()
        if a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) < 0:
            U[:, 2] = -U[:, 2]
            R = U @ Vt
        out = np.zeros((4, 4))
        out[:3, :3] = R
        out[:3, 3] = T[:3, 3]
        out[3, 3] = 1.0
        return out
    D = np.ones(T.shape[:-2] + (3,))
    D[..., 2] = np.sign(np.linalg.det(U @ Vt))
    return make_pose((U * D[..., None, :]) @ Vt, T[..., :3, 3])


def transform_points(T_a_b: np.ndarray, points_b: np.ndarray) -> np.ndarray:
    """Apply ``T_a_b`` (4, 4) to points (N, 3) -> (N, 3)."""
    T = np.asarray(T_a_b, dtype=np.float64)
    p = np.asarray(points_b, dtype=np.float64)
    return p @ T[:3, :3].T + T[:3, 3]
