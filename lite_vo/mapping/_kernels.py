"""numba kernels of the per-pixel inverse-depth filter (chapter 3.2 of the thesis).

Owns: image gradients for mapping, the epipolar line search (`line_stereo`), the stereo
observation pass over the whole map (`observe_kernel`), forward-warping propagation
(`propagate_kernel`), regularisation (`regularize_kernel`), hole filling (`fill_kernel`), the
outcome counts (`count_codes`), the published map (`masked_map`) and the allocators of the kernels'
scratch (`propagation_work`, `fill_work`, `regularize_work`: made once per Mapper). Every threshold is an argument: one float64 parameter vector ``prm`` built once per configuration
by ``lite_vo.mapping.mapper.mapping_params`` (the ``P_*`` constants below are only indices into
it). Kernels never allocate per pixel; the :class:`~lite_vo.mapping.mapper.Mapper` validates inputs
and allocates outputs and scratch.

Map state (:class:`MapState`, a namedtuple of HxW arrays, one entry per pixel of the current frame):
``idepth, idepth_var`` (float32, the filter state), ``idepth_s, var_s`` (float32, regularised
values used for tracking and as stereo prior), ``valid`` (uint8), ``validity`` (float32 counter),
``pos_x, pos_y`` (float32 sub-pixel location of the hypothesis), ``ref_id`` (int64, oldest frame
id usable as stereo reference), ``blacklist`` (int32, decremented on removals/failed creations),
``skip`` (int32, stereo iterations still to skip: a converged pixel waits for more baseline).

The buffer of stereo reference frames is a :class:`RefFrames` namedtuple (oldest first).

Imports: numpy and numba only (no module of this package: the warm-up calls the kernels directly).
"""
from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import njit, prange

# indices into the stereo parameter vector (layout fixed; values come from MappingConfig)
P_MIN_GRAD = 0
P_MIN_EPL_LENGTH = 1
P_MIN_EPL_GRAD_SQ = 2
P_MIN_EPL_ANGLE_COS = 3
P_MAX_IDEPTH = 4          # 1 / min_depth
P_MAX_EPL = 5
P_MIN_EPL = 6
P_SSD_MAX = 7
P_SSD_GRAD_FACTOR = 8
P_AMBIGUITY = 9
P_MIN_SCALE = 10
P_MAX_SCALE = 11
P_SUBPIXEL = 12
P_SIGMA_I2 = 13
P_MAX_VAR = 14
P_PRED_NOISE = 15
P_FAIL_VAR_INC = 16
P_BORDER_SAMPLES = 17
P_MIN_CLIPPED_EPL = 18
P_GEO_BASE = 19
P_SUBPIX_VAR = 20
P_NOSUBPIX_VAR = 21
P_SEARCH_SIGMAS = 22
P_DIFF_FAC_OBSERVE = 23
P_VALIDITY_INC = 24
P_VALIDITY_DEC = 25
P_VALIDITY_MAX = 26
P_VALIDITY_MAX_GRAD = 27
P_OBSERVE_VALIDITY = 28
P_CREATE_PRIOR = 29
P_MIN_BLACKLIST = 30
P_SKIP_CONVERGED = 31
P_BORDER = 32             # propagation: drop hypotheses this close to the border
P_PROP_DIFF_CONST2 = 33   # propagation intensity check: r^2 / (this + P_PROP_DIFF_GRAD * g^2) > 1 drops
P_PROP_DIFF_GRAD = 34
P_PROP_MERGE = 35         # collisions fuse when this * diff^2 <= var_a + var_b
P_PROP_VAR_ADD = 36       # sigma_p^2 added on propagation
P_VALIDITY_CAP = 37       # validity_max + validity_max_grad
P_REG_RADIUS = 38
P_REG_DIST_VAR = 39
P_REG_DIFF_FAC = 40
P_REG_VALIDITY_SUM = 41
P_REG_VAR_MODE = 42       # 0 min, 1 own, 2 fused
P_FILL_VALIDITY_SUM = 43
P_UNBLACKLIST_SUM = 44
P_INIT_VAR = 45
P_FILL_VALIDITY = 46
P_SATURATION = 47         # intensities at or above this are clipped: never matched, never compared ...
P_SAT_GAIN_TOL = 48       # ... when the brightness transfer's gain differs from 1 by more than this
P_KEEP_CLIPPED = 49     # 1: a hypothesis whose pixel is clipped and flat is kept, not removed
P_N = 50

#: the per-pixel arrays of a map (see the module docstring for dtypes)
MapState = namedtuple("MapState", ["idepth", "idepth_var", "idepth_s", "var_s", "valid", "validity",
                                   "pos_x", "pos_y", "ref_id", "blacklist", "skip"])
#: the stereo reference buffer, oldest first: ``images`` (slots, H, W) float32, ``slots`` / ``ids``
#: (n,) int64, ``R`` / ``t`` (n, 3, 3) / (n, 3) T_ref_cur, ``c`` (n, 3) reference centres in the
#: current camera, ``residual`` (n,) tracking residual of each reference, ``affine`` (n, 2) the
#: brightness transfer ``(a, b)`` of each reference into the current frame: ``I_cur ~ a I_ref + b``
#: scratch of :func:`propagate_kernel` (HxW each): where each hypothesis lands (flat index or a
#: negative drop code), its new inverse depth and variance, its sub-pixel position in the new frame;
#: (H,) each: the smallest and largest target row of each source row's hypotheses
PropagationWork = namedtuple("PropagationWork", ["target", "idepth", "var", "u", "v", "row_lo", "row_hi"])
#: scratch of :func:`fill_kernel` (HxW each): horizontal 5-sums of validity, idepth/var and 1/var
#: (float64) and the 5-minimum of ref_id (int64)
FillWork = namedtuple("FillWork", ["validity", "idepth", "inv_var", "ref_id"])
#: scratch of :func:`regularize_kernel` ((H+2r)x(W+2r) float32 each): the map padded by the radius r:
#: inverse depth (NaN without a hypothesis), variance, validity
RegularizeWork = namedtuple("RegularizeWork", ["idepth", "var", "validity"])
RefFrames = namedtuple("RefFrames", ["images", "slots", "ids", "R", "t", "c", "residual", "affine"])

# return codes of line_stereo
OK = 0
OUT_OF_IMAGE = -1      # line (or the scale change) unusable with this reference: try a newer one
BAD_MATCH = -2         # ambiguous match or negative depth
NO_MATCH = -3          # matching error too high
NUMERIC = -4           # NaN / inf / empty line
TOO_LONG = -5          # full search line longer than max_epl: try a newer reference
NO_EPL = -6            # (observe only) epipolar line too short or gradient along it too weak


@njit(cache=True, nogil=True, inline="always")
def _min2(a, b):
    """``min(a, b)`` as a select (the same value, NaN included). numba compiles the builtins ``min``,
    ``max`` and ``int`` of scalars as calls that LLVM leaves out of line: a loop with one is not vectorised."""
    return b if b < a else a


@njit(cache=True, nogil=True, inline="always")
def _max2(a, b):
    """``max(a, b)`` as a select (the same value, NaN included); see :func:`_min2`."""
    return b if b > a else a


@njit(cache=True, nogil=True, fastmath=False, error_model="numpy", inline="always")
def _bilinear(img, x, y):
    """Bilinear sample; the caller guarantees 0 <= x < W-1 and 0 <= y < H-1 (unsigned indices: numba
    skips its negative-index wrap-around)."""
    ix = np.int64(x)
    iy = np.int64(y)
    dx = x - ix
    dy = y - iy
    ux = np.uint64(ix)
    uy = np.uint64(iy)
    one = np.uint64(1)
    return ((1.0 - dx) * (1.0 - dy) * img[uy, ux] + dx * (1.0 - dy) * img[uy, ux + one]
            + (1.0 - dx) * dy * img[uy + one, ux] + dx * dy * img[uy + one, ux + one])


