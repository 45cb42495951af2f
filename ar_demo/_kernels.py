"""numba kernels of the AR world model: inverse-variance block reduction (eq. 5.2/5.3) and the
variational in-painting solver (eq. 5.6).

All thresholds are arguments; the public wrappers in :mod:`ar_demo.inpaint` validate inputs and
allocate. Slow numpy twins live in ``tests/naive_ar.py``. Imports: numpy and numba only.

Discretisation of eq. 5.6 on an ``H x W`` grid (unit cell area)::

    E(u) = sum_i w_i (u_i - f_i)^2 + alpha * sum_i huber_delta(|grad u_i|)

with ``f = D, w = 1/V`` where the map has a hypothesis and ``f = pi, w = 1/V_pi`` elsewhere,
forward differences and Neumann boundary (the difference leaving the grid is zero), and
``huber_delta(m) = m^2 / (2 delta)`` for ``m < delta`` else ``m - delta/2``.

Solver: diagonally preconditioned gradient descent ``u <- u - grad E(u) / M`` with
``M_i = 2 w_i + 2 alpha deg_i / delta`` (``deg_i``: grid neighbours of i). Since the Hessian of E is
bounded by ``diag(M)`` everywhere (Huber curvature <= 1/delta, graph Laplacian <= 2 diag(deg)),
every step minimises a quadratic upper bound of E: the energy decreases monotonically and the
iteration converges to the unique minimiser (E is strictly convex because w > 0).
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, fastmath=False)
def reduce_idepth_kernel(idepth, idepth_var, out_idepth, out_var, out_count):
    """Inverse-variance weighted reduction of an ``H x W`` map to the ``h x w`` output grid.

    A pixel ``(y, x)`` belongs to cell ``(y * h // H, x * w // W)``. Valid pixels have a finite
    idepth and a finite variance > 0. Per cell (eq. 5.2/5.3): ``D = sum(D/V) / sum(1/V)``,
    ``V = n / sum(1/V)`` with ``n`` valid pixels; cells without valid pixels get NaN and count 0.
    """
    H, W = idepth.shape
    h, w = out_idepth.shape
    info = np.zeros((h, w))
    acc = np.zeros((h, w))
    for y in range(h):
        for x in range(w):
            out_count[y, x] = 0
    for y in range(H):
        cy = (y * h) // H
        for x in range(W):
            d = idepth[y, x]
            v = idepth_var[y, x]
            if not (np.isfinite(d) and np.isfinite(v)) or v <= 0.0:
                continue
            cx = (x * w) // W
            info[cy, cx] += 1.0 / v
            acc[cy, cx] += d / v
            out_count[cy, cx] += 1
    for y in range(h):
        for x in range(w):
            n = out_count[y, x]
            if n > 0:
                out_idepth[y, x] = acc[y, x] / info[y, x]
                out_var[y, x] = n / info[y, x]
            else:
                out_idepth[y, x] = np.nan
                out_var[y, x] = np.nan


@njit(cache=True, nogil=True, fastmath=False)
def _huber(m, delta):
    if m < delta:
        return m * m / (2.0 * delta)
    return m - 0.5 * delta


@njit(cache=True, nogil=True, fastmath=False)
def inpaint_energy_kernel(u, f, w, alpha, delta):
    """Energy of eq. 5.6 (discretised as in the module docstring) at ``u``."""
    H, W = u.shape
    e = 0.0
    for y in range(H):
        for x in range(W):
            r = u[y, x] - f[y, x]
            e += w[y, x] * r * r
            gx = u[y, x + 1] - u[y, x] if x + 1 < W else 0.0
            gy = u[y + 1, x] - u[y, x] if y + 1 < H else 0.0
            e += alpha * _huber(np.sqrt(gx * gx + gy * gy), delta)
    return e


@njit(cache=True, nogil=True, fastmath=False)
def inpaint_gradient_kernel(u, f, w, alpha, delta, grad):
    """Gradient of the energy at ``u`` written into ``grad``."""
    H, W = u.shape
    for y in range(H):
        for x in range(W):
            grad[y, x] = 2.0 * w[y, x] * (u[y, x] - f[y, x])
    for y in range(H):
        for x in range(W):
            gx = u[y, x + 1] - u[y, x] if x + 1 < W else 0.0
            gy = u[y + 1, x] - u[y, x] if y + 1 < H else 0.0
            m = np.sqrt(gx * gx + gy * gy)
            c = alpha / (m if m > delta else delta)
            if x + 1 < W:
                grad[y, x + 1] += c * gx
                grad[y, x] -= c * gx
            if y + 1 < H:
                grad[y + 1, x] += c * gy
                grad[y, x] -= c * gy


@njit(cache=True, nogil=True, fastmath=False)
def inpaint_kernel(u, f, w, alpha, delta, iterations, tol, energies):
    """Minimise eq. 5.6 in place on ``u`` (initial guess) by preconditioned gradient descent.

    ``energies`` (length >= iterations + 1) receives E before the first and after each step.
    Stops early when the relative decrease of a step is below ``tol``. Returns the number of
    steps taken.
    """
    H, W = u.shape
    grad = np.empty((H, W))
    precond = np.empty((H, W))
    for y in range(H):
        for x in range(W):
            deg = 0
            if x > 0:
                deg += 1
            if x + 1 < W:
                deg += 1
            if y > 0:
                deg += 1
            if y + 1 < H:
                deg += 1
            precond[y, x] = 2.0 * w[y, x] + 2.0 * alpha * deg / delta
    e = inpaint_energy_kernel(u, f, w, alpha, delta)
    energies[0] = e
    n = 0
    for it in range(iterations):
        inpaint_gradient_kernel(u, f, w, alpha, delta, grad)
        for y in range(H):
            for x in range(W):
                u[y, x] -= grad[y, x] / precond[y, x]
        e_new = inpaint_energy_kernel(u, f, w, alpha, delta)
        energies[it + 1] = e_new
        n = it + 1
        if e - e_new <= tol * abs(e):
            break
        e = e_new
    return n


def warmup() -> None:
    """Compile (and cache) every kernel of this module on tiny inputs."""
    d = np.array([[1.0, np.nan], [0.5, 2.0]])
    v = np.array([[0.1, 0.1], [np.inf, 0.2]])
    oi = np.empty((1, 1))
    ov = np.empty((1, 1))
    oc = np.empty((1, 1), dtype=np.int64)
    reduce_idepth_kernel(d, v, oi, ov, oc)
    f = np.ones((2, 2))
    w = np.ones((2, 2))
    u = np.zeros((2, 2))
    energies = np.empty(3)
    inpaint_kernel(u, f, w, 0.1, 0.05, 2, 0.0, energies)
    inpaint_energy_kernel(u, f, w, 0.1, 0.05)
    inpaint_gradient_kernel(u, f, w, 0.1, 0.05, np.empty((2, 2)))
