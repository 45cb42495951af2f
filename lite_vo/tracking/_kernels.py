"""numba kernels of direct SE(3) tracking.

Owns the hot loops of :mod:`lite_vo.tracking`:

* :func:`accumulate` - ONE pass over the reference points of a level: warp into the new image,
  bilinear intensity and gradient, residual, variance + Huber weight, the 8x8 normal equations of
  pose and affine brightness, robust energy, good/bad counts.
* :func:`lm_level` - the iteratively re-weighted Levenberg-Marquardt loop of one pyramid level
  (calls :func:`accumulate` once per iteration; no Python between iterations).
* :func:`track_level` - one level of a frame in one call: the new image's interpolation stack, then
  :func:`lm_level`, then the pose and brightness handed on to the next level.
* small helpers: :func:`exp_se3_nb`, :func:`solve_spd` (Cholesky), pose composition.

Affine brightness (thesis 6.3.3, DSO): ``I_new(warp(p)) = a * I_ref(p) + b`` with ``a = exp(alpha)``;
``(alpha, b)`` are estimated jointly with the pose in the same LM system (8 unknowns: twist, alpha,
b), with a weak prior pulling ``alpha`` and ``b`` to 0 (energy ``N * (prior_a alpha^2 + prior_b b^2)``
for N used points). With ``TP_AFF_ENABLED = 0`` the system is 6x6 and ``(a, b)`` stay as given.

The pose estimated here is ``T_new_ref`` (reference points are warped into the new image), with
left-multiplicative updates ``T <- exp(dxi) @ T``; the Jacobian is then evaluated at the warped
point ``q = T_new_ref p`` (``dq/dxi = [I | -[q]x]``), which is cheap.

Reference point layout (``pts``, float32, shape (N, PTS_COLS)): ``X, Y, Z`` (the point in the
reference camera, ``Z = 1/idepth``), ``I_ref``, ``idepth_var``.

Every threshold is an argument: one float64 parameter vector ``prm`` built once per configuration
by ``lite_vo.tracking.tracker.tracking_params`` (the ``TP_*`` constants are indices into it); the
camera of a level is ``cam = (fx, fy, cx, cy)``. Imports numpy, numba and the image kernels of
:mod:`lite_vo.image` only.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..image import bspline_coefficients_nb, gradient_stack_nb

PTS_COLS = 5
BUF_ROWS = 9       # per-point scratch rows: jx, jy, jz, qx, qy, qz, r, w, I_ref
NP = 8             # unknowns: twist (6), alpha, b

# accumulator layout (float64 vector filled by accumulate)
ACC_H = 0          # 36 entries: upper triangle of the 8x8 H, row-major (affine rows 0 when disabled)
ACC_G = 36         # 8 entries: g = sum w r J
ACC_ENERGY = 44    # sum of the Huber energy of the normalised residuals
ACC_N = 45         # points inside the image (used)
ACC_GOOD = 46      # good residuals
ACC_BAD = 47       # bad residuals
ACC_ABS_R = 48     # sum |r| (grey levels)
ACC_SIZE = 49

# lm_level statistics output
ST_ITER = 0        # outer LM iterations
ST_ERR = 1         # final mean energy (data + affine prior, per point)
ST_STATUS = 2      # 0 converged/cap, 1 no points, 2 singular system
ST_LAST_N = 3      # points in the scratch buffer: its residual row is that of the last evaluation
ST_SIZE = 4

# indices into the tracking parameter vector (layout fixed; values come from TrackingConfig)
TP_SIGMA_I2 = 0           # sigma_i^2 (grey levels^2)
TP_HUBER = 1              # Huber threshold on the normalised residual
TP_AFF_PRIOR_A = 2        # weak prior on alpha = log a, per used point
TP_GOOD_C2 = 3            # good-residual test constant^2
TP_GOOD_G2 = 4            # good-residual test gradient factor^2
TP_BORDER = 5             # a warped point must lie this far inside the image (px)
TP_MIN_Z = 6              # skip points whose warped depth is at or below this
TP_CONV_RATIO = 7
TP_CONV_EPS = 8
TP_LAMBDA_INIT = 9
TP_LAMBDA_ACCEPT_MAX = 10
TP_LAMBDA_ACCEPT_FACTOR = 11
TP_LAMBDA_REJECT_FACTOR = 12
TP_MIN_POINTS = 13
TP_SOLVE_EPS = 14
TP_MIN_HESSIAN_DIAG = 15
TP_AFF_ENABLED = 16       # 1: estimate the affine brightness jointly with the pose
TP_AFF_PRIOR_B = 17       # weak prior on the offset b (grey levels^-2), per used point
TP_SATURATION = 18        # points whose reference or new intensity is at or above this are skipped
TP_N = 19

INTERP_BILINEAR = 0   # bilinear intensity + bilinearly interpolated central-difference gradients
INTERP_BSPLINE = 1    # cubic B-spline value and its exact derivative (4x4 taps)


@njit(cache=True, nogil=True, fastmath=False, inline="always")
def _sample_bspline(coef, x0, y0, tx, ty):
    """Cubic B-spline value and gradient at ``(x0 + tx, y0 + ty)`` from coefficients ``coef[:, :, 0]``."""
    sx = 1.0 - tx
    sy = 1.0 - ty
    tx2 = tx * tx
    ty2 = ty * ty
    wx0 = sx * sx * sx / 6.0
    wx1 = (3.0 * tx2 * tx - 6.0 * tx2 + 4.0) / 6.0
    wx2 = (-3.0 * tx2 * tx + 3.0 * tx2 + 3.0 * tx + 1.0) / 6.0
    wx3 = tx2 * tx / 6.0
    dx0 = -0.5 * sx * sx
    dx1 = 1.5 * tx2 - 2.0 * tx
    dx2 = -1.5 * tx2 + tx + 0.5
    dx3 = 0.5 * tx2
    wy0 = sy * sy * sy / 6.0
    wy1 = (3.0 * ty2 * ty - 6.0 * ty2 + 4.0) / 6.0
    wy2 = (-3.0 * ty2 * ty + 3.0 * ty2 + 3.0 * ty + 1.0) / 6.0
    wy3 = ty2 * ty / 6.0
    dy0 = -0.5 * sy * sy
    dy1 = 1.5 * ty2 - 2.0 * ty
    dy2 = -1.5 * ty2 + ty + 0.5
    dy3 = 0.5 * ty2
    val = 0.0
    gx = 0.0
    gy = 0.0
    for j in range(4):
        if j == 0:
            wy = wy0; dy = dy0
        elif j == 1:
            wy = wy1; dy = dy1
        elif j == 2:
            wy = wy2; dy = dy2
        else:
            wy = wy3; dy = dy3
        yy = y0 - 1 + j
        c0 = np.float64(coef[yy, x0 - 1, 0])
        c1 = np.float64(coef[yy, x0, 0])
        c2 = np.float64(coef[yy, x0 + 1, 0])
        c3 = np.float64(coef[yy, x0 + 2, 0])
        rv = wx0 * c0 + wx1 * c1 + wx2 * c2 + wx3 * c3
        rd = dx0 * c0 + dx1 * c1 + dx2 * c2 + dx3 * c3
        val += wy * rv
        gx += wy * rd
        gy += dy * rv
    return val, gx, gy


# Reduction-only kernel: "reassoc" lets LLVM vectorise the sums (summation order changes, nothing
# else: NaN/inf semantics stay strict, no approximate functions).
@njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _reduce_normal_equations(buf, n, aff_a, with_affine, acc):
    """H (upper triangle, 8x8) and g from the per-point buffer rows ``jx, jy, jz, qx, qy, qz, r, w, I_ref``.

    The affine columns are ``dr/dalpha = -a I_ref`` and ``dr/db = -1`` (left 0 without ``with_affine``)."""
    jx = buf[0]; jy = buf[1]; jz = buf[2]
    qx = buf[3]; qy = buf[4]; qz = buf[5]
    rr = buf[6]; ww = buf[7]
    h00 = 0.0; h01 = 0.0; h02 = 0.0; h03 = 0.0; h04 = 0.0; h05 = 0.0
    h11 = 0.0; h12 = 0.0; h13 = 0.0; h14 = 0.0; h15 = 0.0
    h22 = 0.0; h23 = 0.0; h24 = 0.0; h25 = 0.0
    h33 = 0.0; h34 = 0.0; h35 = 0.0
    h44 = 0.0; h45 = 0.0
    h55 = 0.0
    g0 = 0.0; g1 = 0.0; g2 = 0.0; g3 = 0.0; g4 = 0.0; g5 = 0.0
    for i in range(n):
        a0 = jx[i]; a1 = jy[i]; a2 = jz[i]
        x = qx[i]; y = qy[i]; z = qz[i]
        # J_omega = q x J_v
        a3 = y * a2 - z * a1
        a4 = z * a0 - x * a2
        a5 = x * a1 - y * a0
        w = ww[i]
        wr = w * rr[i]
        b0 = w * a0; b1 = w * a1; b2 = w * a2; b3 = w * a3; b4 = w * a4; b5 = w * a5
        h00 += b0 * a0; h01 += b0 * a1; h02 += b0 * a2; h03 += b0 * a3; h04 += b0 * a4; h05 += b0 * a5
        h11 += b1 * a1; h12 += b1 * a2; h13 += b1 * a3; h14 += b1 * a4; h15 += b1 * a5
        h22 += b2 * a2; h23 += b2 * a3; h24 += b2 * a4; h25 += b2 * a5
        h33 += b3 * a3; h34 += b3 * a4; h35 += b3 * a5
        h44 += b4 * a4; h45 += b4 * a5
        h55 += b5 * a5
        g0 += wr * a0; g1 += wr * a1; g2 += wr * a2; g3 += wr * a3; g4 += wr * a4; g5 += wr * a5
    acc[0] = h00; acc[1] = h01; acc[2] = h02; acc[3] = h03; acc[4] = h04; acc[5] = h05
    acc[8] = h11; acc[9] = h12; acc[10] = h13; acc[11] = h14; acc[12] = h15
    acc[15] = h22; acc[16] = h23; acc[17] = h24; acc[18] = h25
    acc[21] = h33; acc[22] = h34; acc[23] = h35
    acc[26] = h44; acc[27] = h45
    acc[30] = h55
    acc[ACC_G + 0] = g0; acc[ACC_G + 1] = g1; acc[ACC_G + 2] = g2
    acc[ACC_G + 3] = g3; acc[ACC_G + 4] = g4; acc[ACC_G + 5] = g5
    if with_affine:
        _reduce_affine(buf, n, aff_a, acc)


@njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _reduce_affine(buf, n, aff_a, acc):
    """The affine rows of H and g: columns ``-a I_ref`` (alpha) and ``-1`` (b)."""
    jx = buf[0]; jy = buf[1]; jz = buf[2]
    qx = buf[3]; qy = buf[4]; qz = buf[5]
    rr = buf[6]; ww = buf[7]; ir = buf[8]
    p0 = 0.0; p1 = 0.0; p2 = 0.0; p3 = 0.0; p4 = 0.0; p5 = 0.0     # sum w J_k (-a I_ref)
    q0 = 0.0; q1 = 0.0; q2 = 0.0; q3 = 0.0; q4 = 0.0; q5 = 0.0     # sum w J_k (-1)
    h66 = 0.0; h67 = 0.0; h77 = 0.0; g6 = 0.0; g7 = 0.0
    for i in range(n):
        a0 = jx[i]; a1 = jy[i]; a2 = jz[i]
        x = qx[i]; y = qy[i]; z = qz[i]
        a3 = y * a2 - z * a1
        a4 = z * a0 - x * a2
        a5 = x * a1 - y * a0
        w = ww[i]
        c6 = -aff_a * ir[i]
        wc6 = w * c6
        p0 += wc6 * a0; p1 += wc6 * a1; p2 += wc6 * a2; p3 += wc6 * a3; p4 += wc6 * a4; p5 += wc6 * a5
        q0 -= w * a0; q1 -= w * a1; q2 -= w * a2; q3 -= w * a3; q4 -= w * a4; q5 -= w * a5
        h66 += wc6 * c6
        h67 -= wc6
        h77 += w
        g6 += wc6 * rr[i]
        g7 -= w * rr[i]
    acc[6] = p0; acc[13] = p1; acc[19] = p2; acc[24] = p3; acc[28] = p4; acc[31] = p5
    acc[7] = q0; acc[14] = q1; acc[20] = q2; acc[25] = q3; acc[29] = q4; acc[32] = q5
    acc[33] = h66; acc[34] = h67; acc[35] = h77
    acc[ACC_G + 6] = g6
    acc[ACC_G + 7] = g7


@njit(cache=True, nogil=True, fastmath=False)
def accumulate(pts, img3, interp, T, cam, prm, aff_a, aff_b, buf, acc):
    """Residuals, weights and normal equations of all points at pose ``T`` (= T_new_ref).

    ``img3``: (H, W, 3) float32 of the new image at this level: ``[I, gx, gy]`` sampled bilinearly
    when ``interp == INTERP_BILINEAR``; channel 0 = cubic B-spline coefficients (value and exact
    derivative of the spline) when ``interp == INTERP_BSPLINE`` (then ``border`` must be >= 1).
    A point is used when its warped depth exceeds ``prm[TP_MIN_Z]``, its position lies in
    ``[border, W-1-border) x [border, H-1-border)`` and the interpolated values are finite.
    Residual ``r = I_new(warp) - (aff_a * I_ref + aff_b)``; weight
    ``w = 1 / (sigma_i^2 + var * (dr/d idepth)^2)`` times Huber (threshold ``prm[TP_HUBER]`` on ``|r| sqrt(w)``).
    Results are written into ``acc`` (layout ``ACC_*``, zeroed first; the affine rows of H and g only
    when ``prm[TP_AFF_ENABLED]``). ``buf``: float64 scratch of shape (BUF_ROWS, >= N); the per-point
    loop fills it, a vectorised reduction then sums H and g. Returns the number of used points.
    """
    for k in range(acc.shape[0]):
        acc[k] = 0.0
    fx, fy, cx, cy = cam[0], cam[1], cam[2], cam[3]
    sigma_i2 = prm[TP_SIGMA_I2]
    huber_k = prm[TP_HUBER]
    good_c2 = prm[TP_GOOD_C2]
    good_g2 = prm[TP_GOOD_G2]
    border = prm[TP_BORDER]
    min_z = prm[TP_MIN_Z]
    sat = prm[TP_SATURATION]
    h = img3.shape[0]
    w = img3.shape[1]
    umax = w - 1.0 - border
    vmax = h - 1.0 - border
    r00 = T[0, 0]; r01 = T[0, 1]; r02 = T[0, 2]; t0 = T[0, 3]
    r10 = T[1, 0]; r11 = T[1, 1]; r12 = T[1, 2]; t1 = T[1, 3]
    r20 = T[2, 0]; r21 = T[2, 1]; r22 = T[2, 2]; t2 = T[2, 3]
    huber_k2 = huber_k * huber_k
    energy = 0.0; n_good = 0; abs_r = 0.0
    bjx = buf[0]; bjy = buf[1]; bjz = buf[2]
    bqx = buf[3]; bqy = buf[4]; bqz = buf[5]
    br = buf[6]; bw = buf[7]; bir = buf[8]
    m = 0
    n = pts.shape[0]
    for i in range(n):
        X = np.float64(pts[i, 0])
        Y = np.float64(pts[i, 1])
        Z = np.float64(pts[i, 2])
        qz = r20 * X + r21 * Y + r22 * Z + t2
        if not (qz > min_z):
            continue
        qx = r00 * X + r01 * Y + r02 * Z + t0
        qy = r10 * X + r11 * Y + r12 * Z + t1
        iz = 1.0 / qz
        u = fx * qx * iz + cx
        v = fy * qy * iz + cy
        if not (u >= border and u < umax and v >= border and v < vmax):
            continue
        x0 = np.int64(u)
        y0 = np.int64(v)
        ax = u - x0
        ay = v - y0
        if interp == INTERP_BSPLINE:
            i_new, gx, gy = _sample_bspline(img3, x0, y0, ax, ay)
        else:
            w00 = (1.0 - ax) * (1.0 - ay)
            w10 = ax * (1.0 - ay)
            w01 = (1.0 - ax) * ay
            w11 = ax * ay
            i_new = (w00 * img3[y0, x0, 0] + w10 * img3[y0, x0 + 1, 0]
                     + w01 * img3[y0 + 1, x0, 0] + w11 * img3[y0 + 1, x0 + 1, 0])
            gx = (w00 * img3[y0, x0, 1] + w10 * img3[y0, x0 + 1, 1]
                  + w01 * img3[y0 + 1, x0, 1] + w11 * img3[y0 + 1, x0 + 1, 1])
            gy = (w00 * img3[y0, x0, 2] + w10 * img3[y0, x0 + 1, 2]
                  + w01 * img3[y0 + 1, x0, 2] + w11 * img3[y0 + 1, x0 + 1, 2])
        i_ref = np.float64(pts[i, 3])
        if i_ref >= sat or i_new >= sat:       # clipped: the brightness model does not hold there
            continue
        r = i_new - (aff_a * i_ref + aff_b)
        if not (abs(r) < np.inf and abs(gx) < np.inf and abs(gy) < np.inf):
            continue
        var = np.float64(pts[i, 4])
        gxf = gx * fx
        gyf = gy * fy
        jx = gxf * iz
        jy = gyf * iz
        jz = -(jx * qx + jy * qy) * iz
        dr_dd = (jx * t0 + jy * t1 + jz * t2) * Z
        wp = 1.0 / (sigma_i2 + var * dr_dd * dr_dd)
        rn2 = r * r * wp
        if rn2 <= huber_k2:
            wgt = wp
            energy += rn2
        else:
            rn = np.sqrt(rn2)
            wgt = wp * huber_k / rn
            energy += 2.0 * huber_k * rn - huber_k2
        bjx[m] = jx; bjy[m] = jy; bjz[m] = jz
        bqx[m] = qx; bqy[m] = qy; bqz[m] = qz
        br[m] = r; bw[m] = wgt; bir[m] = i_ref
        m += 1
        if r * r < good_c2 + good_g2 * (gx * gx + gy * gy):
            n_good += 1
        abs_r += abs(r)
    _reduce_normal_equations(buf, m, aff_a, prm[TP_AFF_ENABLED] > 0.5, acc)
    acc[ACC_ENERGY] = energy
    acc[ACC_N] = m
    acc[ACC_GOOD] = n_good
    acc[ACC_BAD] = m - n_good
    acc[ACC_ABS_R] = abs_r
    return m


@njit(cache=True, nogil=True, fastmath=False)
def unpack_normal_equations(acc, H, g):
    """Fill the symmetric 8x8 ``H`` and the 8-vector ``g`` from an accumulator vector."""
    k = 0
    for i in range(NP):
        for j in range(i, NP):
            H[i, j] = acc[ACC_H + k]
            H[j, i] = acc[ACC_H + k]
            k += 1
        g[i] = acc[ACC_G + i]


@njit(cache=True, nogil=True, fastmath=False)
def solve_spd(A, b, x, n, rel_eps):
    """Solve the SPD system ``A[:n, :n] x[:n] = b[:n]`` by Cholesky; False when a pivot is not positive.

    A pivot counts as not positive when it is below ``rel_eps`` times the largest diagonal entry
    (or not finite). ``A`` is left unchanged; ``x[n:]`` is set to 0.
    """
    L = np.zeros((n, n))
    for i in range(n, x.shape[0]):
        x[i] = 0.0
    dmax = 0.0
    for i in range(n):
        if A[i, i] > dmax:
            dmax = A[i, i]
    if not (dmax > 0.0 and dmax < np.inf):
        return False
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not (s > rel_eps * dmax):
            return False
        ljj = np.sqrt(s)
        L[j, j] = ljj
        for i in range(j + 1, n):
            s2 = A[i, j]
            for k in range(j):
                s2 -= L[i, k] * L[j, k]
            L[i, j] = s2 / ljj
    y = np.zeros(n)
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * y[k]
        y[i] = s / L[i, i]
    for i in range(n - 1, -1, -1):
        s = y[i]
        for k in range(i + 1, n):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]
    return True


@njit(cache=True, nogil=True, fastmath=False)
def exp_se3_nb(xi, out):
    """``out = exp(xi)`` for the twist ``xi = (v, omega)`` (same maths as geometry.exp_se3; entries of
    ``xi`` after the sixth are ignored)."""
    wx = xi[3]; wy = xi[4]; wz = xi[5]
    th2 = wx * wx + wy * wy + wz * wz
    th = np.sqrt(th2)
    if th2 < 1e-10:
        A = 1.0 - th2 / 6.0
        B = 0.5 - th2 / 24.0
        C = 1.0 / 6.0 - th2 / 120.0
    else:
        A = np.sin(th) / th
        B = (1.0 - np.cos(th)) / th2
        C = (th - np.sin(th)) / (th2 * th)
    # W = hat(w); W^2 = w w^T - th2 I
    W = np.zeros((3, 3))
    W[0, 1] = -wz; W[0, 2] = wy
    W[1, 0] = wz; W[1, 2] = -wx
    W[2, 0] = -wy; W[2, 1] = wx
    # W^2 = w w^T - th2 I, written out: a matrix product would need SciPy's BLAS inside numba,
    # which the core install (numpy, numba, OpenCV) does not have
    w = (wx, wy, wz)
    W2 = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            W2[i, j] = w[i] * w[j] - (th2 if i == j else 0.0)
    for i in range(3):
        for j in range(3):
            e = 1.0 if i == j else 0.0
            out[i, j] = e + A * W[i, j] + B * W2[i, j]
    for i in range(3):
        Vv = 0.0
        for j in range(3):
            e = 1.0 if i == j else 0.0
            Vv += (e + B * W[i, j] + C * W2[i, j]) * xi[j]
        out[i, 3] = Vv
    out[3, 0] = 0.0; out[3, 1] = 0.0; out[3, 2] = 0.0; out[3, 3] = 1.0


@njit(cache=True, nogil=True, fastmath=False)
def _matmul4(A, B, out):
    for i in range(4):
        for j in range(4):
            s = 0.0
            for k in range(4):
                s += A[i, k] * B[k, j]
            out[i, j] = s


@njit(cache=True, nogil=True, fastmath=False)
def lm_level(pts, img3, interp, T_init, cam, prm, max_iter, aff_in, buf, T_out, acc_out, aff_out, stats):
    """Iteratively re-weighted Levenberg-Marquardt on ``T_new_ref`` for one pyramid level.

    Schedule (ALGORITHM_NOTES; parameters ``TP_LAMBDA_*``): lambda starts at 0; accepted step:
    ``lambda <- 0`` if ``lambda <= accept_max`` else ``lambda * accept_factor``; rejected step:
    ``lambda <- lambda_init`` if it was 0 else ``lambda * reject_factor^k`` for the ``k``-th try of the
    iteration (LSD-SLAM's SE3Tracker: after repeated rejections lambda grows fast, so a converged level
    stops after a few wasted evaluations instead of up to seven; phone, KITTI 07 seeds 1 / 2: tracking 6.9 /
    6.4 -> 5.7 / 5.7 ms per frame, ATE 0.48 / 0.44 -> 0.46 / 0.49 % of the path); damping
    ``H_ii *= (1 + lambda)``. The level stops when ``err/last_err > TP_CONV_RATIO`` after an accepted
    step, when a rejected step has ``|dxi|^2 < TP_CONV_EPS``, after ``max_iter`` accepted-or-final
    iterations, or when the system is singular. Each evaluation is one :func:`accumulate` pass.
    With ``prm[TP_AFF_ENABLED]`` the unknowns are the twist, ``alpha = log a`` and ``b`` (starting
    from ``aff_in = (a, b)``; prior ``N * (TP_AFF_PRIOR_A alpha^2 + TP_AFF_PRIOR_B b^2)`` added to H, g
    and the energy); otherwise only the twist, with ``(a, b) = aff_in`` fixed.
    Writes the final pose (``T_out``), its accumulator (``acc_out``), the affine brightness
    (``aff_out``) and ``stats`` (layout ``ST_*``).
    """
    conv_ratio = prm[TP_CONV_RATIO]
    conv_eps = prm[TP_CONV_EPS]
    lambda_init = prm[TP_LAMBDA_INIT]
    lambda_accept_max = prm[TP_LAMBDA_ACCEPT_MAX]
    lambda_accept_factor = prm[TP_LAMBDA_ACCEPT_FACTOR]
    lambda_reject_factor = prm[TP_LAMBDA_REJECT_FACTOR]
    min_points = prm[TP_MIN_POINTS]
    solve_eps = prm[TP_SOLVE_EPS]
    min_hessian_diag = prm[TP_MIN_HESSIAN_DIAG]
    aff_enabled = prm[TP_AFF_ENABLED] > 0.5
    n_unk = NP if aff_enabled else 6
    prior_a = prm[TP_AFF_PRIOR_A] if aff_enabled else 0.0
    prior_b = prm[TP_AFF_PRIOR_B] if aff_enabled else 0.0
    T = T_init.copy()
    Tn = np.empty((4, 4))
    E = np.empty((4, 4))
    acc = acc_out
    acc_new = np.empty(ACC_SIZE)
    H = np.empty((NP, NP))
    A = np.empty((NP, NP))
    g = np.empty(NP)
    b = np.empty(NP)
    inc = np.zeros(NP)
    aff_a = aff_in[0]
    aff_b = aff_in[1]
    alpha = np.log(aff_a) if aff_a > 0.0 else 0.0
    aff_a = np.exp(alpha)
    last_n = accumulate(pts, img3, interp, T, cam, prm, aff_a, aff_b, buf, acc)
    iters = 0
    status = 0
    if acc[ACC_N] < min_points:
        status = 1
    else:
        last_err = acc[ACC_ENERGY] / acc[ACC_N] + prior_a * alpha * alpha + prior_b * aff_b * aff_b
        lam = 0.0
        done = False
        while iters < max_iter and not done:
            iters += 1
            unpack_normal_equations(acc, H, g)
            n_pts = acc[ACC_N]
            if aff_enabled:          # the weak prior pulling alpha and b to 0
                H[6, 6] += prior_a * n_pts
                g[6] += prior_a * n_pts * alpha
                H[7, 7] += prior_b * n_pts
                g[7] += prior_b * n_pts * aff_b
            hmax = 0.0
            for i in range(6):
                if H[i, i] > hmax:
                    hmax = H[i, i]
            if not (hmax > min_hessian_diag * acc[ACC_N]):
                status = 2
                break
            tries = 0
            while True:
                tries += 1
                for i in range(n_unk):
                    for j in range(n_unk):
                        A[i, j] = H[i, j]
                    A[i, i] = H[i, i] * (1.0 + lam)
                    b[i] = -g[i]
                if not solve_spd(A, b, inc, n_unk, solve_eps):
                    status = 2
                    done = True
                    break
                exp_se3_nb(inc, E)
                _matmul4(E, T, Tn)
                alpha_n = alpha + inc[6]
                b_n = aff_b + inc[7]
                a_n = np.exp(alpha_n)
                last_n = accumulate(pts, img3, interp, Tn, cam, prm, a_n, b_n, buf, acc_new)
                n_new = acc_new[ACC_N]
                if n_new >= min_points:
                    err = acc_new[ACC_ENERGY] / n_new + prior_a * alpha_n * alpha_n + prior_b * b_n * b_n
                else:
                    err = np.inf
                if err < last_err:
                    for i in range(4):
                        for j in range(4):
                            T[i, j] = Tn[i, j]
                    for k in range(ACC_SIZE):
                        acc[k] = acc_new[k]
                    alpha = alpha_n
                    aff_a = a_n
                    aff_b = b_n
                    if err / last_err > conv_ratio:
                        done = True
                    last_err = err
                    if lam <= lambda_accept_max:
                        lam = 0.0
                    else:
                        lam *= lambda_accept_factor
                    break
                else:
                    step2 = 0.0
                    for i in range(6):
                        step2 += inc[i] * inc[i]
                    if step2 < conv_eps or tries >= max_iter:
                        done = True
                        break
                    if lam == 0.0:
                        lam = lambda_init
                    else:
                        lam *= lambda_reject_factor ** tries     # LSD-SLAM: the k-th retry multiplies by factor^k
        stats[ST_ERR] = last_err
    for i in range(4):
        for j in range(4):
            T_out[i, j] = T[i, j]
    aff_out[0] = aff_a
    aff_out[1] = aff_b
    stats[ST_ITER] = iters
    stats[ST_STATUS] = status
    stats[ST_LAST_N] = last_n
    if status == 1:
        stats[ST_ERR] = np.nan


@njit(cache=True, nogil=True, fastmath=False)
def track_level(pts, img, interp, horizon, img3, T, cam, prm, max_iter, aff, buf, T_out, acc_out, aff_out, stats):
    """One pyramid level of a frame: the interpolation stack of the (smoothed) new image ``img`` into
    ``img3`` (cubic B-spline coefficients, ``horizon`` as in :func:`lite_vo.image.bspline_coefficient_stack`,
    when ``interp == INTERP_BSPLINE``; else ``[I, gx, gy]`` as in
    :func:`lite_vo.image.intensity_gradient_stack`), then :func:`lm_level` from the pose ``T`` and the
    brightness ``aff``. When the level has a result (status not 1) and its pose is finite, ``T`` and
    ``aff`` are overwritten with it (the next level starts there). Returns the status (``ST_STATUS``)."""
    if interp == INTERP_BSPLINE:
        bspline_coefficients_nb(img, img3, horizon)
    else:
        gradient_stack_nb(img, img3)
    lm_level(pts, img3, interp, T, cam, prm, max_iter, aff, buf, T_out, acc_out, aff_out, stats)
    status = int(stats[ST_STATUS])
    if status != 1:
        finite = True
        for i in range(4):
            for j in range(4):
                if not np.isfinite(T_out[i, j]):
                    finite = False
        if finite:
            for i in range(4):
                for j in range(4):
                    T[i, j] = T_out[i, j]
            aff[0] = aff_out[0]
            aff[1] = aff_out[1]
    return status


@njit(cache=True, nogil=True, fastmath=False)
def extract_points(valid, idepth, idepth_var, img, cam, pts, xs, ys):
    """Fill the packed point array (layout ``PTS_COLS``) and pixel coordinates of the valid pixels,
    row-major order; returns the count (``pts`` must have room for every valid pixel)."""
    fx, fy, cx, cy = cam[0], cam[1], cam[2], cam[3]
    h, w = valid.shape
    n = 0
    for y in range(h):
        for x in range(w):
            if valid[y, x]:
                z = 1.0 / np.float64(idepth[y, x])
                pts[n, 0] = (x - cx) / fx * z
                pts[n, 1] = (y - cy) / fy * z
                pts[n, 2] = z
                pts[n, 3] = img[y, x]
                pts[n, 4] = idepth_var[y, x]
                xs[n] = x
                ys[n] = y
                n += 1
    return n


def warmup(runtime: bool = False) -> None:
    """Compile (or load from the cache) every kernel of this module on tiny inputs. ``runtime``: only
    what a run calls (the read-only points of a TrackingReference; not the standalone inner helpers,
    which are compiled into their callers, nor the writable-points signatures the tests use)."""
    rng = np.random.default_rng(0)
    n = 16
    pts = np.empty((n, PTS_COLS), np.float32)
    pts[:, 0] = rng.uniform(-0.3, 0.3, n)
    pts[:, 1] = rng.uniform(-0.3, 0.3, n)
    pts[:, 2] = 1.0
    pts[:, 3] = rng.uniform(0, 255, n)
    pts[:, 4] = 1e-3
    img3 = rng.uniform(0, 255, (8, 8, 3)).astype(np.float32)
    T = np.eye(4)
    cam = np.array([4.0, 4.0, 3.5, 3.5])
    prm = np.zeros(TP_N)
    prm[TP_SIGMA_I2] = 16.0
    prm[TP_HUBER] = 1.5
    prm[TP_BORDER] = 1.0
    prm[TP_MIN_POINTS] = 6.0
    prm[TP_SATURATION] = 255.0
    acc = np.empty(ACC_SIZE)
    buf = np.empty((BUF_ROWS, n))
    T_out = np.empty((4, 4))
    aff = np.array([1.0, 0.0])
    aff_out = np.empty(2)
    stats = np.zeros(ST_SIZE)
    # TrackingReference hands the kernels read-only point arrays: numba types those separately
    pts_ro = pts.copy()
    pts_ro.flags.writeable = False
    for p in ((pts_ro,) if runtime else (pts, pts_ro)):
        for enabled in (0.0, 1.0):
            prm[TP_AFF_ENABLED] = enabled
            if not runtime:
                accumulate(p, img3, INTERP_BILINEAR, T, cam, prm, 1.0, 0.0, buf, acc)
            lm_level(p, img3, INTERP_BSPLINE, T, cam, prm, 3, aff, buf, T_out, acc, aff_out, stats)
            img = img3[:, :, 0].copy()
            img_ro = img.copy()
            img_ro.flags.writeable = False        # the pyramid itself when the reference does not smooth
            for im in (img, img_ro):
                track_level(p, im, INTERP_BILINEAR, 14, img3, T.copy(), cam, prm, 3, aff.copy(), buf, T_out, acc,
                            aff_out, stats)
                track_level(p, im, INTERP_BSPLINE, 14, img3[:, :, :1].copy(), T.copy(), cam, prm, 3, aff.copy(),
                            buf, T_out, acc, aff_out, stats)
    m = np.ones((4, 4), np.bool_)
    one = np.ones((4, 4), np.float32)
    extract_points(m, one, one, one, cam, np.empty((16, PTS_COLS), np.float32),
                   np.empty(16, np.float32), np.empty(16, np.float32))
    if runtime:
        return
    unpack_normal_equations(acc, np.empty((NP, NP)), np.empty(NP))
    x = np.zeros(NP)
    solve_spd(np.eye(NP), np.ones(NP), x, NP, 1e-12)
    E = np.empty((4, 4))
    exp_se3_nb(np.full(6, 0.1), E)