#: rows per block of the parallel stereo pass's row order (:func:`interleaved_rows`)
ROW_BLOCK = 8
#: bands of target rows per numba thread in the parallel collision pass of :func:`propagate_kernel`
#: (see :func:`propagation_bands`)
PROPAGATE_BANDS_PER_THREAD = 4


@njit(cache=True, nogil=True)
def interleaved_rows(lo, hi, block, nthreads):
    """The rows ``lo .. hi-1`` in blocks of ``block`` rows, the blocks ordered by their index modulo
    ``nthreads`` (blocks 0, T, 2T, .., then 1, T+1, .., ...; the natural order for one thread).

    A parallel loop over this order hands each of the ``nthreads`` threads (numba splits the range into
    equal contiguous parts) every T-th block, i.e. rows from the whole image instead of one part of it:
    the stereo work per row follows the scene (on ICL the lower half has 1.5x the searches of the
    upper). Rows inside a block stay consecutive (neighbouring rows read neighbouring reference
    pixels, from the cache). Every row is processed exactly once, so the result does not change."""
    n = max(hi - lo, 0)
    out = np.empty(n, np.int64)
    if nthreads <= 1 or block < 1:
        for k in range(n):
            out[k] = lo + k
        return out
    nblocks = (n + block - 1) // block
    k = 0
    for c in range(min(nthreads, nblocks)):
        for bi in range(c, nblocks, nthreads):
            for y in range(lo + bi * block, min(lo + (bi + 1) * block, hi)):
                out[k] = y
                k += 1
    return out


@njit(cache=True, nogil=True, fastmath=False, error_model="numpy", parallel=True)
def gradients_kernel(img, gx, gy, maxgrad):
    """Half central differences (0 on the 1-pixel border) and the 3x3 max filter of |g|.

    float32 throughout, branch-free rows (vectorised); the max filter is separable (rows, then columns).
    Each pass runs in parallel over rows (every output value is computed on its own: the result does not
    depend on the number of threads)."""
    h, w = img.shape
    mag = np.zeros((h, w), np.float32)
    rowmax = np.zeros((h, w), np.float32)
    for y in prange(h):
        if y == 0 or y == h - 1:
            for x in range(w):
                gx[y, x] = 0.0
                gy[y, x] = 0.0
            continue
        gx[y, 0] = 0.0
        gy[y, 0] = 0.0
        gx[y, w - 1] = 0.0
        gy[y, w - 1] = 0.0
        for x in range(1, w - 1):
            a = np.float32(0.5) * (img[y, x + 1] - img[y, x - 1])
            b = np.float32(0.5) * (img[y + 1, x] - img[y - 1, x])
            gx[y, x] = a
            gy[y, x] = b
            mag[y, x] = math.sqrt(a * a + b * b)
    for y in prange(h):
        if w == 1:
            rowmax[y, 0] = mag[y, 0]
            continue
        rowmax[y, 0] = _max2(mag[y, 0], mag[y, 1])
        rowmax[y, w - 1] = _max2(mag[y, w - 2], mag[y, w - 1])
        for x in range(1, w - 1):
            rowmax[y, x] = _max2(_max2(mag[y, x - 1], mag[y, x]), mag[y, x + 1])
    for y in prange(h):
        y0 = _max2(y - 1, 0)
        y1 = _min2(y + 1, h - 1)
        for x in range(w):
            maxgrad[y, x] = _max2(_max2(rowmax[y0, x], rowmax[y, x]), rowmax[y1, x])


@njit(cache=True, nogil=True, fastmath=False, error_model="numpy", inline="always")
def epipolar_direction(cur, x, y, px, py, c, fx, fy, cx, cy, prm):
    """Epipolar direction at pixel (x, y) (sub-pixel position (px, py)) for a reference whose
    centre is ``c`` in current-camera coordinates. Returns (ok, epx_unit, epy_unit)."""
    epx = -fx * c[0] + c[2] * (px - cx)
    epy = -fy * c[1] + c[2] * (py - cy)
    len2 = epx * epx + epy * epy
    # written so that NaN fails the test (the reference code's precedence slip let NaN through)
    if not (len2 >= prm[P_MIN_EPL_LENGTH] * prm[P_MIN_EPL_LENGTH]):
        return False, 0.0, 0.0
    gxf = np.float64(cur[y, x + 1]) - cur[y, x - 1]
    gyf = np.float64(cur[y + 1, x]) - cur[y - 1, x]
    dot = gxf * epx + gyf * epy
    eplgrad2 = dot * dot / len2
    if not (eplgrad2 >= prm[P_MIN_EPL_GRAD_SQ]):
        return False, 0.0, 0.0
    g2 = gxf * gxf + gyf * gyf
    if not (eplgrad2 >= prm[P_MIN_EPL_ANGLE_COS] * prm[P_MIN_EPL_ANGLE_COS] * g2):
        return False, 0.0, 0.0
    n = math.sqrt(len2)
    return True, epx / n, epy / n


@njit(cache=True, nogil=True, fastmath=False, error_model="numpy", inline="always")
def line_length(u, v, min_id, max_id, R, t, fx, fy, cx, cy):
    """Length in pixels of the epipolar segment of inverse depths [min_id, max_id] (inf if unusable)."""
    rx = (u - cx) / fx
    ry = (v - cy) / fy
    ax = R[0, 0] * rx + R[0, 1] * ry + R[0, 2]
    ay = R[1, 0] * rx + R[1, 1] * ry + R[1, 2]
    az = R[2, 0] * rx + R[2, 1] * ry + R[2, 2]
    if az + max_id * t[2] < 0.001:
        max_id = (0.001 - az) / t[2]
    zf = az + min_id * t[2]
    zc = az + max_id * t[2]
    if not (zf >= 0.001 and max_id >= min_id):
        return np.inf
    dx = fx * ((ax + max_id * t[0]) / zc - (ax + min_id * t[0]) / zf)
    dy = fy * ((ay + max_id * t[1]) / zc - (ay + min_id * t[1]) / zf)
    n = math.sqrt(dx * dx + dy * dy)
    return n if math.isfinite(n) else np.inf


@njit(cache=True, nogil=True, fastmath=False, error_model="numpy", inline="always")
def _slide_into(p, q, dp, dq, lo, hi):
    """Move the point (p, q) along (dp, dq) until p lies on ``lo`` or ``hi`` when it is at or beyond
    that bound; returns it unchanged when ``lo < p < hi``."""
    if p <= lo:
        k = (lo - p) / dp
    elif p >= hi:
        k = (hi - p) / dp
    else:
        return p, q
    return p + k * dp, q + k * dq


@njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def _min_in(a, lo, hi):
    """The smallest of ``a[lo:hi]`` below 1e50, else 1e50 (NaN never counts): what one scan with ``<``
    starting from 1e50 finds, as four interleaved scans (no chain of dependent compares: the stereo
    pass's best and second-best match, 10 % of its time). Not inlined by numba: a copy per call site
    added a fifth to the mapping kernels' compile time (the warm-up), for no speed."""
    m0 = 1e50
    m1 = 1e50
    m2 = 1e50
    m3 = 1e50
    k = lo
    while k + 4 <= hi:
        v0 = a[k]
        v1 = a[k + 1]
        v2 = a[k + 2]
        v3 = a[k + 3]
        m0 = v0 if v0 < m0 else m0
        m1 = v1 if v1 < m1 else m1
        m2 = v2 if v2 < m2 else m2
        m3 = v3 if v3 < m3 else m3
        k += 4
    while k < hi:
        v0 = a[k]
        m0 = v0 if v0 < m0 else m0
        k += 1
    m0 = m1 if m1 < m0 else m0
    m2 = m3 if m3 < m2 else m2
    return m2 if m2 < m0 else m0


