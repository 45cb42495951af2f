"""SO(3): hat/vee, exponential and logarithm (Rodrigues), batched over leading dimensions."""
from __future__ import annotations

import numpy as np

_SMALL = 1e-10


def hat(w: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix of ``w`` (..., 3) -> (..., 3, 3), so ``hat(a) @ b == cross(a, b)``."""
    w = np.asarray(w, dtype=np.float64)
    out = np.zeros(w.shape[:-1] + (3, 3))
    out[..., 0, 1] = -w[..., 2]
    out[..., 0, 2] = w[..., 1]
    out[..., 1, 0] = w[..., 2]
    out[..., 1, 2] = -w[..., 0]
    out[..., 2, 0] = -w[..., 1]
    out[..., 2, 1] = w[..., 0]
    return out


def vee(m: np.ndarray) -> np.ndarray:
    """Inverse of :func:`hat`: (..., 3, 3) -> (..., 3)."""
    m = np.asarray(m, dtype=np.float64)
    return np.stack([m[..., 2, 1], m[..., 0, 2], m[..., 1, 0]], axis=-1)


def _coeffs(theta: np.ndarray):
    """A = sin/th, B = (1-cos)/th^2, C = (th - sin)/th^3, with Taylor series near 0."""
    th2 = theta * theta
    small = theta < 1e-4
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - th2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
    c = np.where(small, 1.0 / 6.0 - th2 / 120.0, (safe - np.sin(safe)) / (safe ** 3))
    return a, b, c


def exp_so3(w: np.ndarray) -> np.ndarray:
    """Rotation matrix of the rotation vector ``w`` (..., 3)."""
    w = np.asarray(w, dtype=np.float64)
    theta = np.linalg.norm(w, axis=-1)
    a, b, _ = _coeffs(theta)
    W = hat(w)
    eye = np.broadcast_to(np.eye(3), W.shape)
    return eye + a[..., None, None] * W + b[..., None, None] * (W @ W)


def left_jacobian_so3(w: np.ndarray) -> np.ndarray:
    """V(w) = I + B W + C W^2: the matrix that turns the twist's v into the translation."""
    w = np.asarray(w, dtype=np.float64)
    theta = np.linalg.norm(w, axis=-1)
    _, b, c = _coeffs(theta)
    W = hat(w)
    eye = np.broadcast_to(np.eye(3), W.shape)
    return eye + b[..., None, None] * W + c[..., None, None] * (W @ W)


def log_so3(R: np.ndarray) -> np.ndarray:
    """Rotation vector of the rotation matrix ``R`` (..., 3, 3); angle in [0, pi]."""
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R, axis1=-2, axis2=-1)
    cos_t = np.clip((tr - 1.0) * 0.5, -1.0, 1.0)
    theta = np.arccos(cos_t)
    skew = vee(R - np.swapaxes(R, -1, -2)) * 0.5  # = sin(theta) * axis
    sin_t = np.sin(theta)
    small = theta < 1e-4
    factor = np.where(small, 1.0 + theta * theta / 6.0, theta / np.where(small, 1.0, sin_t))
    w = skew * factor[..., None]
    # Near pi sin(theta) -> 0 and the skew part loses the axis: recover it from R + R^T.
    near_pi = theta > np.pi - 1e-3
    if np.any(near_pi):
        Rp = R[near_pi]
        th = theta[near_pi]
        B = (Rp + np.swapaxes(Rp, -1, -2)) * 0.5 - np.eye(3) * cos_t[near_pi][..., None, None]
        # B = (1 - cos) a a^T; take the column with the largest diagonal entry.
        idx = np.argmax(np.diagonal(B, axis1=-2, axis2=-1), axis=-1)
        col = np.take_along_axis(B, idx[..., None, None].repeat(3, axis=-1), axis=-2)[..., 0, :]
        axis = col / np.linalg.norm(col, axis=-1, keepdims=True)
        # fix the sign with the (small but informative) skew part
        sgn = np.sign(np.sum(axis * skew[near_pi], axis=-1))
        sgn = np.where(sgn == 0, 1.0, sgn)
        w[near_pi] = axis * (sgn * th)[..., None]
    return w
