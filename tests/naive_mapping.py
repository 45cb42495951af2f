"""Slow, obviously-correct numpy twins of the mapping kernels (``lite_vo/mapping/_kernels.py``).

Written for clarity, per pixel in plain Python/numpy, on small images only. The tests compare
each kernel with its twin on seeded inputs including edge cases.
"""
from __future__ import annotations

import math

import naive_tracking
import numpy as np

from lite_vo.mapping import _kernels as kernels


def bilinear(img, x, y):
    ix, iy = int(math.floor(x)), int(math.floor(y))
    dx, dy = x - ix, y - iy
    p = img.astype(np.float64)
    return ((1 - dx) * (1 - dy) * p[iy, ix] + dx * (1 - dy) * p[iy, ix + 1]
            + (1 - dx) * dy * p[iy + 1, ix] + dx * dy * p[iy + 1, ix + 1])


def gradients(img):
    """The half central differences of naive_tracking and the 3x3 max filter of their magnitude."""
    gx, gy = naive_tracking.gradients(img)
    h, w = gx.shape
    mag = np.hypot(gx, gy)
    pad = np.pad(mag, 1, constant_values=0.0)
    maxg = np.max([pad[dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3)], axis=0)
    return gx, gy, maxg


def epipolar_direction(cur, x, y, px, py, c, fx, fy, cx, cy, prm):
    ep = np.array([-fx * c[0] + c[2] * (px - cx), -fy * c[1] + c[2] * (py - cy)])
    n2 = float(ep @ ep)
    if not n2 >= prm[kernels.P_MIN_EPL_LENGTH] ** 2:
        return False, 0.0, 0.0
    g = np.array([float(cur[y, x + 1]) - float(cur[y, x - 1]), float(cur[y + 1, x]) - float(cur[y - 1, x])])
    along2 = float(g @ ep) ** 2 / n2
    if not along2 >= prm[kernels.P_MIN_EPL_GRAD_SQ]:
        return False, 0.0, 0.0
    if not along2 >= prm[kernels.P_MIN_EPL_ANGLE_COS] ** 2 * float(g @ g):
        return False, 0.0, 0.0
    e = ep / math.sqrt(n2)
    return True, e[0], e[1]