@njit(cache=True, nogil=True, fastmath=False, error_model="numpy", inline="always")
def line_stereo(cur, ref, u, v, epxn, epyn, min_id, prior_id, max_id, R, t, fx, fy, cx, cy,
                gxi, gyi, track_residual, prm, allow_long, ref_a, ref_b, samples, ssd, frac_y, at):
    """Search the epipolar line of current pixel (u, v) in ``ref``.

    ``R, t`` = T_ref_cur; ``(epxn, epyn)`` unit epipolar direction in the current image;
    ``ref_a, ref_b``: brightness transfer of the reference into the current frame (the SSD compares
    ``ref_a * I_ref + ref_b`` with ``I_cur``: exposure changes do not bias the match);
    ``(gxi, gyi)`` half-central-difference gradient at (u, v); ``samples``, ``ssd``, ``frac_y`` (float64)
    and ``at`` (int32) scratch.
    Returns (code, idepth, idepth_var, epl_length, error).
    """
    h, w = cur.shape
    rx = (u - cx) / fx
    ry = (v - cy) / fy
    ax = R[0, 0] * rx + R[0, 1] * ry + R[0, 2]
    ay = R[1, 0] * rx + R[1, 1] * ry + R[1, 2]
    az = R[2, 0] * rx + R[2, 1] * ry + R[2, 2]
    tx, ty, tz = t[0], t[1], t[2]
    rescale = az + prior_id * tz
    if not (rescale > prm[P_MIN_SCALE] and rescale < prm[P_MAX_SCALE]):
        return OUT_OF_IMAGE, 0.0, 0.0, 0.0, 0.0
    # far and near end of the inverse depth interval, projected into the reference
    if az + max_id * tz < 0.001:
        max_id = (0.001 - az) / tz
    if az + min_id * tz < 0.001 or max_id < min_id:
        return OUT_OF_IMAGE, 0.0, 0.0, 0.0, 0.0
    zf = az + min_id * tz
    far_x = fx * (ax + min_id * tx) / zf + cx
    far_y = fy * (ay + min_id * ty) / zf + cy
    zc = az + max_id * tz
    close_x = fx * (ax + max_id * tx) / zc + cx
    close_y = fy * (ay + max_id * ty) / zc + cy
    if not (math.isfinite(far_x + far_y + close_x + close_y)):
        return NUMERIC, 0.0, 0.0, 0.0, 0.0
    incx = close_x - far_x
    incy = close_y - far_y
    epl_length = math.sqrt(incx * incx + incy * incy)
    if not (epl_length > 0.0) or not math.isfinite(epl_length):
        return NUMERIC, 0.0, 0.0, 0.0, 0.0
    if epl_length > prm[P_MAX_EPL]:
        if not allow_long:
            return TOO_LONG, 0.0, 0.0, epl_length, 0.0
        close_x = far_x + incx * prm[P_MAX_EPL] / epl_length
        close_y = far_y + incy * prm[P_MAX_EPL] / epl_length
    incx /= epl_length
    incy /= epl_length
    # one extra sample on each side, then pad short lines to the minimum length
    far_x -= incx
    far_y -= incy
    close_x += incx
    close_y += incy
    if epl_length < prm[P_MIN_EPL]:
        pad = 0.5 * (prm[P_MIN_EPL] - epl_length)
        far_x -= incx * pad
        far_y -= incy * pad
        close_x += incx * pad
        close_y += incy * pad
    b = prm[P_BORDER_SAMPLES]
    if far_x <= b or far_x >= w - b or far_y <= b or far_y >= h - b:
        return OUT_OF_IMAGE, 0.0, 0.0, 0.0, 0.0
    if close_x <= b or close_x >= w - b or close_y <= b or close_y >= h - b:
        # clip the near end into the image along the line
        close_x, close_y = _slide_into(close_x, close_y, incx, incy, b, w - b)
        close_y, close_x = _slide_into(close_y, close_x, incy, incx, b, h - b)
        dxl = close_x - far_x
        dyl = close_y - far_y
        if (not (close_x > b and close_x < w - b and close_y > b and close_y < h - b)
                or not (math.sqrt(dxl * dxl + dyl * dyl) >= prm[P_MIN_CLIPPED_EPL])):
            return OUT_OF_IMAGE, 0.0, 0.0, 0.0, 0.0
    # the five samples in the current image, one (scaled) pixel apart along the line
    sx = epxn * rescale
    sy = epyn * rescale
    first_x = u - 2.0 * sx
    first_y = v - 2.0 * sy
    last_x = u + 2.0 * sx
    last_y = v + 2.0 * sy
    if not (first_x > 0.0 and first_x < w - 2.0 and first_y > 0.0 and first_y < h - 2.0
            and last_x > 0.0 and last_x < w - 2.0 and last_y > 0.0 and last_y < h - 2.0):
        return OUT_OF_IMAGE, 0.0, 0.0, 0.0, 0.0
    c0 = _bilinear(cur, u - 2.0 * sx, v - 2.0 * sy)
    c1 = _bilinear(cur, u - sx, v - sy)
    c2 = _bilinear(cur, u, v)
    c3 = _bilinear(cur, u + sx, v + sy)
    c4 = _bilinear(cur, u + 2.0 * sx, v + 2.0 * sy)
    # clipped pixels: where the exposure changed, a clipped patch's edges move with it
    sat = prm[P_SATURATION] if abs(ref_a - 1.0) > prm[P_SAT_GAIN_TOL] else np.inf
    if c0 >= sat or c1 >= sat or c2 >= sat or c3 >= sat or c4 >= sat:
        return NO_EPL, 0.0, 0.0, 0.0, 0.0      # a clipped patch: its edges move with the exposure

    dxl = close_x - far_x
    dyl = close_y - far_y
    n_steps = np.int64(math.sqrt(dxl * dxl + dyl * dyl) + 1e-6) + 1
    if n_steps + 4 > samples.shape[0]:
        n_steps = samples.shape[0] - 4
    # reference samples at far + (j - 2) * inc, j = 0 .. n_steps + 3 (all inside by the border test)
    # bilinear, the same arithmetic as _bilinear, in two loops: the positions (vectorised; their x
    # fractions kept in ssd until the SSDs overwrite them), then the four pixels of each. The positions
    # are positive, so floor = truncation; floor, an int32 index and an int32 counter keep every conversion
    # a packed AVX2 one (there is none to or from int64; int() is even a call): the loop went from a fifth
    # of the stereo pass's time to 4 %, and a loop that also samples (one loop) is slower
    rw = ref.shape[1]
    flat = ref.reshape(ref.size)
    frw = np.float64(rw)
    for j in range(n_steps + 4):
        fj = np.float64(np.int32(j - 2))
        x = far_x + fj * incx
        y = far_y + fj * incy
        fx0 = np.floor(x)
        fy0 = np.floor(y)
        ssd[j] = x - fx0
        frac_y[j] = y - fy0
        at[j] = np.int32(fy0 * frw + fx0)
    one = np.uint64(1)
    down = np.uint64(rw)
    down1 = np.uint64(rw + 1)
    for j in range(n_steps + 4):
        k = np.uint64(at[j])
        dx = ssd[j]
        dy = frac_y[j]
        sv = ((1.0 - dx) * (1.0 - dy) * flat[k] + dx * (1.0 - dy) * flat[k + one]
              + (1.0 - dx) * dy * flat[k + down] + dx * dy * flat[k + down1])
        samples[j] = ref_a * sv + ref_b if sv < sat else 1e6     # clipped: no window through it matches
    # the SSD of every window first (a branch-free loop), then the best: 4 % less stereo time than one loop
    for k in range(n_steps):
        e0 = samples[k] - c0
        e1 = samples[k + 1] - c1
        e2 = samples[k + 2] - c2
        e3 = samples[k + 3] - c3
        e4 = samples[k + 4] - c4
        ssd[k] = e0 * e0 + e1 * e1 + e2 * e2 + e3 * e3 + e4 * e4
    best_err = _min_in(ssd, 0, n_steps)
    best = 0                     # the first window with the smallest SSD (0 when none is below 1e50)
    if best_err < 1e50:
        while ssd[best] != best_err:
            best += 1
    # the second best: the smallest SSD at least two windows from the best (NaN never counts)
    for k in range(_max2(best - 1, 0), _min2(best + 2, n_steps)):
        ssd[k] = np.nan
    second_err = _min_in(ssd, 0, n_steps)
    if not (best_err <= 4.0 * prm[P_SSD_MAX]):
        return NO_MATCH, 0.0, 0.0, epl_length, best_err
    if prm[P_AMBIGUITY] * best_err > second_err:
        return BAD_MATCH, 0.0, 0.0, epl_length, best_err

    # sub-pixel: minimise |r_b + s (r_j - r_b)|^2 towards either neighbour (line ends handled)
    pos = np.float64(best)
    err = best_err
    did_subpixel = False
    if prm[P_SUBPIXEL] > 0.5:
        best_side_err = best_err
        best_side_pos = pos
        for side in (-1, 1):
            j = best + side
            if j < 0 or j >= n_steps:
                continue
            rb0 = samples[best] - c0
            rb1 = samples[best + 1] - c1
            rb2 = samples[best + 2] - c2
            rb3 = samples[best + 3] - c3
            rb4 = samples[best + 4] - c4
            rj0 = samples[j] - c0
            rj1 = samples[j + 1] - c1
            rj2 = samples[j + 2] - c2
            rj3 = samples[j + 3] - c3
            rj4 = samples[j + 4] - c4
            bb = rb0 * rb0 + rb1 * rb1 + rb2 * rb2 + rb3 * rb3 + rb4 * rb4
            bj = rb0 * rj0 + rb1 * rj1 + rb2 * rj2 + rb3 * rj3 + rb4 * rj4
            jj = rj0 * rj0 + rj1 * rj1 + rj2 * rj2 + rj3 * rj3 + rj4 * rj4
            den = bb - 2.0 * bj + jj
            num = bb - bj
            if den > 0.0 and num > 0.0:
                s = num / den
                if s < 1.0:
                    e_s = bb - num * num / den
                    if e_s < best_side_err:
                        best_side_err = e_s
                        best_side_pos = best + side * s
        if best_side_pos != pos:
            did_subpixel = True
            pos = best_side_pos
            err = best_side_err
    grad_along = ((c1 - c0) * (c1 - c0) + (c2 - c1) * (c2 - c1) + (c3 - c2) * (c3 - c2)
                  + (c4 - c3) * (c4 - c3))
    if err > prm[P_SSD_MAX] + math.sqrt(grad_along) * prm[P_SSD_GRAD_FACTOR]:
        return NO_MATCH, 0.0, 0.0, epl_length, err

    bx = far_x + pos * incx
    by = far_y + pos * incy
    if incx * incx > incy * incy:
        xn = (bx - cx) / fx
        den = xn * tz - tx
        idepth = (ax - xn * az) / den
        alpha = incx / fx * (az * tx - ax * tz) / (den * den)
    else:
        yn = (by - cy) / fy
        den = yn * tz - ty
        idepth = (ay - yn * az) / den
        alpha = incy / fy * (az * ty - ay * tz) / (den * den)
    if not (idepth >= 0.0) or not math.isfinite(alpha):
        return BAD_MATCH, 0.0, 0.0, epl_length, err
    photo = 4.0 * prm[P_SIGMA_I2] / (grad_along + 1e-10)
    e = prm[P_GEO_BASE] * (1.0 + track_residual)
    gdot = gxi * epxn + gyi * epyn + 1e-10
    geo = e * e * (gxi * gxi + gyi * gyi) / (gdot * gdot)
    c = prm[P_SUBPIX_VAR] if did_subpixel else prm[P_NOSUBPIX_VAR]
    var = alpha * alpha * (c + geo + photo)
    if not (var > 0.0 and math.isfinite(var)):
        return NUMERIC, 0.0, 0.0, epl_length, err
    return OK, idepth, var, epl_length, err


