"""Slow, obviously-correct numpy twins of the image and tracking kernels, plus a tiny analytic
textured-room renderer with exact depth (for synthetic tracking tests).

Nothing here is fast or clever on purpose: tests compare the numba kernels against these.
"""
from __future__ import annotations

import numpy as np

from lite_vo.camera import PinholeIntrinsics
from lite_vo.tracking import _kernels as kernels


# ----------------------------------------------------------------------------- image
def downsample_image(img):
    img = np.asarray(img, np.float64)
    h2, w2 = img.shape[0] // 2, img.shape[1] // 2
    out = np.zeros((h2, w2))
    for y in range(h2):
        for x in range(w2):
            out[y, x] = img[2 * y:2 * y + 2, 2 * x:2 * x + 2].mean()
    return out.astype(np.float32)


def downsample_idepth(d, v, m):
    h2, w2 = d.shape[0] // 2, d.shape[1] // 2
    od = np.full((h2, w2), np.nan)
    ov = np.full((h2, w2), np.nan)
    om = np.zeros((h2, w2), bool)
    for y in range(h2):
        for x in range(w2):
            sel = m[2 * y:2 * y + 2, 2 * x:2 * x + 2]
            if sel.any():
                dd = d[2 * y:2 * y + 2, 2 * x:2 * x + 2][sel].astype(np.float64)
                vv = v[2 * y:2 * y + 2, 2 * x:2 * x + 2][sel].astype(np.float64)
                od[y, x] = np.sum(dd / vv) / np.sum(1 / vv)      # eq. 5.2
                ov[y, x] = len(dd) / np.sum(1 / vv)              # eq. 5.3
                om[y, x] = True
    return od, ov, om


def gradients(img):
    img = np.asarray(img, np.float64)
    gx = np.zeros_like(img)
    gy = np.zeros_like(img)
    gx[1:-1, 1:-1] = 0.5 * (img[1:-1, 2:] - img[1:-1, :-2])
    gy[1:-1, 1:-1] = 0.5 * (img[2:, 1:-1] - img[:-2, 1:-1])
    return gx, gy


# ----------------------------------------------------------------------------- tracking
def bspline_sample(coef, u, v):
    """Cubic B-spline value and gradient at (u, v) from a coefficient image (textbook weights)."""
    x0, y0 = int(np.floor(u)), int(np.floor(v))
    tx, ty = u - x0, v - y0

    def w(t):
        return np.array([(1 - t) ** 3, 3 * t ** 3 - 6 * t ** 2 + 4, -3 * t ** 3 + 3 * t ** 2 + 3 * t + 1, t ** 3]) / 6

    def dw(t):
        return np.array([-3 * (1 - t) ** 2, 9 * t ** 2 - 12 * t, -9 * t ** 2 + 6 * t + 3, 3 * t ** 2]) / 6

    patch = coef[y0 - 1:y0 + 3, x0 - 1:x0 + 3]
    return w(ty) @ patch @ w(tx), w(ty) @ patch @ dw(tx), dw(ty) @ patch @ w(tx)