def line_stereo(cur, ref, u, v, epxn, epyn, min_id, prior_id, max_id, R, t, fx, fy, cx, cy,
                gxi, gyi, track_residual, prm, allow_long, ref_a, ref_b, scratch_len=64):
    """Same contract as ``_kernels.line_stereo`` (without scratch arrays)."""
    h, w = cur.shape
    Kmat = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    a = R @ np.array([(u - cx) / fx, (v - cy) / fy, 1.0])
    t = np.asarray(t, float)
    rescale = a[2] + prior_id * t[2]
    fail = lambda code, length=0.0, err=0.0: (code, 0.0, 0.0, length, err)  # noqa: E731
    if not (prm[kernels.P_MIN_SCALE] < rescale < prm[kernels.P_MAX_SCALE]):
        return fail(kernels.OUT_OF_IMAGE)
    if a[2] + max_id * t[2] < 0.001:
        max_id = (0.001 - a[2]) / t[2]
    if a[2] + min_id * t[2] < 0.001 or max_id < min_id:
        return fail(kernels.OUT_OF_IMAGE)

    def proj(d):
        p = Kmat @ (a + d * t)
        return p[:2] / p[2]
    far, close = proj(min_id), proj(max_id)
    if not np.all(np.isfinite(np.concatenate([far, close]))):
        return fail(kernels.NUMERIC)
    length = float(np.linalg.norm(close - far))
    if not (length > 0) or not math.isfinite(length):
        return fail(kernels.NUMERIC)
    inc = (close - far) / length
    if length > prm[kernels.P_MAX_EPL]:
        if not allow_long:
            return fail(kernels.TOO_LONG, length)
        close = far + inc * prm[kernels.P_MAX_EPL]
    far = far - inc
    close = close + inc
    if length < prm[kernels.P_MIN_EPL]:
        pad = 0.5 * (prm[kernels.P_MIN_EPL] - length)
        far, close = far - pad * inc, close + pad * inc
    b = prm[kernels.P_BORDER_SAMPLES]
    inside = lambda p: b < p[0] < w - b and b < p[1] < h - b  # noqa: E731
    if not inside(far):
        return fail(kernels.OUT_OF_IMAGE)
    if not inside(close):
        # move the near end back along the line until it is inside (x first, then y)
        if close[0] <= b:
            close = close + (b - close[0]) / inc[0] * inc
        elif close[0] >= w - b:
            close = close + (w - b - close[0]) / inc[0] * inc
        if close[1] <= b:
            close = close + (b - close[1]) / inc[1] * inc
        elif close[1] >= h - b:
            close = close + (h - b - close[1]) / inc[1] * inc
        if not inside(close) or not np.linalg.norm(close - far) >= prm[kernels.P_MIN_CLIPPED_EPL]:
            return fail(kernels.OUT_OF_IMAGE)
    # the five samples in the current image (checked after the line geometry)
    ep = np.array([epxn, epyn]) * rescale
    offs = np.arange(-2, 3)
    cur_pts = np.array([u, v]) + offs[:, None] * ep
    if not (np.all(cur_pts[[0, -1], 0] > 0) and np.all(cur_pts[[0, -1], 0] < w - 2)
            and np.all(cur_pts[[0, -1], 1] > 0) and np.all(cur_pts[[0, -1], 1] < h - 2)):
        return fail(kernels.OUT_OF_IMAGE)
    cvals = np.array([bilinear(cur, x, y) for x, y in cur_pts])
    sat = prm[kernels.P_SATURATION] if abs(ref_a - 1.0) > prm[kernels.P_SAT_GAIN_TOL] else np.inf
    if np.any(cvals >= sat):
        return fail(kernels.NO_EPL)                       # clipped patch

    def ref_sample(p):                                    # the reference in the current brightness
        s = bilinear(ref, *p)
        return ref_a * s + ref_b if s < sat else 1e6      # clipped samples never match
    n = int(np.linalg.norm(close - far) + 1e-6) + 1
    n = min(n, scratch_len - 4)
    positions = far + np.arange(n)[:, None] * inc
    # residual vectors of every candidate position (5 samples each)
    # the reference in the current frame's brightness
    resid = np.array([[ref_sample(p + o * inc) for o in offs] for p in positions]) - cvals
    ssd = np.sum(resid ** 2, axis=1)
    best = int(np.argmin(ssd))
    far_ones = [ssd[k] for k in range(n) if abs(k - best) >= 2]
    second = min(far_ones) if far_ones else 1e50
    if not ssd[best] <= 4 * prm[kernels.P_SSD_MAX]:
        return fail(kernels.NO_MATCH, length, ssd[best])
    if prm[kernels.P_AMBIGUITY] * ssd[best] > second:
        return fail(kernels.BAD_MATCH, length, ssd[best])
    pos, err, sub = float(best), ssd[best], False
    if prm[kernels.P_SUBPIXEL] > 0.5:
        cands = []
        for side in (-1, 1):
            j = best + side
            if 0 <= j < n:
                rb, rj = resid[best], resid[j]
                # E(s) = |rb + s (rj - rb)|^2 is a parabola; its minimum, if inside (0, 1)
                d = rj - rb
                s = -(rb @ d) / (d @ d) if d @ d > 0 else -1.0
                if 0 < s < 1 and rb @ d < 0:
                    cands.append((float(np.sum((rb + s * d) ** 2)), best + side * s))
        cands = [c for c in cands if c[0] < err]
        if cands:
            err, pos = min(cands)
            sub = True
    grad_along = float(np.sum(np.diff(cvals) ** 2))
    if err > prm[kernels.P_SSD_MAX] + math.sqrt(grad_along) * prm[kernels.P_SSD_GRAD_FACTOR]:
        return fail(kernels.NO_MATCH, length, err)
    match = far + pos * inc
    # inverse depth whose projection is the match (solve along the larger line component)
    if inc[0] ** 2 > inc[1] ** 2:
        xn = (match[0] - cx) / fx
        idepth = (a[0] - xn * a[2]) / (xn * t[2] - t[0])
        didpix = (a[2] * t[0] - a[0] * t[2]) / (xn * t[2] - t[0]) ** 2 / fx
        alpha = inc[0] * didpix
    else:
        yn = (match[1] - cy) / fy
        idepth = (a[1] - yn * a[2]) / (yn * t[2] - t[1])
        didpix = (a[2] * t[1] - a[1] * t[2]) / (yn * t[2] - t[1]) ** 2 / fy
        alpha = inc[1] * didpix
    if not idepth >= 0 or not math.isfinite(alpha):
        return fail(kernels.BAD_MATCH, length, err)
    photo = 4 * prm[kernels.P_SIGMA_I2] / (grad_along + 1e-10)
    e = prm[kernels.P_GEO_BASE] * (1 + track_residual)
    gl = gxi * epxn + gyi * epyn + 1e-10
    geo = e * e * (gxi ** 2 + gyi ** 2) / gl ** 2
    c = prm[kernels.P_SUBPIX_VAR] if sub else prm[kernels.P_NOSUBPIX_VAR]
    var = alpha ** 2 * (c + geo + photo)
    if not (var > 0 and math.isfinite(var)):
        return kernels.NUMERIC, 0.0, 0.0, length, err
    return kernels.OK, idepth, var, length, err


