"""Slow, obviously-correct reference versions of the point-cloud kernels (lite_vo/_cloud_kernels.py):
one full-array numpy pass per window offset (the implementation before the kernels)."""
from __future__ import annotations

import numpy as np


def support(p_cam: np.ndarray, fx: float, fy: float, cx: float, cy: float, width: int, height: int,
            idepth: np.ndarray, rel_tol: float, win: int) -> tuple[np.ndarray, np.ndarray]:
    """(seen, agree) per point, see ``support_counts``."""
    n = len(p_cam)
    seen = np.zeros(n, bool)
    agree = np.zeros(n, bool)
    front = p_cam[:, 2] > 1e-9
    if not front.any():
        return seen, agree
    p = p_cam[front]
    ui = np.rint(fx * p[:, 0] / p[:, 2] + cx).astype(np.int64)
    vi = np.rint(fy * p[:, 1] / p[:, 2] + cy).astype(np.int64)
    ids = np.nonzero(front)[0]
    inside = (ui >= win) & (ui < width - win) & (vi >= win) & (vi < height - win)
    ids, ui, vi = ids[inside], ui[inside], vi[inside]
    want = 1.0 / p_cam[ids, 2]
    for dv in range(-win, win + 1):
        for du in range(-win, win + 1):
            d = idepth[vi + dv, ui + du]
            ok = np.isfinite(d)
            seen[ids[ok]] = True
            agree[ids[ok & (np.abs(d - want) <= rel_tol * want)]] = True
    return seen, agree


def depth_jump(idepth: np.ndarray, radius: int = 2) -> np.ndarray:
    """See ``depth_jump_kernel``."""
    D = np.asarray(idepth, np.float64)
    H, W = D.shape
    P = np.pad(D, radius, constant_values=np.nan)
    out = np.zeros_like(D)
    for dv in range(2 * radius + 1):
        for du in range(2 * radius + 1):
            q = P[dv:dv + H, du:du + W]
            with np.errstate(invalid="ignore", divide="ignore"):
                out = np.fmax(out, np.abs(q - D) / D)
    out[~np.isfinite(D)] = np.nan
    return out