def accumulate(pts, img3, interp, T, cam, prm, aff_a, aff_b):
    """Twin of ``_kernels.accumulate``; returns the accumulator vector (``ACC_*`` layout)."""
    fx, fy, cx, cy = cam
    sigma_i2, huber_k = prm[kernels.TP_SIGMA_I2], prm[kernels.TP_HUBER]
    with_affine = prm[kernels.TP_AFF_ENABLED] > 0.5
    good_c2, good_g2 = prm[kernels.TP_GOOD_C2], prm[kernels.TP_GOOD_G2]
    border, min_z = prm[kernels.TP_BORDER], prm[kernels.TP_MIN_Z]
    pts = np.asarray(pts, np.float64)
    img3 = np.asarray(img3, np.float64)
    h, w = img3.shape[:2]
    P = pts[:, :3]
    q = P @ T[:3, :3].T + T[:3, 3]
    ok = q[:, 2] > min_z
    with np.errstate(divide="ignore", invalid="ignore"):
        u = fx * q[:, 0] / q[:, 2] + cx
        v = fy * q[:, 1] / q[:, 2] + cy
    ok &= (u >= border) & (u < w - 1 - border) & (v >= border) & (v < h - 1 - border)
    acc = np.zeros(kernels.ACC_SIZE)
    Hm = np.zeros((8, 8))
    g = np.zeros(8)
    for i in np.nonzero(ok)[0]:
        if interp == kernels.INTERP_BSPLINE:
            i_new, gx, gy = bspline_sample(img3[:, :, 0], u[i], v[i])
        else:
            x0, y0 = int(np.floor(u[i])), int(np.floor(v[i]))
            ax, ay = u[i] - x0, v[i] - y0
            patch = img3[y0:y0 + 2, x0:x0 + 2]                   # [[p00, p10], [p01, p11]]
            wts = np.array([[(1 - ax) * (1 - ay), ax * (1 - ay)], [(1 - ax) * ay, ax * ay]])
            i_new, gx, gy = (patch * wts[:, :, None]).sum(axis=(0, 1))
        if pts[i, 3] >= prm[kernels.TP_SATURATION] or i_new >= prm[kernels.TP_SATURATION]:
            continue                                         # clipped pixel
        r = i_new - (aff_a * pts[i, 3] + aff_b)
        if not (np.isfinite(r) and np.isfinite(gx) and np.isfinite(gy)):
            continue
        X, Y, Z = q[i]
        # d proj / d q, then chain with the gradient
        dproj = np.array([[fx / Z, 0, -fx * X / Z ** 2], [0, fy / Z, -fy * Y / Z ** 2]])
        Jq = np.array([gx, gy]) @ dproj
        # d q / d xi for a left increment: [I | -hat(q)]
        hatq = np.array([[0, -Z, Y], [Z, 0, -X], [-Y, X, 0]])
        J6 = Jq @ np.hstack([np.eye(3), -hatq])
        # affine brightness: r = I_new - (exp(alpha) I_ref + b): dr/dalpha = -a I_ref, dr/db = -1
        J = np.concatenate([J6, [-aff_a * pts[i, 3], -1.0] if with_affine else [0.0, 0.0]])
        # d r / d idepth: the reference point is p(d) = ray / d, q(d) = R ray / d + t
        d_ref = 1.0 / pts[i, 2]
        ray = pts[i, :3] * d_ref
        dq_dd = -(T[:3, :3] @ ray) / d_ref ** 2
        dr_dd = Jq @ dq_dd
        wp = 1.0 / (sigma_i2 + pts[i, 4] * dr_dd ** 2)
        rn = abs(r) * np.sqrt(wp)
        wh = 1.0 if rn <= huber_k else huber_k / rn
        wgt = wp * wh
        acc[kernels.ACC_ENERGY] += rn ** 2 if rn <= huber_k else 2 * huber_k * rn - huber_k ** 2
        Hm += wgt * np.outer(J, J)
        g += wgt * J * r
        if not with_affine:
            Hm[6:, :] = 0.0
            Hm[:, 6:] = 0.0
        acc[kernels.ACC_N] += 1
        if r * r / (good_c2 + good_g2 * (gx * gx + gy * gy)) < 1:
            acc[kernels.ACC_GOOD] += 1
        else:
            acc[kernels.ACC_BAD] += 1
        acc[kernels.ACC_ABS_R] += abs(r)
    acc[kernels.ACC_H:kernels.ACC_H + 36] = Hm[np.triu_indices(8)]
    acc[kernels.ACC_G:kernels.ACC_G + 8] = g
    return acc


def track_level(pts, img, interp, img3, T, cam, prm, max_iter, aff, buf, T_out, acc, aff_out, stats):
    """Twin of ``kernels.track_level`` from the public pieces: the image module's stack functions,
    ``kernels.lm_level``, then the pose and brightness handed on in numpy (``T`` and ``aff`` in place)."""
    from lite_vo.image import bspline_coefficient_stack, intensity_gradient_stack
    if interp == kernels.INTERP_BSPLINE:
        img3[...] = bspline_coefficient_stack(img)
    else:
        img3[...] = intensity_gradient_stack(img)
    kernels.lm_level(pts, img3, interp, T, cam, prm, max_iter, aff, buf, T_out, acc, aff_out, stats)
    status = int(stats[kernels.ST_STATUS])
    if status != 1 and np.all(np.isfinite(T_out)):
        T[...] = T_out
        aff[...] = aff_out
    return status


