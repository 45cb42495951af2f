"""Slow, obviously-correct numpy twins of the AR kernels (``ar_demo/_kernels.py``) and small
analytic scenes for the AR tests (ray casting a floor and boxes; no renderer needed)."""
from __future__ import annotations

import numpy as np


# ----------------------------------------------------------------------------- kernel twins
def reduce_idepth_naive(idepth, idepth_var, out_shape):
    """Eq. 5.2/5.3 over blocks: pixel (y, x) -> cell (y*h//H, x*w//W)."""
    H, W = idepth.shape
    h, w = out_shape
    D = np.full((h, w), np.nan)
    V = np.full((h, w), np.nan)
    C = np.zeros((h, w), dtype=np.int64)
    cy = (np.arange(H) * h) // H
    cx = (np.arange(W) * w) // W
    for y in range(h):
        for x in range(w):
            d = idepth[np.ix_(cy == y, cx == x)].ravel()
            v = idepth_var[np.ix_(cy == y, cx == x)].ravel()
            ok = np.isfinite(d) & np.isfinite(v) & (v > 0)
            if ok.any():
                D[y, x] = np.sum(d[ok] / v[ok]) / np.sum(1 / v[ok])
                V[y, x] = ok.sum() / np.sum(1 / v[ok])
                C[y, x] = ok.sum()
    return D, V, C


def _grads(u):
    gx = np.zeros_like(u)
    gy = np.zeros_like(u)
    gx[:, :-1] = u[:, 1:] - u[:, :-1]
    gy[:-1, :] = u[1:, :] - u[:-1, :]
    return gx, gy


def huber_naive(m, delta):
    return np.where(m < delta, m**2 / (2 * delta), m - delta / 2)


def energy_naive(u, f, w, alpha, delta):
    gx, gy = _grads(u)
    return float(np.sum(w * (u - f) ** 2) + alpha * np.sum(huber_naive(np.hypot(gx, gy), delta)))


def gradient_naive(u, f, w, alpha, delta):
    gx, gy = _grads(u)
    c = alpha / np.maximum(np.hypot(gx, gy), delta)
    px, py = c * gx, c * gy
    # -div(p) with the adjoint of the forward differences
    g = 2 * w * (u - f)
    g[:, 1:] += px[:, :-1]
    g[:, :-1] -= px[:, :-1]
    g[1:, :] += py[:-1, :]
    g[:-1, :] -= py[:-1, :]
    return g


def inpaint_naive(u0, f, w, alpha, delta, iterations, tol):
    H, W = u0.shape
    deg = np.full((H, W), 4.0)
    deg[0, :] -= 1
    deg[-1, :] -= 1
    deg[:, 0] -= 1
    deg[:, -1] -= 1
    M = 2 * w + 2 * alpha * deg / delta
    u = u0.astype(np.float64).copy()
    energies = [energy_naive(u, f, w, alpha, delta)]
    for _ in range(iterations):
        u = u - gradient_naive(u, f, w, alpha, delta) / M
        energies.append(energy_naive(u, f, w, alpha, delta))
        if energies[-2] - energies[-1] <= tol * abs(energies[-2]):
            break
    return u, np.array(energies)


# ----------------------------------------------------------------------------- analytic scenes
def look_at(eye, target, up=(0.0, 0.0, 1.0)):
    """T_world_cam of an OpenCV camera (x right, y down, z forward) at ``eye`` looking at ``target``
    (:func:`ar_demo.video.look_at` with world z up by default)."""
    from ar_demo.video import look_at as _look_at
    return _look_at(eye, target, up)


def raycast_depth(T_world_cam, K, width, height, boxes=(), floor_z=0.0):
    """z-depth image of the floor ``z = floor_z`` (world z up) and axis-aligned boxes
    ``(xmin, ymin, zmin, xmax, ymax, zmax)``; 0 where nothing is hit. Also returns a label image
    (0 none, 1 floor, 2+i box i)."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    d_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    R, C = T_world_cam[:3, :3], T_world_cam[:3, 3]
    d = d_cam @ R.T                      # world direction with camera z-component 1 -> t is z-depth
    t_best = np.full(u.shape, np.inf)
    label = np.zeros(u.shape, dtype=np.int32)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (floor_z - C[2]) / d[..., 2]
    hit = np.isfinite(t) & (t > 0)
    t_best[hit] = t[hit]
    label[hit] = 1
    for i, b in enumerate(boxes):
        lo, hi = np.array(b[:3]), np.array(b[3:])
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (lo - C) / d
            t2 = (hi - C) / d
        tmin = np.nanmax(np.minimum(t1, t2), axis=-1)
        tmax = np.nanmin(np.maximum(t1, t2), axis=-1)
        hitb = (tmax >= tmin) & (tmin > 0) & (tmin < t_best)
        t_best[hitb] = tmin[hitb]
        label[hitb] = 2 + i
    depth = np.where(np.isfinite(t_best), t_best, 0.0)
    return depth, label


def idepth_from_depth(depth, rng=None, drop=0.0):
    """Inverse depth of a ray-cast depth map (NaN where no hit); with ``rng``, a ``drop`` fraction
    of the pixels is emptied at random (a semi-dense map)."""
    idepth = np.where(depth > 0, 1 / np.where(depth > 0, depth, 1), np.nan)
    if rng is not None:
        idepth[rng.random(idepth.shape) < drop] = np.nan
    return idepth