def line_length(u, v, min_id, max_id, R, t, fx, fy, cx, cy):
    a = R @ np.array([(u - cx) / fx, (v - cy) / fy, 1.0])
    t = np.asarray(t, float)
    if a[2] + max_id * t[2] < 0.001:
        max_id = (0.001 - a[2]) / t[2]
    if not (a[2] + min_id * t[2] >= 0.001 and max_id >= min_id):
        return math.inf
    Kmat = np.array([[fx, 0, 0], [0, fy, 0], [0, 0, 1.0]])
    p0, p1 = Kmat @ (a + min_id * t), Kmat @ (a + max_id * t)
    n = float(np.linalg.norm(p1[:2] / p1[2] - p0[:2] / p0[2]))
    return n if math.isfinite(n) else math.inf


def observe(cur, gx, gy, maxgrad, ref_images, ref_slots, ref_ids, ref_R, ref_t, ref_c, ref_residual, ref_aff,
            st, fx, fy, cx, cy, prm, stride, offset, scratch_len):
    """Twin of ``observe_kernel``; ``st`` is a dict of the state arrays (modified in place)."""
    h, w = cur.shape
    status = np.zeros((h, w), np.int8)
    nref = len(ref_slots)
    for y in range(3, h - 3):
        for x in range(3, w - 3):
            has = st["valid"][y, x] != 0
            g = maxgrad[y, x]
            if has and g < prm[kernels.P_MIN_GRAD]:
                st["valid"][y, x] = 0
                status[y, x] = 6
                continue
            if g < prm[kernels.P_MIN_GRAD] or st["blacklist"][y, x] < prm[kernels.P_MIN_BLACKLIST]:
                continue
            if stride > 1 and (y * w + x) % stride != offset:
                continue
            if nref == 0:
                continue
            if has and st["skip"][y, x] > 0:      # converged: wait for more baseline
                st["skip"][y, x] -= 1
                status[y, x] = 8
                continue
            if has:
                px, py = float(st["pos_x"][y, x]), float(st["pos_y"][y, x])
                prior = float(st["idepth_s"][y, x])
                sd = math.sqrt(float(st["var_s"][y, x]))
                lo = max(prior - prm[kernels.P_SEARCH_SIGMAS] * sd, 0.0)
                hi = min(prior + prm[kernels.P_SEARCH_SIGMAS] * sd, prm[kernels.P_MAX_IDEPTH])
                older = [i for i in range(nref) if ref_ids[i] >= st["ref_id"][y, x]]
                b = older[0] if older else nref - 1
            else:
                px, py, prior, lo, hi = float(x), float(y), prm[kernels.P_CREATE_PRIOR], 0.0, prm[kernels.P_MAX_IDEPTH]
                # oldest reference such that it and every newer one has a full-range line <= max_epl
                b = nref - 1
                while b > 0 and line_length(px, py, lo, hi, ref_R[b - 1], ref_t[b - 1], fx, fy, cx, cy) <= prm[kernels.P_MAX_EPL]:
                    b -= 1
            code, used, r_len = kernels.OUT_OF_IMAGE, b, 0.0
            while b < nref:
                ok, ex, ey = epipolar_direction(cur, x, y, px, py, ref_c[b], fx, fy, cx, cy, prm)
                if not ok:
                    code = kernels.NO_EPL
                    break
                code, r_id, r_var, r_len, _ = line_stereo(
                    cur, ref_images[ref_slots[b]], px, py, ex, ey, lo, prior, hi, ref_R[b], ref_t[b],
                    fx, fy, cx, cy, bilinear(gx, px, py), bilinear(gy, px, py), ref_residual[b], prm,
                    b == nref - 1, ref_aff[b][0], ref_aff[b][1], scratch_len)
                used = b
                if code in (kernels.OUT_OF_IMAGE, kernels.TOO_LONG):
                    b += 1
                    continue
                break
            if code == kernels.NO_EPL:
                status[y, x] = 7
                continue
            if code in (kernels.OUT_OF_IMAGE, kernels.TOO_LONG, kernels.NUMERIC):
                status[y, x] = 5
                continue
            if has:
                st["ref_id"][y, x] = max(st["ref_id"][y, x], ref_ids[used])
            if not has:
                if code == kernels.OK and r_var <= prm[kernels.P_MAX_VAR]:
                    for k, val in (("idepth", r_id), ("idepth_var", r_var), ("idepth_s", r_id), ("var_s", r_var),
                                   ("valid", 1), ("validity", prm[kernels.P_OBSERVE_VALIDITY]), ("pos_x", px),
                                   ("pos_y", py), ("ref_id", ref_ids[used]), ("blacklist", 0), ("skip", 0)):
                        st[k][y, x] = val
                    status[y, x] = 2
                elif code in (kernels.BAD_MATCH, kernels.NO_MATCH):
                    st["blacklist"][y, x] -= 1
                    status[y, x] = 4
                continue
            if code in (kernels.BAD_MATCH, kernels.NO_MATCH):
                st["validity"][y, x] = max(st["validity"][y, x] - prm[kernels.P_VALIDITY_DEC], 0.0)
                st["ref_id"][y, x] = ref_ids[used] + 1
                if code == kernels.BAD_MATCH:
                    st["idepth_var"][y, x] *= prm[kernels.P_FAIL_VAR_INC]
                    if st["idepth_var"][y, x] > prm[kernels.P_MAX_VAR]:
                        st["valid"][y, x] = 0
                        st["blacklist"][y, x] -= 1
                status[y, x] = 4
                continue
            if prm[kernels.P_DIFF_FAC_OBSERVE] * (r_id - prior) ** 2 > r_var + st["var_s"][y, x]:
                st["idepth_var"][y, x] *= prm[kernels.P_FAIL_VAR_INC]
                if st["idepth_var"][y, x] > prm[kernels.P_MAX_VAR]:
                    st["valid"][y, x] = 0
                status[y, x] = 3
                continue
            pvar = float(st["idepth_var"][y, x]) * prm[kernels.P_PRED_NOISE]
            # product of the two Gaussians (eq. 3.13)
            st["idepth"][y, x] = (pvar * r_id + r_var * float(st["idepth"][y, x])) / (pvar + r_var)
            st["idepth_var"][y, x] = min(pvar * r_var / (pvar + r_var), float(st["idepth_var"][y, x]))
            vmax = prm[kernels.P_VALIDITY_MAX] + g * prm[kernels.P_VALIDITY_MAX_GRAD] / 255.0
            st["validity"][y, x] = min(st["validity"][y, x] + prm[kernels.P_VALIDITY_INC], vmax)
            if r_len < prm[kernels.P_MIN_EPL]:
                st["skip"][y, x] = int(prm[kernels.P_SKIP_CONVERGED])
            status[y, x] = 1
    return status