@njit(cache=True, nogil=True, fastmath=False, error_model="numpy", parallel=True)
def observe_kernel(cur, gx, gy, maxgrad, refs, st, cam, prm, stride, offset, scratch_len, status, row_groups=1):
    """One stereo pass over the map ``st`` (a :class:`MapState`, in place) against the reference
    buffer ``refs`` (:class:`RefFrames`, oldest -> newest); ``cam = (fx, fy, cx, cy)``.

    status per pixel: 0 not tried, 1 updated, 2 created, 3 inconsistent, 4 failed search
    (no/bad match), 5 no usable reference (line outside the image, scale change, NaN),
    6 removed (gradient too low), 7 epipolar line unusable (too short, weak gradient along it),
    8 skipped (converged: its last search line was shorter than min_epl_search).

    ``row_groups``: the rows are visited in the order of :func:`interleaved_rows` with this many
    groups (pass the number of numba threads: balances them; 1 = top to bottom). The result does
    not depend on it.
    """
    ref_images, ref_slots, ref_ids, ref_R, ref_t, ref_c, ref_residual, ref_aff = refs
    idepth, idepth_var, idepth_s, var_s, valid, validity, pos_x, pos_y, ref_id, blacklist, skip = st
    fx, fy, cx, cy = cam[0], cam[1], cam[2], cam[3]
    h, w = cur.shape
    nref = ref_slots.shape[0]
    min_grad = prm[P_MIN_GRAD]
    max_idepth_all = prm[P_MAX_IDEPTH]
    keep_clipped = prm[P_KEEP_CLIPPED] > 0.5
    rows = interleaved_rows(3, h - 3, ROW_BLOCK, row_groups)
    for yi in prange(rows.shape[0]):
        y = rows[yi]
        samples = np.empty(scratch_len, np.float64)
        ssd = np.empty(scratch_len, np.float64)
        frac_y = np.empty(scratch_len, np.float64)
        at = np.empty(scratch_len, np.int32)
        for x in range(3, w - 3):
            status[y, x] = 0
            has = valid[y, x] != 0
            g = maxgrad[y, x]
            if has and g < min_grad:
                if keep_clipped and cur[y, x] >= prm[P_SATURATION]:
                    continue              # flattened by clipping, not textureless: kept until it can be seen
                valid[y, x] = 0
                status[y, x] = 6
                continue
            if g < min_grad or blacklist[y, x] < prm[P_MIN_BLACKLIST]:
                continue
            if stride > 1 and (y * w + x) % stride != offset:
                continue
            if nref == 0:
                continue
            if has and skip[y, x] > 0:
                skip[y, x] -= 1
                status[y, x] = 8
                continue
            if has:
                px = np.float64(pos_x[y, x])
                py = np.float64(pos_y[y, x])
                prior = np.float64(idepth_s[y, x])
                sd = math.sqrt(var_s[y, x])
                lo = prior - prm[P_SEARCH_SIGMAS] * sd
                hi = prior + prm[P_SEARCH_SIGMAS] * sd
                if lo < 0.0:
                    lo = 0.0
                if hi > max_idepth_all:
                    hi = max_idepth_all
                b = 0
                while b < nref - 1 and ref_ids[b] < ref_id[y, x]:
                    b += 1
            else:
                px = np.float64(x)
                py = np.float64(y)
                prior = prm[P_CREATE_PRIOR]
                lo = 0.0
                hi = max_idepth_all
                # the oldest reference whose full-range line still fits: walk back from the newest
                b = nref - 1
                while b > 0 and line_length(px, py, lo, hi, ref_R[b - 1], ref_t[b - 1], fx, fy, cx,
                                            cy) <= prm[P_MAX_EPL]:
                    b -= 1
            code = OUT_OF_IMAGE
            r_id = 0.0
            r_var = 0.0
            r_len = 0.0
            used = b
            gxi = _bilinear(gx, px, py)      # the same for every reference
            gyi = _bilinear(gy, px, py)
            while b < nref:
                slot = ref_slots[b]
                ok, epxn, epyn = epipolar_direction(cur, x, y, px, py, ref_c[b], fx, fy, cx, cy, prm)
                if not ok:
                    code = NO_EPL
                    break
                code, r_id, r_var, r_len, r_err = line_stereo(
                    cur, ref_images[slot], px, py, epxn, epyn, lo, prior, hi, ref_R[b], ref_t[b],
                    fx, fy, cx, cy, gxi, gyi, ref_residual[b], prm, b == nref - 1, ref_aff[b, 0], ref_aff[b, 1],
                    samples, ssd, frac_y, at)
                used = b
                if code == OUT_OF_IMAGE or code == TOO_LONG:
                    b += 1
                    continue
                break
            if code == NO_EPL:
                status[y, x] = 7
                continue
            if code == OUT_OF_IMAGE or code == TOO_LONG or code == NUMERIC:
                status[y, x] = 5
                continue
            if has and ref_ids[used] > ref_id[y, x]:
                ref_id[y, x] = ref_ids[used]     # older references were unusable: skip them from now on
            if not has:
                if code == OK and r_var <= prm[P_MAX_VAR]:
                    idepth[y, x] = r_id
                    idepth_var[y, x] = r_var
                    idepth_s[y, x] = r_id
                    var_s[y, x] = r_var
                    valid[y, x] = 1
                    validity[y, x] = prm[P_OBSERVE_VALIDITY]
                    pos_x[y, x] = px
                    pos_y[y, x] = py
                    ref_id[y, x] = ref_ids[used]
                    blacklist[y, x] = 0
                    skip[y, x] = 0
                    status[y, x] = 2
                elif code == BAD_MATCH or code == NO_MATCH:
                    blacklist[y, x] -= 1
                    status[y, x] = 4
                continue
            if code == BAD_MATCH or code == NO_MATCH:
                # failed search: lower validity, move on to a newer reference frame
                vnew = validity[y, x] - prm[P_VALIDITY_DEC]
                validity[y, x] = vnew if vnew > 0.0 else 0.0
                ref_id[y, x] = ref_ids[used] + 1
                if code == BAD_MATCH:
                    idepth_var[y, x] *= prm[P_FAIL_VAR_INC]
                    if idepth_var[y, x] > prm[P_MAX_VAR]:
                        valid[y, x] = 0
                        blacklist[y, x] -= 1
                status[y, x] = 4
                continue
            diff = r_id - prior
            if prm[P_DIFF_FAC_OBSERVE] * diff * diff > r_var + var_s[y, x]:
                idepth_var[y, x] *= prm[P_FAIL_VAR_INC]
                if idepth_var[y, x] > prm[P_MAX_VAR]:
                    valid[y, x] = 0
                status[y, x] = 3
                continue
            # Kalman update (eq. 3.13) after inflating the prior by the prediction noise
            pvar = idepth_var[y, x] * prm[P_PRED_NOISE]
            wgt = r_var / (r_var + pvar)
            idepth[y, x] = (1.0 - wgt) * r_id + wgt * idepth[y, x]
            nvar = pvar * wgt
            if nvar < idepth_var[y, x]:
                idepth_var[y, x] = nvar
            vmax = prm[P_VALIDITY_MAX] + g * prm[P_VALIDITY_MAX_GRAD] / 255.0
            vnew = validity[y, x] + prm[P_VALIDITY_INC]
            validity[y, x] = vnew if vnew < vmax else vmax
            if r_len < prm[P_MIN_EPL]:
                skip[y, x] = np.int32(prm[P_SKIP_CONVERGED])
            status[y, x] = 1


