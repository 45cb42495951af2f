"""Variational in-painting of the semi-dense map into a dense low-resolution grid (thesis eq. 5.6).

1. :func:`reduce_idepth` brings the semi-dense map (mapping resolution, NaN/invalid where empty) to
   the grid size by the inverse-variance weighted pyramid of eq. 5.2/5.3: exact 2x2 steps while the
   map is at least twice the grid size, then one block step for the remaining factor.
2. :func:`inpaint` minimises ``sum w (u - f)^2 + alpha sum huber(grad u)`` with the map as data term
   where it has a hypothesis and the ground-plane inverse depth (weight ``1 / V_pi``) elsewhere.
   The problem is solved in normalised units (inverse depth divided by the median of the data) so
   that ``alpha``, ``huber_delta``, ``ground_var`` do not depend on the arbitrary monocular scale.

Imports: numpy, ar_demo._kernels, lite_vo (errors) only.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lite_vo.errors import InputError

from . import _kernels


def reduce_idepth(idepth: np.ndarray, idepth_var: np.ndarray,
                  out_shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(D, V, count) on the ``out_shape`` grid; D, V are NaN where no valid pixel falls into a cell."""
    d = np.array(idepth, dtype=np.float64)
    v = np.array(idepth_var, dtype=np.float64)
    if d.ndim != 2 or d.shape != v.shape:
        raise InputError(f"reduce_idepth: idepth {d.shape} and idepth_var {v.shape} must be equal 2-D arrays")
    h, w = int(out_shape[0]), int(out_shape[1])
    if h < 1 or w < 1 or h > d.shape[0] or w > d.shape[1]:
        raise InputError(f"reduce_idepth: grid {h}x{w} must be within 1x1 .. {d.shape[0]}x{d.shape[1]}")
    d[~(d > 0)] = np.nan                   # non-positive idepth is not a hypothesis
    count = None
    while d.shape[0] >= 2 * h and d.shape[1] >= 2 * w and d.shape[0] % 2 == 0 and d.shape[1] % 2 == 0:
        shape = (d.shape[0] // 2, d.shape[1] // 2)
        d, v, count = _reduce_once(d, v, shape)
    if count is None or d.shape != (h, w):
        d, v, count = _reduce_once(d, v, (h, w))   # count: valid children at the last step
    return d, v, count


def _reduce_once(d, v, shape):
    od = np.empty(shape)
    ov = np.empty(shape)
    oc = np.empty(shape, dtype=np.int64)
    _kernels.reduce_idepth_kernel(np.ascontiguousarray(d), np.ascontiguousarray(v), od, ov, oc)
    return od, ov, oc


@dataclass
class InpaintResult:
    idepth: np.ndarray          # (h, w) dense inverse depth
    data_mask: np.ndarray       # (h, w) bool: the cell had a map hypothesis
    energies: np.ndarray        # energy before and after each iteration (normalised units)
    iterations: int
    scale: float                # the normalisation (median data inverse depth)


def inpaint(D: np.ndarray, V: np.ndarray, prior_idepth: np.ndarray, alpha: float, huber_delta: float,
            ground_var: float, min_var: float = 1e-4, iterations: int = 400,
            tol: float = 1e-9) -> InpaintResult:
    """Dense inverse depth minimising eq. 5.6.

    ``D, V``: reduced map (NaN where empty), ``prior_idepth``: ground-plane inverse depth per cell
    (0 where the ray misses the plane), same shape. Normalised by the median of D (else of the
    positive prior).
    """
    D = np.asarray(D, dtype=np.float64)
    V = np.asarray(V, dtype=np.float64)
    prior = np.asarray(prior_idepth, dtype=np.float64)
    if D.shape != V.shape or D.shape != prior.shape or D.ndim != 2:
        raise InputError(f"inpaint: D {D.shape}, V {V.shape}, prior {prior.shape} must be equal 2-D arrays")
    mask = np.isfinite(D) & np.isfinite(V) & (D > 0) & (V > 0)
    ref = D[mask] if mask.any() else prior[prior > 0]
    scale = float(np.median(ref)) if ref.size else 1.0
    if not (scale > 0 and np.isfinite(scale)):
        raise InputError(f"inpaint: normalisation scale must be positive, got {scale}")
    prior_n = np.where(np.isfinite(prior) & (prior > 0), prior, 0.0) / scale
    f = np.where(mask, np.where(mask, D, 0.0) / scale, prior_n)
    w = np.where(mask, 1.0 / np.maximum(np.where(mask, V, 1.0) / scale**2, min_var), 1.0 / ground_var)
    u = f.copy()
    energies = np.empty(int(iterations) + 1)
    n = _kernels.inpaint_kernel(u, np.ascontiguousarray(f), np.ascontiguousarray(w), float(alpha),
                                float(huber_delta), int(iterations), float(tol), energies)
    return InpaintResult(u * scale, mask, energies[:n + 1].copy(), int(n), scale)