def propagate(st, img_old, img_new, maxgrad_new, R, t, fx, fy, cx, cy, border, min_grad, diff_const2,
              diff_grad_mult, merge_fac, var_add, validity_cap, aff=(1.0, 0.0), saturation=250.0, sat_gain_tol=0.02):
    """Twin of ``propagate_kernel``: returns (new state dict, counts)."""
    h, w = img_old.shape
    out = {k: np.zeros((h, w), st[k].dtype) for k in ("idepth", "idepth_var", "idepth_s", "var_s", "valid",
                                                      "validity", "pos_x", "pos_y", "ref_id", "skip")}
    out["blacklist"] = st["blacklist"].copy()      # stays with the pixel, reset where a hypothesis lands
    out["pos_y"][:], out["pos_x"][:] = np.mgrid[0:h, 0:w]   # empty pixels keep their grid position
    counts = dict(kept=0, border=0, intensity=0, occluded=0, fused=0)
    for y in range(h):
        for x in range(w):
            if not st["valid"][y, x]:
                continue
            d = float(st["idepth_s"][y, x])
            if not d > 0:
                counts["border"] += 1
                continue
            px, py = float(st["pos_x"][y, x]), float(st["pos_y"][y, x])
            P_old = np.array([(px - cx) / fx, (py - cy) / fy, 1.0]) / d
            P = R @ P_old + t
            if not P[2] > 0:
                counts["border"] += 1
                continue
            d_new = 1.0 / P[2]
            u, v = fx * P[0] / P[2] + cx, fy * P[1] / P[2] + cy
            if not (border <= u <= w - 1 - border and border <= v <= h - 1 - border and 0 <= u < w - 1
                    and 0 <= v < h - 1):
                counts["border"] += 1
                continue
            ix, iy = int(u + 0.5), int(v + 0.5)
            g = float(maxgrad_new[iy, ix])
            if g < min_grad:
                counts["intensity"] += 1
                continue
            if 0 <= px < w - 1 and 0 <= py < h - 1:
                src = bilinear(img_old, px, py)
            else:
                src = float(img_old[min(max(int(py + 0.5), 0), h - 1), min(max(int(px + 0.5), 0), w - 1)])
            r = bilinear(img_new, u, v) - (aff[0] * src + aff[1])     # old intensity in the new brightness
            dst = bilinear(img_new, u, v)
            clipped = abs(aff[0] - 1.0) > sat_gain_tol and (src >= saturation or dst >= saturation)
            if not clipped and r * r > diff_const2 + diff_grad_mult * g * g:
                counts["intensity"] += 1
                continue
            new_var = (d_new / d) ** 4 * float(st["idepth_var"][y, x]) + var_add
            if out["valid"][iy, ix]:
                other = float(out["idepth"][iy, ix])
                if merge_fac * (other - d_new) ** 2 > new_var + out["idepth_var"][iy, ix]:
                    counts["occluded"] += 1
                    if d_new < other:
                        continue
                    out["valid"][iy, ix] = 0
            if not out["valid"][iy, ix]:
                vals = dict(idepth=d_new, idepth_var=new_var, validity=st["validity"][y, x], pos_x=u, pos_y=v,
                            ref_id=st["ref_id"][y, x], skip=st["skip"][y, x], valid=1)
                counts["kept"] += 1
            else:
                ov = float(out["idepth_var"][iy, ix])
                vals = dict(idepth=(ov * d_new + new_var * float(out["idepth"][iy, ix])) / (ov + new_var),
                            idepth_var=1.0 / (1.0 / ov + 1.0 / new_var),
                            validity=min(out["validity"][iy, ix] + st["validity"][y, x], validity_cap),
                            ref_id=min(out["ref_id"][iy, ix], st["ref_id"][y, x]),
                            skip=min(out["skip"][iy, ix], st["skip"][y, x]))
                counts["fused"] += 1
            for k, val in vals.items():
                out[k][iy, ix] = val
            out["idepth_s"][iy, ix] = out["idepth"][iy, ix]
            out["var_s"][iy, ix] = out["idepth_var"][iy, ix]
            out["blacklist"][iy, ix] = 0
    return out, counts