@njit(cache=True, nogil=True, fastmath=False, error_model="numpy", parallel=True)
def propagate_kernel(old, img_old, img_new, maxgrad_new, R, t, cam, prm, aff, new, work, bands=1):
    """Forward-warp every hypothesis of the map ``old`` into the map ``new`` of the new frame
    (both :class:`MapState`). ``R, t`` = T_new_old; ``cam = (fx, fy, cx, cy)``;
    ``aff = (a, b)``: brightness transfer of the old frame into the new one (the intensity check
    compares ``I_new`` with ``a * I_old + b``).

    Two passes, both parallel, and the result does not depend on the number of threads:

    1. over source rows: resets ``new`` (no hypothesis, positions on the pixel grid, ``blacklist``
       copied from ``old``: it stays with the pixel location) and warps every pixel of the row in one
       branch-free (vectorised) loop, then runs each hypothesis's checks (each source pixel writes
       only its own entry of the work arrays; ``work.var`` holds the warped depth's z until then);
    2. over bands of TARGET rows: a band visits, in raster order, the source rows whose hypotheses
       land in it (pass 1 records each source row's range of target rows) and resolves the
       collisions on its own target pixels. Every target pixel sees its sources in raster order,
       as one serial loop over the image would. ``bands``: how many (pass :func:`propagation_bands`;
       1 = one serial loop); the result does not depend on it.

    ``new``'s arrays are only written where a hypothesis lands (after the reset); ``work``: the
    :class:`PropagationWork` scratch of the map's size (allocated once by the caller). Returns
    (kept, dropped_border, dropped_intensity, occluded, fused).
    """
    idepth_s, idepth_var, valid, validity = old.idepth_s, old.idepth_var, old.valid, old.validity
    pos_x, pos_y, ref_id, skip, blacklist = old.pos_x, old.pos_y, old.ref_id, old.skip, old.blacklist
    (o_idepth, o_var, o_idepth_s, o_var_s, o_valid, o_validity, o_pos_x, o_pos_y, o_ref_id, o_blacklist,
     o_skip) = new
    fx, fy, cx, cy = cam[0], cam[1], cam[2], cam[3]
    border = prm[P_BORDER]
    min_grad = prm[P_MIN_GRAD]
    diff_const2 = prm[P_PROP_DIFF_CONST2]
    diff_grad_mult = prm[P_PROP_DIFF_GRAD]
    merge_fac = prm[P_PROP_MERGE]
    var_add = prm[P_PROP_VAR_ADD]
    validity_cap = prm[P_VALIDITY_CAP]
    sat = prm[P_SATURATION]
    sat_check = abs(aff[0] - 1.0) > prm[P_SAT_GAIN_TOL]
    keep_clipped = prm[P_KEEP_CLIPPED] > 0.5
    h, w = idepth_s.shape
    # pass 1: where each hypothesis lands (target >= 0: flat index; -1 border, -2 intensity, -3 none)
    target, w_d, w_var, w_u, w_v, row_lo, row_hi = work
    r00, r01, r02 = R[0, 0], R[0, 1], R[0, 2]
    r10, r11, r12 = R[1, 0], R[1, 1], R[1, 2]
    r20, r21, r22 = R[2, 0], R[2, 1], R[2, 2]
    t0, t1, t2 = t[0], t[1], t[2]
    n_border = 0
    n_int = 0
    for y in prange(h):
        lo_y = h
        hi_y = -1
        # the warp of every pixel of the row first, valid or not (branch-free: vectorised), then the checks
        for x in range(w):
            d = np.float64(idepth_s[y, x])
            rx = (np.float64(pos_x[y, x]) - cx) / fx
            ry = (np.float64(pos_y[y, x]) - cy) / fy
            qx = (r00 * rx + r01 * ry + r02) / d + t0
            qy = (r10 * rx + r11 * ry + r12) / d + t1
            qz = (r20 * rx + r21 * ry + r22) / d + t2
            d_new = 1.0 / qz
            w_d[y, x] = d_new
            w_u[y, x] = fx * qx * d_new + cx
            w_v[y, x] = fy * qy * d_new + cy
            w_var[y, x] = qz
            o_valid[y, x] = 0
            o_pos_x[y, x] = x
            o_pos_y[y, x] = y
            o_blacklist[y, x] = blacklist[y, x]
            target[y, x] = -3
        for x in range(w):
            if valid[y, x] == 0:
                continue
            target[y, x] = -1
            d = np.float64(idepth_s[y, x])
            if not (d > 0.0):
                n_border += 1
                continue
            px = np.float64(pos_x[y, x])
            py = np.float64(pos_y[y, x])
            qz = w_var[y, x]
            if not (qz > 0.0):
                n_border += 1
                continue
            d_new = w_d[y, x]
            u = w_u[y, x]
            v = w_v[y, x]
            if not (u >= border and v >= border and u <= w - 1 - border and v <= h - 1 - border
                    and u < w - 1 and v < h - 1 and u >= 0.0 and v >= 0.0):
                n_border += 1
                continue
            target[y, x] = -2
            ix = np.int64(u + 0.5)
            iy = np.int64(v + 0.5)
            g = np.float64(maxgrad_new[iy, ix])
            # the new intensity; for a pixel without gradient only when keep_clipped asks whether it is
            # clipped (flattened by clipping, not textureless: kept)
            dst = _bilinear(img_new, u, v) if (g >= min_grad or keep_clipped) else 0.0
            flat_clipped = keep_clipped and g < min_grad and dst >= sat
            if g < min_grad and not flat_clipped:
                n_int += 1
                continue
            if px >= 0.0 and py >= 0.0 and px < w - 1 and py < h - 1:
                src = _bilinear(img_old, px, py)
            else:
                sy = _min2(_max2(np.int64(py + 0.5), 0), h - 1)      # nearest source pixel, clamped
                sx = _min2(_max2(np.int64(px + 0.5), 0), w - 1)
                src = np.float64(img_old[sy, sx])
            r = dst - (aff[0] * src + aff[1])
            clipped = (sat_check or flat_clipped) and (src >= sat or dst >= sat)  # not comparable
            if not clipped and r * r / (diff_const2 + diff_grad_mult * g * g) > 1.0:
                n_int += 1
                continue
            ratio = d_new / d
            ratio *= ratio
            target[y, x] = iy * w + ix
            w_var[y, x] = ratio * ratio * idepth_var[y, x] + var_add
            if iy < lo_y:
                lo_y = iy
            if iy > hi_y:
                hi_y = iy
        row_lo[y] = lo_y
        row_hi[y] = hi_y
    # pass 2: collisions, per band of target rows; each band's sources in raster order
    nb = min(max(bands, 1), h)
    band_counts = np.zeros((nb, 3), np.int64)        # kept, occluded, fused
    for b in prange(nb):
        b_lo = (b * h) // nb
        b_hi = ((b + 1) * h) // nb                    # target rows b_lo .. b_hi - 1
        kept = 0
        n_occ = 0
        n_fused = 0
        for y in range(h):
            if row_hi[y] < b_lo or row_lo[y] >= b_hi:
                continue
            for x in range(w):
                tg = target[y, x]
                if tg < 0:
                    continue
                iy = tg // w
                if iy < b_lo or iy >= b_hi:
                    continue
                ix = tg - iy * w
                d_new = w_d[y, x]
                new_var = w_var[y, x]
                if o_valid[iy, ix] != 0:
                    other = np.float64(o_idepth[iy, ix])
                    diff = other - d_new
                    if merge_fac * diff * diff > new_var + o_var[iy, ix]:
                        n_occ += 1
                        if d_new < other:
                            continue          # the new one is farther: occluded
                        o_valid[iy, ix] = 0   # the new one is nearer: replaces
                if o_valid[iy, ix] == 0:
                    o_idepth[iy, ix] = d_new
                    o_var[iy, ix] = new_var
                    o_validity[iy, ix] = validity[y, x]
                    o_pos_x[iy, ix] = w_u[y, x]
                    o_pos_y[iy, ix] = w_v[y, x]
                    o_ref_id[iy, ix] = ref_id[y, x]
                    o_skip[iy, ix] = skip[y, x]
                    o_valid[iy, ix] = 1
                    kept += 1
                else:
                    ov = np.float64(o_var[iy, ix])
                    wgt = new_var / (ov + new_var)
                    o_idepth[iy, ix] = wgt * o_idepth[iy, ix] + (1.0 - wgt) * d_new
                    o_var[iy, ix] = 1.0 / (1.0 / ov + 1.0 / new_var)
                    mv = o_validity[iy, ix] + validity[y, x]
                    o_validity[iy, ix] = mv if mv < validity_cap else validity_cap
                    if ref_id[y, x] < o_ref_id[iy, ix]:
                        o_ref_id[iy, ix] = ref_id[y, x]
                    if skip[y, x] < o_skip[iy, ix]:
                        o_skip[iy, ix] = skip[y, x]
                    n_fused += 1
                o_idepth_s[iy, ix] = o_idepth[iy, ix]
                o_var_s[iy, ix] = o_var[iy, ix]
                o_blacklist[iy, ix] = 0
        band_counts[b, 0] = kept
        band_counts[b, 1] = n_occ
        band_counts[b, 2] = n_fused
    kept = 0
    n_occ = 0
    n_fused = 0
    for b in range(nb):
        kept += band_counts[b, 0]
        n_occ += band_counts[b, 1]
        n_fused += band_counts[b, 2]
    return kept, n_border, n_int, n_occ, n_fused


