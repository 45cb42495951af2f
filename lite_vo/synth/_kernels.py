"""numba kernels of the synthetic renderer: an exact ray caster of axis-aligned boxes.

Owns the hot loop only (ray casting, mip-mapped texture sampling). Scene layout, texture
generation and validation live in :mod:`lite_vo.synth.scenes` / :mod:`lite_vo.synth.render`.
Imports numpy and numba only. Thresholds are arguments (numba freezes globals).
``error_model="numpy"``: no ZeroDivisionError checks in the hot loop (every division is
guarded or cannot be by zero), ~10 % faster.

Face numbering: the room box (seen from inside) has faces 0..5, solid box ``b`` has faces
``6 + 6 b + 0..5``; inside a box, face ``2 * axis + side`` (side 0: the ``lo`` face, 1: ``hi``).
A face's texture coordinates are the world coordinates of the two other axes,
``((axis + 1) % 3, (axis + 2) % 3)``, minus the face's ``tex_origin``, in texels of ``tex_texel``.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange


@njit(cache=True, nogil=True, error_model="numpy")
def _room_exit(o, d, lo, hi, t_min, t_best, face, axis):
    """Exit plane of the room along one axis: updates (t_best, face)."""
    if d > 0.0:
        t = (hi - o) / d
        side = 1
    elif d < 0.0:
        t = (lo - o) / d
        side = 0
    else:
        return t_best, face
    if t > t_min and t < t_best:
        return t, 2 * axis + side
    return t_best, face


@njit(cache=True, nogil=True, error_model="numpy")
def _slab(o, d, lo, hi, t_near, t_far, ax_near, side_near, axis):
    """One axis of the ray/box slab test: updates (t_near, t_far, entry axis, entry side);
    returns t_near = +inf on a miss (ray parallel to the slab and outside it)."""
    if d == 0.0:
        if o < lo or o > hi:
            return np.inf, t_far, ax_near, side_near
        return t_near, t_far, ax_near, side_near
    t0 = (lo - o) / d
    t1 = (hi - o) / d
    if d > 0.0:
        if t0 > t_near:
            t_near, ax_near, side_near = t0, axis, 0
        if t1 < t_far:
            t_far = t1
    else:
        if t1 > t_near:
            t_near, ax_near, side_near = t1, axis, 1
        if t0 < t_far:
            t_far = t0
    return t_near, t_far, ax_near, side_near


@njit(cache=True, nogil=True, error_model="numpy")
def cast_ray(ox, oy, oz, dx, dy, dz, room_lo, room_hi, box_lo, box_hi, t_min, pu, pv, box_px):
    """Nearest hit ``(t, face)`` of the ray ``o + t d`` (t > t_min); face -1 if nothing is hit.

    ``(pu, pv)``: the ray's pixel coordinates; box ``b`` is skipped when they lie outside its
    conservative screen rectangle ``box_px[b] = (u_min, u_max, v_min, v_max)`` (culling only:
    pass +-inf rectangles to test every box)."""
    t_best = np.inf
    face = -1
    # room: the ray leaves the room box through the nearest exit plane
    t_best, face = _room_exit(ox, dx, room_lo[0], room_hi[0], t_min, t_best, face, 0)
    t_best, face = _room_exit(oy, dy, room_lo[1], room_hi[1], t_min, t_best, face, 1)
    t_best, face = _room_exit(oz, dz, room_lo[2], room_hi[2], t_min, t_best, face, 2)
    # solid boxes: slab test, entry face
    for b in range(box_lo.shape[0]):
        if pu < box_px[b, 0] or pu > box_px[b, 1] or pv < box_px[b, 2] or pv > box_px[b, 3]:
            continue
        tn, tf, ax, sd = -np.inf, np.inf, -1, 0
        tn, tf, ax, sd = _slab(ox, dx, box_lo[b, 0], box_hi[b, 0], tn, tf, ax, sd, 0)
        tn, tf, ax, sd = _slab(oy, dy, box_lo[b, 1], box_hi[b, 1], tn, tf, ax, sd, 1)
        tn, tf, ax, sd = _slab(oz, dz, box_lo[b, 2], box_hi[b, 2], tn, tf, ax, sd, 2)
        if ax < 0 or tn > tf or tn <= t_min or tn >= t_best:
            continue
        t_best = tn
        face = 6 + 6 * b + 2 * ax + sd
    return t_best, face


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def sample_level(tex_data, off, w, h, x, y):
    """Bilinear sample at texel coordinates (x, y) (texel centres at integers), clamped to the edge."""
    if x < 0.0:
        x = 0.0
    elif x > w - 1.0:
        x = w - 1.0
    if y < 0.0:
        y = 0.0
    elif y > h - 1.0:
        y = h - 1.0
    x0 = int(x)
    y0 = int(y)
    if x0 > w - 2:
        x0 = w - 2 if w > 1 else 0
    if y0 > h - 2:
        y0 = h - 2 if h > 1 else 0
    fx = x - x0
    fy = y - y0
    i00 = off + y0 * w + x0
    step_x = 1 if w > 1 else 0
    step_y = w if h > 1 else 0
    v00 = tex_data[i00]
    v01 = tex_data[i00 + step_x]
    v10 = tex_data[i00 + step_y]
    v11 = tex_data[i00 + step_y + step_x]
    top = v00 + fx * (v01 - v00)
    bot = v10 + fx * (v11 - v10)
    return top + fy * (bot - top)


@njit(cache=True, nogil=True, error_model="numpy")
def shade_hit(px, py, pz, dx, dy, dz, face, depth, sample_px, tex_data, tex_meta, tex_nlev,
              tex_origin, tex_texel, lod_bias, min_cos):
    """Trilinear (mip-mapped) texture value of the hit point p on ``face``.

    ``sample_px``: size of one sample at unit depth (1 / (f * ss)); the footprint on the surface
    is ``depth * sample_px * |d| / sqrt(|cos|)`` (area-based level of detail), with |cos| clamped
    to ``min_cos``; ``lod = log2(footprint / texel) + lod_bias`` clamped to the pyramid.
    """
    a = (face % 6) // 2
    if a == 0:
        s_m, t_m, da = py, pz, dx
    elif a == 1:
        s_m, t_m, da = pz, px, dy
    else:
        s_m, t_m, da = px, py, dz
    s_m -= tex_origin[face, 0]
    t_m -= tex_origin[face, 1]
    n2 = dx * dx + dy * dy + dz * dz
    c = math.sqrt(da * da / n2)
    if c < min_cos:
        c = min_cos
    texel = tex_texel[face]
    f = depth * sample_px / texel
    q = f * f * n2 / c  # (footprint / texel)^2
    lod = 0.5 * math.log2(max(q, 1e-12)) + lod_bias
    nlev = tex_nlev[face]
    if lod < 0.0:
        lod = 0.0
    if lod > nlev - 1.0:
        lod = nlev - 1.0
    l0 = int(lod)
    if l0 > nlev - 2:
        l0 = nlev - 2 if nlev > 1 else 0
    frac = lod - l0
    inv = 1.0 / (texel * (1 << l0))
    v0 = sample_level(tex_data, tex_meta[face, l0, 0], tex_meta[face, l0, 1],
                      tex_meta[face, l0, 2], s_m * inv - 0.5, t_m * inv - 0.5)
    if frac <= 0.0 or l0 + 1 >= nlev:
        return v0
    l1 = l0 + 1
    inv *= 0.5
    v1 = sample_level(tex_data, tex_meta[face, l1, 0], tex_meta[face, l1, 1],
                      tex_meta[face, l1, 2], s_m * inv - 0.5, t_m * inv - 0.5)
    return v0 + frac * (v1 - v0)


@njit(cache=True, nogil=True, error_model="numpy")
def _pixel_ray(R, xs, ys):
    return (R[0, 0] * xs + R[0, 1] * ys + R[0, 2], R[1, 0] * xs + R[1, 1] * ys + R[1, 2],
            R[2, 0] * xs + R[2, 1] * ys + R[2, 2])


@njit(cache=True, nogil=True, error_model="numpy")
def render_rows_centre(row_lo, row_hi, row_step, R, t, fx, fy, cx, cy, room_lo, room_hi, box_lo, box_hi,
                       box_px, tex_data, tex_meta, tex_nlev, tex_origin, tex_texel, lod_bias,
                       min_cos, t_min, out_img, out_depth, out_face):
    """Serial kernel, pass 1 for rows range(row_lo, row_hi, row_step): the ray through each pixel centre gives
    the z-depth, the face and a texture value filtered over one pixel footprint."""
    width = out_img.shape[1]
    sample_px = 1.0 / (0.5 * (fx + fy))
    ox, oy, oz = t[0], t[1], t[2]
    for v in range(row_lo, row_hi, row_step):
        yc = (v - cy) / fy
        for u in range(width):
            dx, dy, dz = _pixel_ray(R, (u - cx) / fx, yc)
            tc, fc = cast_ray(ox, oy, oz, dx, dy, dz, room_lo, room_hi, box_lo, box_hi, t_min,
                              u, v, box_px)
            out_face[v, u] = fc
            if fc < 0:
                out_depth[v, u] = 0.0
                out_img[v, u] = 0.0
                continue
            out_depth[v, u] = tc
            out_img[v, u] = shade_hit(ox + tc * dx, oy + tc * dy, oz + tc * dz, dx, dy, dz, fc,
                                      tc, sample_px, tex_data, tex_meta, tex_nlev, tex_origin,
                                      tex_texel, lod_bias, min_cos)


@njit(cache=True, nogil=True, error_model="numpy")
def render_rows_refine(row_lo, row_hi, row_step, R, t, fx, fy, cx, cy, ss, adaptive, room_lo, room_hi,
                       box_lo, box_hi, box_px, tex_data, tex_meta, tex_nlev, tex_origin,
                       tex_texel, lod_bias, min_cos, t_min, face, out_img):
    """Serial kernel, pass 2: replace a pixel by the mean of ss x ss sub-pixel samples (each
    filtered over its own footprint) - every pixel, or with ``adaptive`` only pixels whose 3x3
    neighbourhood sees more than one face (geometric edges; textures are already band-limited
    by the mip-maps)."""
    height, width = out_img.shape
    inv_ss = 1.0 / ss
    sample_px = 1.0 / (0.5 * (fx + fy) * ss)
    ox, oy, oz = t[0], t[1], t[2]
    for v in range(row_lo, row_hi, row_step):
        for u in range(width):
            if adaptive:
                f0 = face[v, u]
                edge = False
                for nv in range(max(v - 1, 0), min(v + 2, height)):
                    for nu in range(max(u - 1, 0), min(u + 2, width)):
                        if face[nv, nu] != f0:
                            edge = True
                if not edge:
                    continue
            acc = 0.0
            for sy in range(ss):
                py_ = v - 0.5 + (sy + 0.5) * inv_ss
                ys = (py_ - cy) / fy
                for sx in range(ss):
                    px_ = u - 0.5 + (sx + 0.5) * inv_ss
                    dx, dy, dz = _pixel_ray(R, (px_ - cx) / fx, ys)
                    th, fh = cast_ray(ox, oy, oz, dx, dy, dz, room_lo, room_hi, box_lo, box_hi,
                                      t_min, px_, py_, box_px)
                    if fh < 0:
                        continue
                    acc += shade_hit(ox + th * dx, oy + th * dy, oz + th * dz, dx, dy, dz, fh,
                                     th, sample_px, tex_data, tex_meta, tex_nlev, tex_origin,
                                     tex_texel, lod_bias, min_cos)
            out_img[v, u] = acc * inv_ss * inv_ss


@njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def render_image(R, t, fx, fy, cx, cy, ss, adaptive, room_lo, room_hi, box_lo, box_hi, box_px,
                 tex_data, tex_meta, tex_nlev, tex_origin, tex_texel, lod_bias, min_cos, t_min,
                 n_bands, out_img, out_depth, out_face):
    """prange driver over ``n_bands`` interleaved row sets. ``R, t``: T_world_cam; outputs are written in place:
    ``out_img`` (H, W) float32 anti-aliased intensity, ``out_depth`` z-depth (m) of the
    pixel-centre ray (0 if nothing is hit), ``out_face`` the face index of that ray (-1: none).
    ``ss`` > 1 supersamples every pixel, or only geometric edges when ``adaptive``."""
    height = out_img.shape[0]
    # band k renders rows k, k + n_bands, ...: interleaved, so every thread gets a fair share of
    # expensive (floor, boxes) and cheap rows under prange's static scheduling
    for k in prange(n_bands):
        render_rows_centre(k, height, n_bands, R, t, fx, fy, cx, cy, room_lo, room_hi, box_lo,
                           box_hi, box_px, tex_data, tex_meta, tex_nlev, tex_origin, tex_texel,
                           lod_bias, min_cos, t_min, out_img, out_depth, out_face)
    if ss > 1:
        for k in prange(n_bands):
            render_rows_refine(k, height, n_bands, R, t, fx, fy, cx, cy, ss, adaptive, room_lo,
                               room_hi, box_lo, box_hi, box_px, tex_data, tex_meta, tex_nlev,
                               tex_origin, tex_texel, lod_bias, min_cos, t_min, out_face,
                               out_img)


def warmup() -> None:
    """Compile (and cache) the kernels on a tiny scene."""
    room_lo = np.array([-1.0, -1.0, 0.0])
    room_hi = np.array([1.0, 1.0, 2.0])
    box_lo = np.array([[-0.2, -0.2, 0.0]])
    box_hi = np.array([[0.2, 0.2, 0.3]])
    n_faces = 12
    tex_data = np.arange(16, dtype=np.float32)
    tex_meta = np.zeros((n_faces, 2, 3), dtype=np.int64)
    tex_meta[:, 0] = (0, 4, 4)
    tex_meta[:, 1] = (0, 2, 2)
    tex_nlev = np.full(n_faces, 2, dtype=np.int64)
    tex_origin = np.zeros((n_faces, 2))
    tex_texel = np.full(n_faces, 0.5)
    R = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    t = np.array([0.0, -0.8, 1.0])
    img = np.zeros((4, 6), np.float32)
    depth = np.zeros((4, 6), np.float32)
    face = np.zeros((4, 6), np.int32)
    box_px = np.array([[-np.inf, np.inf, -np.inf, np.inf]])
    render_image(R, t, 5.0, 5.0, 2.5, 1.5, 2, True, room_lo, room_hi, box_lo, box_hi, box_px, tex_data,
                 tex_meta, tex_nlev, tex_origin, tex_texel, 0.0, 0.1, 1e-6, 2, img, depth, face)