def regularize(idepth, idepth_var, valid, validity, blacklist, radius, dist_var, diff_fac, validity_th, var_mode=0):
    """Twin of ``regularize_kernel``: returns (idepth_s, var_s, valid_out, blacklist_out) (s only where valid_out)."""
    h, w = idepth.shape
    d = idepth.astype(np.float64)
    v = idepth_var.astype(np.float64)
    out_d = np.zeros((h, w))
    out_v = np.zeros((h, w))
    out_valid = np.zeros((h, w), np.uint8)
    bl = blacklist.copy()
    for y in range(h):
        for x in range(w):
            if not valid[y, x]:
                continue
            ys, xs = np.mgrid[max(y - radius, 0):min(y + radius + 1, h), max(x - radius, 0):min(x + radius + 1, w)]
            ys, xs = ys.ravel(), xs.ravel()
            m = (valid[ys, xs] != 0)
            m &= diff_fac * (d[ys, xs] - d[y, x]) ** 2 <= v[ys, xs] + v[y, x]
            ys, xs = ys[m], xs[m]
            if validity[ys, xs].astype(np.float64).sum() < validity_th:
                bl[y, x] -= 1
                continue
            wgt = 1.0 / (v[ys, xs] + ((ys - y) ** 2 + (xs - x) ** 2) * dist_var)
            out_d[y, x] = np.sum(wgt * d[ys, xs]) / np.sum(wgt)
            out_v[y, x] = (v[ys, xs].min(), v[y, x], 1.0 / np.sum(wgt))[var_mode]
            out_valid[y, x] = 1
    return out_d, out_v, out_valid, bl


def fill(idepth, idepth_var, valid, validity, ref_id, blacklist, maxgrad, min_grad, min_blacklist, create_th,
         unblacklist_th, new_var, new_validity):
    """Twin of ``fill_kernel``: returns a dict of the created hypotheses {(y, x): (idepth, ref_id)}."""
    h, w = idepth.shape
    created = {}
    for y in range(2, h - 2):
        for x in range(2, w - 2):
            if valid[y, x] or maxgrad[y, x] < min_grad:
                continue
            win = (slice(y - 2, y + 3), slice(x - 2, x + 3))
            m = valid[win] != 0
            vs = float(validity[win][m].astype(np.float64).sum())
            if not ((blacklist[y, x] >= min_blacklist and vs > create_th) or vs > unblacklist_th):
                continue
            if not m.any():
                continue
            iv = 1.0 / idepth_var[win][m].astype(np.float64)
            created[(y, x)] = (float(np.sum(iv * idepth[win][m]) / np.sum(iv)), int(ref_id[win][m].min()))
    return created