#: chunk width of :func:`regularize_kernel`'s spans (8 measured best of 4 / 8 / 16 on captured ICL maps)
REG_CHUNK = 8


@njit(cache=True, nogil=True, inline="always")
def _any_valid(row, lo, hi):
    for k in range(lo, hi):
        if row[k] != 0:
            return True
    return False


@njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def _regularize_span(D, V, L, y, r, inv_tab, diff_fac, s, si, vs, vmin, vtmp, x0, x1):
    """Accumulate the compatible neighbours of row ``y``'s pixels ``x0 .. x1-1`` into ``s, si, vs,
    vmin`` (see :func:`regularize_kernel`), offset by offset over the span. Branch-free with unsigned
    indices and every load unconditional: LLVM vectorises it (a conditional load, or a signed index
    that numba wraps around when negative, keeps it scalar: 4.5x slower on captured ICL maps).

    The running minimum ``vmin`` alternates with ``vtmp`` (float32 scratch of the row's length): each offset
    reads one and writes the other. Updated in place, ``vmin[x] = vn if ... else vmin[x]`` became two
    masked stores (``vmaskmovpd``), slow on AMD: the whole loop ran 1.5-2x longer than with this
    unconditional store. There are (2r + 1)^2 offsets, an odd number, so the last one writes ``vmin``."""
    nd = 2 * r + 1
    w = s.shape[0]
    dc = D[y + r, r:r + w]
    vc = V[y + r, r:r + w]
    ux0 = np.uint64(x0)
    n = np.uint64(x1 - x0)
    for k in range(n):
        vtmp[ux0 + k] = vc[ux0 + k]
    for dy in range(nd):
        Dr = D[y + dy]
        Vr = V[y + dy]
        Lr = L[y + dy]
        for dx in range(nd):
            add = inv_tab[dy * nd + dx]
            un = ux0 + np.uint64(dx)
            even = (dy * nd + dx) % 2 == 0
            src = vtmp if even else vmin
            dst = vmin if even else vtmp
            for k in range(n):
                x = ux0 + k
                dn = Dr[un + k]
                vn = Vr[un + k]
                ln = Lr[un + k]
                diff = np.float64(dn) - dc[x]
                ok = diff_fac * diff * diff <= np.float64(vn) + vc[x]   # as the reference: in float64
                iv = 1.0 / (np.float64(vn) + add)
                s[x] += dn * iv if ok else 0.0
                si[x] += iv if ok else 0.0
                vs[x] += ln if ok else 0.0
                m = src[x]
                dst[x] = vn if (ok and vn < m) else m


