"""Sim(3): 4x4 matrices ``[[s R, t], [0, 1]]``, tangent ``(v, omega, sigma)`` with ``s = exp(sigma)``."""
from __future__ import annotations

import numpy as np

from .so3 import exp_so3, hat, log_so3


def _sim3_V(w: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Matrix V with t = V v for Sim(3): V = sum_k (sigma I + W)^k / (k+1)!, in closed form.

    Evaluated as the integral int_0^1 exp(sigma u) exp_so3(u w) du by Gauss-Legendre
    quadrature (exact to machine precision for the moderate angles and scales of VO).
    """
    nodes, weights = np.polynomial.legendre.leggauss(16)
    u = 0.5 * (nodes + 1.0)
    wts = 0.5 * weights
    w = np.asarray(w, dtype=np.float64)
    sigma = np.asarray(sigma, dtype=np.float64)
    out = np.zeros(w.shape[:-1] + (3, 3))
    for uk, wk in zip(u, wts):
        out += wk * np.exp(sigma * uk)[..., None, None] * exp_so3(w * uk)
    return out


def exp_sim3(xi: np.ndarray) -> np.ndarray:
    """Exponential of ``(v, omega, sigma)`` (..., 7) -> (..., 4, 4)."""
    xi = np.asarray(xi, dtype=np.float64)
    v, w, sigma = xi[..., :3], xi[..., 3:6], xi[..., 6]
    out = np.zeros(xi.shape[:-1] + (4, 4))
    out[..., :3, :3] = np.exp(sigma)[..., None, None] * exp_so3(w)
    out[..., :3, 3] = (_sim3_V(w, sigma) @ v[..., None])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def scale_of(S: np.ndarray) -> np.ndarray:
    """Scale factor s of a Sim(3) matrix."""
    S = np.asarray(S, dtype=np.float64)
    return np.cbrt(np.linalg.det(S[..., :3, :3]))


def log_sim3(S: np.ndarray) -> np.ndarray:
    """Tangent ``(v, omega, sigma)`` of a Sim(3) matrix; inverse of :func:`exp_sim3`."""
    S = np.asarray(S, dtype=np.float64)
    s = scale_of(S)
    R = S[..., :3, :3] / s[..., None, None]
    w = log_so3(R)
    sigma = np.log(s)
    V = _sim3_V(w, sigma)
    v = np.linalg.solve(V, S[..., :3, 3][..., None])[..., 0]
    return np.concatenate([v, w, sigma[..., None]], axis=-1)


def inverse_sim3(S: np.ndarray) -> np.ndarray:
    """Inverse of ``[[sR, t]]``: ``[[R^T/s, -R^T t / s]]``."""
    S = np.asarray(S, dtype=np.float64)
    s = scale_of(S)
    Rt = np.swapaxes(S[..., :3, :3], -1, -2) / (s * s)[..., None, None]  # (sR)^-1 = R^T / s
    out = np.zeros(S.shape)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -(Rt @ S[..., :3, 3][..., None])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def adjoint_sim3(S: np.ndarray) -> np.ndarray:
    """7x7 adjoint for ``(v, omega, sigma)``: ``S exp(xi) S^-1 = exp(Ad_S xi)``."""
    S = np.asarray(S, dtype=np.float64)
    s = scale_of(S)
    R = S[..., :3, :3] / s[..., None, None]
    t = S[..., :3, 3]
    out = np.zeros(S.shape[:-2] + (7, 7))
    out[..., :3, :3] = s[..., None, None] * R
    out[..., :3, 3:6] = hat(t) @ R
    out[..., :3, 6] = -t
    out[..., 3:6, 3:6] = R
    out[..., 6, 6] = 1.0
    return out
