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
* :func:`bspline_coefficient_stack` - cubic B-spline coefficients ((H, W, 1)), for
  bicubic-spline sampling in tracking (much less "pixel locking" than bilinear interpolation);
  :func:`bspline_horizon` - the length of its boundary initialisation sum.
* :func:`gaussian_blur` - separable Gaussian (mirror borders), the tracking images' anti-aliasing
  (optionally into a caller's buffer: the tracker reuses one per level).
* :func:`sharpness` - mean squared gradient over the intensity variance (motion-blur score).
* :func:`box_average2_u8` - a uint8 image's 2x2 box average as float32, the same values as
  ``cv2.resize(img.astype(np.float32), ..., interpolation=cv2.INTER_AREA)`` in one pass (the rectifier's
  path for cameras without distortion at half their resolution).
* :func:`warmup` - compiles every kernel of this module on tiny inputs.

The kernels named ``*_nb`` (:func:`gradient_stack_nb`, :func:`bspline_coefficients_nb`) are public for
other numba kernels to call (the tracker fuses them with its alignment); Python code uses the wrappers.

Imports numpy and numba only (no other lite_vo module, no OpenCV).
"""
from __future__ import annotations

import functools

import numpy as np
from numba import njit

__all__ = ["image_pyramid", "idepth_pyramid", "gradients", "intensity_gradient_stack", "bspline_coefficient_stack",
           "bspline_horizon", "downsample_image", "downsample_idepth", "gaussian_blur", "gaussian_kernel", "sharpness",
           "box_average2_u8", "warmup"]


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
def _box_average2_u8(img, out):
    """``out[y, x]`` = the mean of the 2x2 uint8 block: the integer sum is exact in float32 and the factor
    0.25 a power of two, so this equals OpenCV's float area resize by 2 bit for bit (vectorised)."""
    h, w = out.shape
    for y in range(h):
        r0 = img[2 * y]
        r1 = img[2 * y + 1]
        o = out[y]
        for x in range(w):
            o[x] = np.float32(np.int32(r0[2 * x]) + np.int32(r0[2 * x + 1]) + np.int32(r1[2 * x])
                              + np.int32(r1[2 * x + 1])) * np.float32(0.25)


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
def gradient_stack_nb(img, out):
    """``out[:, :, :3] = [I, gx, gy]`` of ``img`` (half central differences, zero on the border)."""
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


@njit(cache=True, nogil=True, fastmath=False)
def _bspline_prefilter_rows(c, r0, r1, horizon):
    """In-place cubic B-spline prefilter along the rows ``r0:r1`` of ``c`` (mirror boundaries; Unser 1993 /
    Thevenaz 2000). The rows' recursions run side by side, one step of each in turn: every value gets the
    same operations in the same order as a row-by-row pass (the same numbers bit for bit), but the
    independent chains overlap instead of waiting on one another (about 3x faster)."""
    w = c.shape[1]
    if w < 2:
        return
    z = np.sqrt(3.0) - 2.0
    for r in range(r0, r1):
        for k in range(w):
            c[r, k] *= 6.0                            # gain (1 - z)(1 - 1/z)
    # causal initialisation (mirror): sum_k z^k c[k], truncated where z^k is negligible
    m = horizon if horizon < w else w
    for r in range(r0, r1):
        zn = z
        s = c[r, 0]
        for k in range(1, m):
            s += zn * c[r, k]
            zn *= z
        c[r, 0] = s
    for k in range(1, w):
        for r in range(r0, r1):
            c[r, k] += z * c[r, k - 1]
    for r in range(r0, r1):
        c[r, w - 1] = (z / (z * z - 1.0)) * (c[r, w - 1] + z * c[r, w - 2])
    for k in range(w - 2, -1, -1):
        for r in range(r0, r1):
            c[r, k] = z * (c[r, k + 1] - c[r, k])


@njit(cache=True, nogil=True, fastmath=False)
def bspline_coefficients_nb(img, out, horizon):
    """Cubic B-spline coefficients of ``img`` into ``out[:, :, 0]`` (rows, then columns; the column
    recursion runs over whole rows at once so memory is read contiguously)."""
    h, w = img.shape
    c = np.empty((h, w))
    for y in range(h):
        for x in range(w):
            c[y, x] = img[y, x]
    for r0 in range(0, h, 8):                         # eight rows' recursions interleaved
        _bspline_prefilter_rows(c, r0, min(r0 + 8, h), horizon)
    if h >= 2:
        z = np.sqrt(3.0) - 2.0
        for y in range(h):
            for x in range(w):
                c[y, x] *= 6.0
        m = horizon if horizon < h else h
        zn = z
        for k in range(1, m):
            for x in range(w):
                c[0, x] += zn * c[k, x]
            zn *= z
        for y in range(1, h):
            for x in range(w):
                c[y, x] += z * c[y - 1, x]
        f = z / (z * z - 1.0)
        for x in range(w):
            c[h - 1, x] = f * (c[h - 1, x] + z * c[h - 2, x])
        for y in range(h - 2, -1, -1):
            for x in range(w):
                c[y, x] = z * (c[y + 1, x] - c[y, x])
    for y in range(h):
        for x in range(w):
            out[y, x, 0] = c[y, x]


@njit(cache=True, nogil=True, fastmath=False)
def _mirror(i, n):
    if i < 0:
        i = -i
    if i >= n:
        i = 2 * n - 2 - i
    return min(max(i, 0), n - 1)


@njit(cache=True, nogil=True, fastmath=False)
def _blur_separable(img, kern, tmp, out):
    """Separable convolution with the symmetric 1-D kernel ``kern`` (odd length), mirror borders.

    Interior loops are branch-free; the vertical pass runs along contiguous rows."""
    h, w = img.shape
    r = kern.shape[0] // 2
    for y in range(h):
        row = img[y]
        trow = tmp[y]
        for x in range(min(r, w)):
            s = 0.0
            for k in range(-r, r + 1):
                s += kern[k + r] * row[_mirror(x + k, w)]
            trow[x] = s
        for x in range(r, w - r):
            s = 0.0
            for k in range(-r, r + 1):
                s += kern[k + r] * row[x + k]
            trow[x] = s
        for x in range(max(w - r, r), w):
            s = 0.0
            for k in range(-r, r + 1):
                s += kern[k + r] * row[_mirror(x + k, w)]
            trow[x] = s
    for y in range(h):
        orow = out[y]
        for x in range(w):
            orow[x] = 0.0
        for k in range(-r, r + 1):
            src = tmp[_mirror(y + k, h)]
            c = kern[k + r]
            for x in range(w):
                orow[x] += c * src[x]


@njit(cache=True, nogil=True, fastmath=False)
def _sanitize_idepth(d_in, v_in, m_in, d_out, v_out, m_out):
    h, w = d_in.shape
    nan = np.float32(np.nan)
    for y in range(h):
        for x in range(w):
            d = d_in[y, x]
            v = v_in[y, x]
            ok = m_in[y, x] and d > 0 and v > 0 and d < np.inf and v < np.inf
            m_out[y, x] = ok
            d_out[y, x] = d if ok else nan
            v_out[y, x] = v if ok else nan


# a reduction only: "reassoc" lets LLVM vectorise the sums (summation order changes, nothing else)
@njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _gradient_energy(img):
    """(mean squared half-central-difference gradient over the interior, intensity variance)."""
    h, w = img.shape
    s = 0.0
    s1 = 0.0
    s2 = 0.0
    n = 0
    for y in range(1, h - 1):
        for x in range(1, w - 1):
            v = np.float64(img[y, x])
            gx = 0.5 * (np.float64(img[y, x + 1]) - img[y, x - 1])
            gy = 0.5 * (np.float64(img[y + 1, x]) - img[y - 1, x])
            s += gx * gx + gy * gy
            s1 += v
            s2 += v * v
            n += 1
    if n == 0:
        return np.nan, np.nan
    m = s1 / n
    return s / n, s2 / n - m * m


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


def box_average2_u8(img: np.ndarray) -> np.ndarray:
    """The 2x2 box average of a 2-D uint8 image as float32 ``(h // 2, w // 2)`` (an odd last row or column
    is ignored): bit for bit ``cv2.resize(img.astype(np.float32), (w // 2, h // 2), interpolation=cv2.INTER_AREA)``,
    in one pass without the full-size float copy (a third of the time for 640x480)."""
    a = np.asarray(img)
    if a.ndim != 2 or a.dtype != np.uint8:
        raise ValueError(f"box_average2_u8 needs a 2-D uint8 image, got {a.dtype} of shape {a.shape}")
    h, w = a.shape[0] // 2, a.shape[1] // 2
    if h < 1 or w < 1:
        raise ValueError(f"image of shape {a.shape} is too small to box-average by 2")
    out = np.empty((h, w), np.float32)
    _box_average2_u8(np.ascontiguousarray(a), out)
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
    d = np.ascontiguousarray(idepth, dtype=np.float32)
    v = np.ascontiguousarray(idepth_var, dtype=np.float32)
    m = np.ascontiguousarray(valid, dtype=np.bool_)
    if d.shape != v.shape or d.shape != m.shape or d.ndim != 2:
        raise ValueError(f"idepth {d.shape}, idepth_var {v.shape}, valid {m.shape} must be equal 2-D shapes")
    od, ov, om = np.empty_like(d), np.empty_like(v), np.empty_like(m)
    _sanitize_idepth(d, v, m, od, ov, om)
    return od, ov, om


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
    gradient_stack_nb(a, out)
    return out


def bspline_coefficient_stack(img: np.ndarray, out: np.ndarray | None = None, precision: float = 1e-7) -> np.ndarray:
    """``(H, W, 1)`` float32 holding the cubic B-spline coefficients of ``img`` (mirror boundaries;
    interpolating: evaluating the spline at pixel centres gives ``img`` back). Same array type as
    :func:`intensity_gradient_stack` (3-D, channel 0 read), for the tracking kernel's B-spline mode.
    ``precision`` sets where the boundary initialisation sum is truncated."""
    a = _as_image(img)
    if out is None or out.shape != a.shape + (1,) or out.dtype != np.float32:
        out = np.empty(a.shape + (1,), np.float32)
    bspline_coefficients_nb(a, out, bspline_horizon(precision))
    return out


@functools.lru_cache(maxsize=8)
def bspline_horizon(precision: float = 1e-7) -> int:
    """Terms of the B-spline prefilter's boundary initialisation sum: where ``z^k`` (``z = sqrt(3) - 2``)
    falls below ``precision``."""
    return int(np.ceil(np.log(precision) / np.log(2.0 - np.sqrt(3.0)))) + 1


def gaussian_kernel(sigma: float, truncate: float = 2.5) -> np.ndarray:
    """Normalised 1-D Gaussian of std ``sigma`` px, radius ``ceil(truncate * sigma)`` (at least 1).
    Cached (every frame blurs with the same few): the array is shared, do not modify it (it stays
    writeable because numba compiles read-only arrays as another type)."""
    return _gaussian_kernel(float(sigma), float(truncate))


@functools.lru_cache(maxsize=64)
def _gaussian_kernel(sigma: float, truncate: float) -> np.ndarray:
    r = max(1, int(np.ceil(truncate * sigma)))
    x = np.arange(-r, r + 1, dtype=np.float64)
    k = np.exp(-0.5 * (x / sigma) ** 2)
    return k / k.sum()


def gaussian_blur(img: np.ndarray, sigma: float, truncate: float = 2.5, out: np.ndarray | None = None) -> np.ndarray:
    """Separable Gaussian blur (float32, mirror borders); ``sigma <= 0`` returns a float32 copy.
    ``out``: a C-contiguous float32 array of the image's shape to write the result into (returned), or
    None (a new array); it must not be the input."""
    a = _as_image(img)
    if out is not None and (out.shape != a.shape or out.dtype != np.float32 or not out.flags.c_contiguous):
        raise ValueError(f"out: expected a C-contiguous float32 array of shape {a.shape}, got {out.dtype} {out.shape}")
    if not sigma > 0:
        if out is None:
            return a.copy()
        out[...] = a
        return out
    kern = gaussian_kernel(sigma, truncate)
    if min(a.shape) > kern.shape[0] // 2:
        # OpenCV's SIMD filter, about 12x faster than the loop below at 160x120 (float32 sums: equal
        # to it within float32 rounding); its reflect-101 border is the loop's mirror when the image is
        # larger than the kernel's radius
        import cv2
        if out is None:
            return cv2.sepFilter2D(a, cv2.CV_32F, kern, kern, borderType=cv2.BORDER_REFLECT_101)
        return cv2.sepFilter2D(a, cv2.CV_32F, kern, kern, dst=out, borderType=cv2.BORDER_REFLECT_101)
    if out is None:
        out = np.empty_like(a)
    _blur_separable(a, kern, np.empty_like(a), out)
    return out


def sharpness(img: np.ndarray) -> float:
    """Mean squared gradient over the intensity variance (1/px^2): motion blur lowers the first and
    hardly changes the second; both scale with the gain squared and ignore an offset, so an exposure
    change does not look like blur. NaN for a flat or tiny image."""
    g2, var = _gradient_energy(_as_image(img))
    return float(g2 / var) if var > 1e-6 else float("nan")


def warmup() -> None:
    """Compile (or load from the cache) every kernel of this module."""
    img = np.arange(16, dtype=np.float32).reshape(4, 4)
    image_pyramid(img, 2)
    idepth_pyramid(np.ones((4, 4), np.float32), np.ones((4, 4), np.float32), np.ones((4, 4), bool), 2)
    intensity_gradient_stack(img)
    bspline_coefficient_stack(img)
    gaussian_blur(img, 0.7)
    sharpness(img)
    u8 = np.zeros((4, 4), np.uint8)
    box_average2_u8(u8)
    u8.flags.writeable = False      # frames decoded by a reader may be read-only
    box_average2_u8(u8)
    img_ro = img.copy()
    img_ro.flags.writeable = False  # pyramids handed to a TrackingReference become read-only
    gaussian_blur(img_ro, 0.7)