@njit(cache=True, nogil=True, fastmath=False, error_model="numpy", parallel=True)
def regularize_kernel(st, prm, o_valid, work):
    """Inverse-variance weighted, edge-preserving smoothing of the valid hypotheses of ``st``
    (a :class:`MapState`): reads ``idepth, idepth_var, valid, validity``, writes ``idepth_s, var_s``
    (where ``o_valid``), ``blacklist`` and ``o_valid``.

    A neighbour counts when ``diff_fac * diff^2 <= var_a + var_b``; weight ``1/(var + dist_var*r^2)``.
    A pixel whose compatible neighbours' validity sum is below ``validity_th`` is removed
    (``o_valid = 0``, blacklist decremented). ``o_var_s``: var_mode 0 = smallest compatible
    variance (thesis 3.2.3), 1 = the pixel's own variance, 2 = 1 / sum of the weights (LSD-SLAM).
    Parameters ``P_REG_*`` (radius, dist_var, diff_fac, validity_th, var_mode).

    Vectorised: the map is copied once into padded float32 planes (inverse depth NaN where there is
    no hypothesis, so the compatibility test fails there without a branch), then every row is
    accumulated offset by offset (SIMD, :func:`_regularize_span`) over its spans of 8-pixel chunks
    that hold a hypothesis (on ICL about half of the chunks are empty: half the time). The sums are
    float64: float32 sums change the map by about 1e-6 relative, which is enough to move a degenerate run (a static
    camera, random init) elsewhere. ``work``: the :class:`RegularizeWork` planes (allocated once by the
    caller for the map's size and radius; overwritten here).
    """
    idepth, idepth_var, valid, validity, blacklist = st.idepth, st.idepth_var, st.valid, st.validity, st.blacklist
    o_idepth_s, o_var_s = st.idepth_s, st.var_s
    r = int(prm[P_REG_RADIUS])
    dist_var = prm[P_REG_DIST_VAR]
    diff_fac = prm[P_REG_DIFF_FAC]
    validity_th = prm[P_REG_VALIDITY_SUM]
    var_mode = int(prm[P_REG_VAR_MODE])
    h, w = idepth.shape
    hp, wp = h + 2 * r, w + 2 * r
    D, V, L = work
    if D.shape[0] != hp or D.shape[1] != wp:
        raise ValueError("regularize_kernel: work planes of the wrong size (see regularize_work)")
    for yp in prange(hp):
        y = yp - r
        for xp in range(wp):
            x = xp - r
            if y >= 0 and y < h and x >= 0 and x < w and valid[y, x] != 0:
                D[yp, xp] = idepth[y, x]
                V[yp, xp] = idepth_var[y, x]
                L[yp, xp] = validity[y, x]
            else:
                D[yp, xp] = np.nan
                V[yp, xp] = 0.0
                L[yp, xp] = 0.0
    nd = 2 * r + 1
    inv_tab = np.empty(nd * nd, np.float64)
    for dy in range(nd):
        for dx in range(nd):
            inv_tab[dy * nd + dx] = ((dy - r) * (dy - r) + (dx - r) * (dx - r)) * dist_var
    for y in prange(h):
        s = np.zeros(w, np.float64)
        si = np.zeros(w, np.float64)
        vs = np.zeros(w, np.float64)
        vmin = np.empty(w, np.float32)
        vtmp = np.empty(w, np.float32)
        vc = V[y + r, r:r + w]
        # only the spans of REG_CHUNK-pixel chunks holding a hypothesis are accumulated (the map is
        # semi-dense: about half of the chunks are empty, and nothing is read there below)
        x = 0
        while x < w:
            while x < w and not _any_valid(valid[y], x, _min2(x + REG_CHUNK, w)):
                x = _min2(x + REG_CHUNK, w)
            x0 = x
            while x < w and _any_valid(valid[y], x, _min2(x + REG_CHUNK, w)):
                x = _min2(x + REG_CHUNK, w)
            if x > x0:
                _regularize_span(D, V, L, y, r, inv_tab, diff_fac, s, si, vs, vmin, vtmp, x0, x)
        for x in range(w):
            if valid[y, x] == 0:
                o_valid[y, x] = 0
                continue
            if vs[x] < validity_th:
                o_valid[y, x] = 0
                blacklist[y, x] -= 1
                continue
            o_valid[y, x] = 1
            o_idepth_s[y, x] = s[x] / si[x]
            if var_mode == 0:
                o_var_s[y, x] = vmin[x]
            elif var_mode == 1:
                o_var_s[y, x] = vc[x]
            else:
                o_var_s[y, x] = 1.0 / si[x]


@njit(cache=True, nogil=True, fastmath=False, error_model="numpy", parallel=True)
def fill_kernel(st, maxgrad, prm, new_flag, work):
    """Create hypotheses in empty pixels of ``st`` (a :class:`MapState`) with gradient >= min_grad
    whose 5x5 validity sum exceeds ``P_FILL_VALIDITY_SUM`` (``P_UNBLACKLIST_SUM`` for pixels with
    blacklist < ``P_MIN_BLACKLIST``), as the inverse-variance mean of the valid neighbours, with
    variance ``P_INIT_VAR`` and validity ``P_FILL_VALIDITY``.

    Writes only EMPTY pixels (and sets ``new_flag`` there); ``valid`` is not modified, so every
    read sees the map before filling. The caller then sets ``valid |= new_flag``.

    The 5x5 sums (validity, idepth/var, 1/var) and the 5x5 minimum of ``ref_id`` over the valid
    pixels are separable: row sums first (vectorised), then column sums at the candidate pixels; both
    passes run in parallel over rows (a row writes only its own sums, a candidate only its own pixel).
    ``work``: the :class:`FillWork` scratch of the map's size (allocated once by the caller: 2.4 MB at
    320x240, which a fresh allocation per call would page in again and again).
    """
    idepth, idepth_var, idepth_s, var_s, valid, validity, pos_x, pos_y, ref_id, blacklist, skip = st
    min_grad = prm[P_MIN_GRAD]
    min_blacklist = prm[P_MIN_BLACKLIST]
    create_th = prm[P_FILL_VALIDITY_SUM]
    unblacklist_th = prm[P_UNBLACKLIST_SUM]
    new_var = prm[P_INIT_VAR]
    new_validity = prm[P_FILL_VALIDITY]
    h, w = idepth.shape
    if h < 5 or w < 5:
        return
    big = np.iinfo(np.int64).max
    # horizontal 5-sums (validity, idepth/var, 1/var) and 5-min (ref_id) of the valid pixels
    # (only columns 2 .. w-3 are read below: the rest stays uninitialised)
    hv, hs, hi, hr = work
    for y in prange(h):
        pv = np.empty(w, np.float64)
        ps = np.empty(w, np.float64)
        pi = np.empty(w, np.float64)
        pr = np.empty(w, np.int64)
        for x in range(w):
            if valid[y, x] != 0:
                iv = 1.0 / np.float64(idepth_var[y, x])
                pv[x] = validity[y, x]
                ps[x] = idepth[y, x] * iv
                pi[x] = iv
                pr[x] = ref_id[y, x]
            else:
                pv[x] = 0.0
                ps[x] = 0.0
                pi[x] = 0.0
                pr[x] = big
        for x in range(2, w - 2):
            hv[y, x] = pv[x - 2] + pv[x - 1] + pv[x] + pv[x + 1] + pv[x + 2]
            hs[y, x] = ps[x - 2] + ps[x - 1] + ps[x] + ps[x + 1] + ps[x + 2]
            hi[y, x] = pi[x - 2] + pi[x - 1] + pi[x] + pi[x + 1] + pi[x + 2]
            hr[y, x] = _min2(_min2(_min2(pr[x - 2], pr[x - 1]), _min2(pr[x], pr[x + 1])), pr[x + 2])
    for y in prange(2, h - 2):
        for x in range(2, w - 2):
            if valid[y, x] != 0 or maxgrad[y, x] < min_grad:
                continue
            vs = hv[y - 2, x] + hv[y - 1, x] + hv[y, x] + hv[y + 1, x] + hv[y + 2, x]
            if not ((blacklist[y, x] >= min_blacklist and vs > create_th) or vs > unblacklist_th):
                continue
            si = hi[y - 2, x] + hi[y - 1, x] + hi[y, x] + hi[y + 1, x] + hi[y + 2, x]
            if not (si > 0.0):
                continue
            s = hs[y - 2, x] + hs[y - 1, x] + hs[y, x] + hs[y + 1, x] + hs[y + 2, x]
            rid = _min2(_min2(_min2(hr[y - 2, x], hr[y - 1, x]), _min2(hr[y, x], hr[y + 1, x])), hr[y + 2, x])
            m = s / si
            idepth[y, x] = m
            idepth_s[y, x] = m
            idepth_var[y, x] = new_var
            var_s[y, x] = new_var
            validity[y, x] = new_validity
            pos_x[y, x] = x
            pos_y[y, x] = y
            ref_id[y, x] = rid
            blacklist[y, x] = 0
            skip[y, x] = 0
            new_flag[y, x] = 1