def residuals(pts, img, T, intr: PinholeIntrinsics):
    """Plain residuals ``I_new(warp) - I_ref`` (NaN where a point does not warp inside)."""
    from scipy.ndimage import map_coordinates
    q = np.asarray(pts[:, :3], np.float64) @ T[:3, :3].T + T[:3, 3]
    u = intr.fx * q[:, 0] / q[:, 2] + intr.cx
    v = intr.fy * q[:, 1] / q[:, 2] + intr.cy
    val = map_coordinates(np.asarray(img, np.float64), [v, u], order=1, mode="nearest")
    out = val - pts[:, 3]
    out[(q[:, 2] <= 0) | (u < 0) | (v < 0) | (u > img.shape[1] - 1) | (v > img.shape[0] - 1)] = np.nan
    return out


# ----------------------------------------------------------------------------- synthetic room
class Room:
    """A textured box room (analytic ray casting): back wall, floor, ceiling, side walls.

    Texture: two octaves of smooth value noise on each plane (band-limited, lots of gradient).
    Coordinates: world = camera frame of the identity pose, looking along +z.
    """

    def __init__(self, seed=0, depth=3.0, half_width=1.6, floor=1.0, ceiling=-1.2, cell=0.06):
        rng = np.random.default_rng(seed)
        self.table = rng.uniform(0.0, 1.0, (5, 256, 256))
        # planes: (normal, offset, in-plane axes, id): n . X = offset
        self.planes = [
            (np.array([0.0, 0.0, 1.0]), depth, (0, 1)),
            (np.array([0.0, 1.0, 0.0]), floor, (0, 2)),
            (np.array([0.0, 1.0, 0.0]), ceiling, (0, 2)),
            (np.array([1.0, 0.0, 0.0]), -half_width, (1, 2)),
            (np.array([1.0, 0.0, 0.0]), half_width, (1, 2)),
        ]
        self.cell = cell

    def _noise(self, k, a, b, cell):
        s, t = a / cell, b / cell
        i0, j0 = np.floor(s).astype(np.int64), np.floor(t).astype(np.int64)
        fs, ft = s - i0, t - j0
        fs = fs * fs * (3 - 2 * fs)
        ft = ft * ft * (3 - 2 * ft)
        tab = self.table[k]
        v00 = tab[i0 % 256, j0 % 256]
        v10 = tab[(i0 + 1) % 256, j0 % 256]
        v01 = tab[i0 % 256, (j0 + 1) % 256]
        v11 = tab[(i0 + 1) % 256, (j0 + 1) % 256]
        return (v00 * (1 - fs) * (1 - ft) + v10 * fs * (1 - ft) + v01 * (1 - fs) * ft + v11 * fs * ft)

    def _texture(self, k, a, b):
        return (20.0 + 70.0 * self._noise(k, a, b, self.cell)
                + 50.0 * self._noise(k, a + 7.3, b - 3.1, self.cell * 3.7)
                + 100.0 * self._noise(k, a - 2.9, b + 5.3, self.cell * 11.0))

    def cast(self, origin, dirs):
        """Distance along ``dirs`` (N, 3) and intensity of the first hit."""
        best_t = np.full(dirs.shape[0], np.inf)
        val = np.zeros(dirs.shape[0])
        for k, (n, off, axes) in enumerate(self.planes):
            nd = dirs @ n
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (off - origin @ n) / nd
            hit = (t > 1e-6) & (t < best_t)
            if hit.any():
                p = origin + t[hit, None] * dirs[hit]
                best_t[hit] = t[hit]
                val[hit] = self._texture(k, p[:, axes[0]], p[:, axes[1]])
        return best_t, val

    def render(self, T_world_cam, intr: PinholeIntrinsics, supersample=3):
        """(image float32 0..255 anti-aliased, depth float32 z at pixel centres)."""
        T = np.asarray(T_world_cam, np.float64)
        R, c = T[:3, :3], T[:3, 3]
        h, w = intr.height, intr.width
        img = np.zeros((h, w))
        offs = (np.arange(supersample) + 0.5) / supersample - 0.5
        ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
        for oy in offs:
            for ox in offs:
                d = np.stack([(xs + ox - intr.cx) / intr.fx, (ys + oy - intr.cy) / intr.fy,
                              np.ones_like(xs)], -1).reshape(-1, 3)
                _, val = self.cast(c, d @ R.T)
                img += val.reshape(h, w)
        img /= supersample ** 2
        d = np.stack([(xs - intr.cx) / intr.fx, (ys - intr.cy) / intr.fy, np.ones_like(xs)], -1).reshape(-1, 3)
        t, _ = self.cast(c, d @ R.T)
        return img.astype(np.float32), t.reshape(h, w).astype(np.float32)
