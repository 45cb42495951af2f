"""Image and inverse-depth pyramids, image gradients (numba kernels + validating wrappers).

Owns:

* :func:`image_pyramid` - 2x2 box-average pyramid; any size (odd sizes floor: level l+1 is
  ``(h // 2, w // 2)``), matching :meth:`lite_vo.camera.PinholeIntrinsics.level`.
* :func:`idepth_pyramid` - the inverse-variance-weighted inverse-depth pyramid of the thesis,
  eq. 5.2/5.3: over the valid pixels of each 2x2 block ``idepth = sum(d/v) / sum(1/v)`` and
  ``var = n / sum(1/v)``; a block without a valid pixel is invalid (NaN, ``valid`` False).
* :func:`gradients` - half central differences ``gx = (I[x+1] - I[x-1]) / 2`` (0 on the border).
* :func:`intensity_gradient_stack` - ``(H, W, 3)`` float32 ``[I, gx, gy]`` interleaved, the layout the
  tracking kernel samples bilinearly (one cache line per corner).
* :func:`warmup` - compiles every kernel of this module on tiny inputs.

Imports numpy and numba only (no other lite_vo module, no OpenCV).
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["image_pyramid", "idepth_pyramid", "gradients", "intensity_gradient_stack",
           "downsample_image", "downsample_idepth", "warmup"]


# --------------------------------------------------------------------------- kernels
@njit(cache=True, nogil=True, fastmath=False)
def _downsample_box(img, out):
    h2, w2 = out.shape
    for y in range(h2):
        r0 = img[2 * y]
        r1 = img[2 * y + 1]
        for x in range(w2):
            out[y, x] = 0.25 * (np.float64(r0[2 * x]) + r0[2 * x + 1] + r1[2 * x] + r1[2 * x + 1])


@njit(cache=True, nogil=True, fastmath=False)
def _downsample_idepth(idepth, var, valid, out_idepth, out_var, out_valid):
    h2, w2 = out_idepth.shape
    for y in range(h2):
        for x in range(w2):
            s_inv = 0.0
            s_d = 0.0
            n = 0
            for dy in range(2):
                for dx in range(2):
                    yy = 2 * y + dy
                    xx = 2 * x + dx
                    if valid[yy, xx]:
                        iv = 1.0 / np.float64(var[yy, xx])
                        s_inv += iv
                        s_d += idepth[yy, xx] * iv
                        n += 1
            if n > 0:
                out_idepth[y, x] = s_d / s_inv
                out_var[y, x] = n / s_inv
                out_valid[y, x] = True
            else:
                out_idepth[y, x] = np.nan
                out_var[y, x] = np.nan
                out_valid[y, x] = False


@njit(cache=True, nogil=True, fastmath=False)
def _gradient_stack(img, out):
    h, w = img.shape
    for y in range(h):
        for x in range(w):
            out[y, x, 0] = img[y, x]
            if 0 < x < w - 1 and 0 < y < h - 1:
                out[y, x, 1] = 0.5 * (np.float64(img[y, x + 1]) - img[y, x - 1])
                out[y, x, 2] = 0.5 * (np.float64(img[y + 1, x]) - img[y - 1, x])
            else:
                out[y, x, 1] = 0.0
                out[y, x, 2] = 0.0


# --------------------------------------------------------------------------- wrappers
def _as_image(img, name="image") -> np.ndarray:
    a = np.asarray(img)
    if a.ndim != 2:
        raise ValueError(f"{name}: expected a 2-D grey image, got shape {a.shape}")
    return np.ascontiguousarray(a, dtype=np.float32)


def downsample_image(img: np.ndarray) -> np.ndarray:
    """One pyramid step: 2x2 box average, output ``(h // 2, w // 2)`` float32."""
    a = _as_image(img)
    h2, w2 = a.shape[0] // 2, a.shape[1] // 2
    if h2 < 1 or w2 < 1:
        raise ValueError(f"image of shape {a.shape} is too small to downsample")
    out = np.empty((h2, w2), np.float32)
    _downsample_box(a, out)
    return out


def image_pyramid(img: np.ndarray, levels: int) -> list[np.ndarray]:
    """``levels`` float32 images: level 0 is ``img`` (as float32), each next one a 2x2 box average."""
    if levels < 1:
        raise ValueError(f"levels must be >= 1, got {levels}")
    pyr = [_as_image(img)]
    for _ in range(levels - 1):
        pyr.append(downsample_image(pyr[-1]))
    return pyr


def downsample_idepth(idepth: np.ndarray, idepth_var: np.ndarray, valid: np.ndarray):
    """One step of the inverse-variance-weighted depth pyramid (eq. 5.2/5.3).

    Inputs must already be sanitised (``valid`` implies finite idepth and var > 0).
    Returns ``(idepth, idepth_var, valid)`` at ``(h // 2, w // 2)``; invalid entries are NaN.
    """
    d = np.ascontiguousarray(idepth, dtype=np.float32)
    v = np.ascontiguousarray(idepth_var, dtype=np.float32)
    m = np.ascontiguousarray(valid, dtype=np.bool_)
    if d.shape != v.shape or d.shape != m.shape or d.ndim != 2:
        raise ValueError(f"idepth {d.shape}, idepth_var {v.shape}, valid {m.shape} must be equal 2-D shapes")
    h2, w2 = d.shape[0] // 2, d.shape[1] // 2
    if h2 < 1 or w2 < 1:
        raise ValueError(f"depth map of shape {d.shape} is too small to downsample")
    od = np.empty((h2, w2), np.float32)
    ov = np.empty((h2, w2), np.float32)
    om = np.empty((h2, w2), np.bool_)
    _downsample_idepth(d, v, m, od, ov, om)
    return od, ov, om


def sanitize_idepth(idepth: np.ndarray, idepth_var: np.ndarray, valid: np.ndarray):
    """``(idepth, var, valid)`` float32/bool with ``valid &= finite & idepth > 0 & var > 0`` and NaN elsewhere."""
    d = np.asarray(idepth, dtype=np.float32)
    v = np.asarray(idepth_var, dtype=np.float32)
    m = np.asarray(valid, dtype=bool)
    if d.shape != v.shape or d.shape != m.shape or d.ndim != 2:
        raise ValueError(f"idepth {d.shape}, idepth_var {v.shape}, valid {m.shape} must be equal 2-D shapes")
    with np.errstate(invalid="ignore"):
        ok = m & np.isfinite(d) & np.isfinite(v) & (d > 0) & (v > 0)
    d = np.where(ok, d, np.float32(np.nan)).astype(np.float32)
    v = np.where(ok, v, np.float32(np.nan)).astype(np.float32)
    return d, v, ok


def idepth_pyramid(idepth: np.ndarray, idepth_var: np.ndarray, valid: np.ndarray, levels: int):
    """Lists ``(idepths, vars, valids)`` of ``levels`` levels (level 0 = the sanitised input)."""
    if levels < 1:
        raise ValueError(f"levels must be >= 1, got {levels}")
    d, v, m = sanitize_idepth(idepth, idepth_var, valid)
    ds, vs, ms = [d], [v], [m]
    for _ in range(levels - 1):
        d, v, m = downsample_idepth(d, v, m)
        ds.append(d)
        vs.append(v)
        ms.append(m)
    return ds, vs, ms


def gradients(img: np.ndarray):
    """Half central differences ``(gx, gy)`` float32 (zero on the one-pixel border)."""
    s = intensity_gradient_stack(img)
    return np.ascontiguousarray(s[:, :, 1]), np.ascontiguousarray(s[:, :, 2])


def intensity_gradient_stack(img: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``(H, W, 3)`` float32 ``[I, gx, gy]`` (half central differences, zero on the border)."""
    a = _as_image(img)
    if out is None or out.shape != a.shape + (3,) or out.dtype != np.float32:
        out = np.empty(a.shape + (3,), np.float32)
    _gradient_stack(a, out)
    return out


def warmup() -> None:
    """Compile (or load from the cache) every kernel of this module."""
    img = np.arange(16, dtype=np.float32).reshape(4, 4)
    image_pyramid(img, 2)
    idepth_pyramid(np.ones((4, 4), np.float32), np.ones((4, 4), np.float32), np.ones((4, 4), bool), 2)
    intensity_gradient_stack(img)