def propagation_bands(num_threads: int) -> int:
    """Bands of target rows for :func:`propagate_kernel` with this many numba threads: one for one thread
    (no source row is visited twice), else a few per thread (balances them)."""
    return 1 if num_threads <= 1 else PROPAGATE_BANDS_PER_THREAD * num_threads


def propagation_work(h: int, w: int) -> PropagationWork:
    """Scratch arrays of :func:`propagate_kernel` for an HxW map."""
    return PropagationWork(np.empty((h, w), np.int64), np.empty((h, w), np.float64), np.empty((h, w), np.float64),
                           np.empty((h, w), np.float64), np.empty((h, w), np.float64), np.empty(h, np.int64),
                           np.empty(h, np.int64))


@njit(cache=True, nogil=True, parallel=True)
def count_codes(codes, n):
    """How often each value 0 .. n-1 occurs in the 2-D int8 array ``codes`` (others are not counted):
    ``np.bincount`` without converting the array to int64 first; rows counted in parallel."""
    h, w = codes.shape
    per_row = np.zeros((h, n), np.int64)
    for y in prange(h):
        for x in range(w):
            c = codes[y, x]
            if c >= 0 and c < n:
                per_row[y, c] += 1
    out = np.zeros(n, np.int64)
    for y in range(h):
        for c in range(n):
            out[c] += per_row[y, c]
    return out


@njit(cache=True, nogil=True, parallel=True)
def masked_map(idepth_s, var_s, valid, o_idepth, o_var, o_valid):
    """The map as published: ``o_idepth, o_var`` = ``idepth_s, var_s`` where ``valid`` and 0 elsewhere,
    ``o_valid`` = ``valid != 0`` (one pass instead of three numpy ones)."""
    h, w = valid.shape
    for y in prange(h):
        for x in range(w):
            if valid[y, x] != 0:
                o_idepth[y, x] = idepth_s[y, x]
                o_var[y, x] = var_s[y, x]
                o_valid[y, x] = True
            else:
                o_idepth[y, x] = 0.0
                o_var[y, x] = 0.0
                o_valid[y, x] = False


def fill_work(h: int, w: int) -> FillWork:
    """Scratch of :func:`fill_kernel` for an HxW map."""
    return FillWork(np.empty((h, w), np.float64), np.empty((h, w), np.float64), np.empty((h, w), np.float64),
                    np.empty((h, w), np.int64))


def regularize_work(h: int, w: int, radius: int) -> RegularizeWork:
    """Scratch of :func:`regularize_kernel` for an HxW map and this radius."""
    shape = (h + 2 * radius, w + 2 * radius)
    return RegularizeWork(np.empty(shape, np.float32), np.empty(shape, np.float32), np.empty(shape, np.float32))


def new_state(h: int, w: int) -> MapState:
    """An empty :class:`MapState` (no hypothesis; positions on the pixel grid)."""
    yy, xx = np.mgrid[0:h, 0:w]
    return MapState(np.zeros((h, w), np.float32), np.zeros((h, w), np.float32), np.zeros((h, w), np.float32),
                    np.zeros((h, w), np.float32), np.zeros((h, w), np.uint8), np.zeros((h, w), np.float32),
                    xx.astype(np.float32), yy.astype(np.float32), np.zeros((h, w), np.int64),
                    np.zeros((h, w), np.int32), np.zeros((h, w), np.int32))


def warmup(runtime: bool = False) -> None:
    """Compile (and cache) every kernel of this module on tiny inputs, with the argument types the
    Mapper passes (it hands the kernels writable C-contiguous arrays only). ``runtime``: only the
    kernels and signatures the Mapper calls (not the defaults the tests use, nor the standalone
    per-pixel helpers, which are inlined into ``observe_kernel``)."""
    h, w = 24, 32
    rng = np.random.default_rng(0)
    img = (rng.random((h, w)) * 255).astype(np.float32)
    gx = np.zeros((h, w), np.float32)
    gy = np.zeros((h, w), np.float32)
    mg = np.zeros((h, w), np.float32)
    gradients_kernel(img, gx, gy, mg)
    prm = np.zeros(P_N)
    prm[P_MIN_EPL_LENGTH] = 1.0
    prm[P_MAX_IDEPTH] = 20.0
    prm[P_MAX_EPL] = 30.0
    prm[P_MIN_EPL] = 3.0
    prm[P_MIN_SCALE] = 0.7
    prm[P_MAX_SCALE] = 1.4
    prm[P_BORDER_SAMPLES] = 2.0
    prm[P_REG_RADIUS] = 2.0
    prm[P_SATURATION] = 255.0
    cam = np.array([30.0, 30.0, 15.5, 11.5])
    st = new_state(h, w)
    st.valid[4:20, 4:28] = 1
    st.idepth[:] = 1.0
    st.idepth_s[:] = 1.0
    st.idepth_var[:] = 0.01
    st.var_s[:] = 0.01
    R = np.eye(3)
    t = np.array([0.01, 0.0, 0.0])
    refs = RefFrames(np.stack([img, img]), np.arange(2, dtype=np.int64), np.arange(2, dtype=np.int64),
                     np.stack([R, R]), np.stack([t, t]), np.stack([-t, -t]), np.zeros(2),
                     np.array([[1.0, 0.0], [1.0, 0.0]]))
    status = np.zeros((h, w), np.int8)
    if not runtime:
        observe_kernel(img, gx, gy, mg, refs, st, cam, prm, 1, 0, 64, status)
    observe_kernel(img, gx, gy, mg, refs, st, cam, prm, 1, 0, 64, status, 2)    # as the Mapper calls it
    new = new_state(h, w)
    if not runtime:
        propagate_kernel(st, img, img, mg, R, t, cam, prm, np.array([1.0, 0.0]), new, propagation_work(h, w))
    propagate_kernel(st, img, img, mg, R, t, cam, prm, np.array([1.0, 0.0]), new, propagation_work(h, w), 8)
    o_valid = np.zeros((h, w), np.uint8)
    regularize_kernel(st, prm, o_valid, regularize_work(h, w, int(prm[P_REG_RADIUS])))
    fill_kernel(st, mg, prm, o_valid, fill_work(h, w))
    count_codes(status, 9)
    masked_map(st.idepth_s, st.var_s, st.valid, np.empty((h, w), np.float32), np.empty((h, w), np.float32),
               np.empty((h, w), np.bool_))
    if runtime:
        return
    # the per-pixel helpers are inlined into observe_kernel; compile their standalone versions too
    epipolar_direction(img, 10, 10, 10.0, 10.0, -t, 30.0, 30.0, 15.5, 11.5, prm)
    line_length(10.0, 10.0, 0.0, 1.0, R, t, 30.0, 30.0, 15.5, 11.5)
    _min_in(np.empty(8), 0, 8)
    line_stereo(img, img, 10.0, 10.0, 1.0, 0.0, 0.0, 1.0, 2.0, R, t, 30.0, 30.0, 15.5, 11.5, 1.0, 0.0, 0.0,
                prm, True, 1.0, 0.0, np.empty(64), np.empty(64), np.empty(64), np.empty(64, np.uint64))
