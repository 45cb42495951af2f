"""Slow, obviously-correct reference versions of the synth kernels (lite_vo/synth/_kernels.py).

Pure Python/numpy, one ray at a time, no culling. Used by tests/test_synth.py only.
"""
from __future__ import annotations

import math

import numpy as np


def naive_cast(o, d, room_lo, room_hi, box_lo, box_hi, t_min=1e-9):
    """Nearest ``(t, face)`` of the ray o + t d: room (from inside) then every box (slab test)."""
    best_t, best_face = math.inf, -1
    for a in range(3):  # leaving the room
        if d[a] > 0:
            t, side = (room_hi[a] - o[a]) / d[a], 1
        elif d[a] < 0:
            t, side = (room_lo[a] - o[a]) / d[a], 0
        else:
            continue
        if t_min < t < best_t:
            best_t, best_face = t, 2 * a + side
    for b in range(len(box_lo)):
        enters, leaves, miss = [], [], False
        for a in range(3):
            lo, hi = box_lo[b][a], box_hi[b][a]
            if d[a] == 0:
                if not lo <= o[a] <= hi:
                    miss = True
                enters.append((-math.inf, a, 0))
                leaves.append(math.inf)
                continue
            t0, t1 = (lo - o[a]) / d[a], (hi - o[a]) / d[a]
            if d[a] > 0:
                enters.append((t0, a, 0))   # entering through the lo face
                leaves.append(t1)
            else:
                enters.append((t1, a, 1))   # entering through the hi face
                leaves.append(t0)
        if miss:
            continue
        t_near = max(e[0] for e in enters)
        axis, side = next((e[1], e[2]) for e in enters if e[0] == t_near)  # first axis wins ties
        if t_near <= min(leaves) and t_min < t_near < best_t:
            best_t, best_face = t_near, 6 + 6 * b + 2 * axis + side
    return best_t, best_face


def _level(scene, face, lvl):
    off, w, h = (int(x) for x in scene.tex_meta[face, lvl])
    return scene.tex_data[off:off + w * h].reshape(h, w).astype(np.float64)


def _bilinear(img, x, y):
    h, w = img.shape
    x = min(max(x, 0.0), w - 1.0)
    y = min(max(y, 0.0), h - 1.0)
    x0 = min(int(math.floor(x)), max(w - 2, 0))
    y0 = min(int(math.floor(y)), max(h - 2, 0))
    x1, y1 = min(x0 + 1, w - 1), min(y0 + 1, h - 1)
    fx, fy = x - x0, y - y0
    top = (1 - fx) * img[y0, x0] + fx * img[y0, x1]
    bot = (1 - fx) * img[y1, x0] + fx * img[y1, x1]
    return (1 - fy) * top + fy * bot


def naive_shade(scene, p, d, face, depth, sample_px, lod_bias=0.0, min_cos=0.1):
    """Trilinear mip-mapped texture value at hit point p (area-based level of detail)."""
    a = (face % 6) // 2
    s_m = p[(a + 1) % 3] - scene.tex_origin[face, 0]
    t_m = p[(a + 2) % 3] - scene.tex_origin[face, 1]
    norm = float(np.linalg.norm(d))
    c = max(abs(d[a]) / norm, min_cos)
    texel = scene.tex_texel[face]
    nlev = int(scene.tex_nlev[face])
    footprint = depth * sample_px * norm / math.sqrt(c)
    lod = min(max(math.log2(max(footprint / texel, 1e-6)) + lod_bias, 0.0), nlev - 1.0)
    l0 = min(int(lod), max(nlev - 2, 0))
    l1 = min(l0 + 1, nlev - 1)
    frac = lod - l0
    vals = []
    for lvl in (l0, l1):
        size = texel * 2 ** lvl
        vals.append(_bilinear(_level(scene, face, lvl), s_m / size - 0.5, t_m / size - 0.5))
    return vals[0] if l1 == l0 else (1 - frac) * vals[0] + frac * vals[1]


def naive_render(scene, T_world_cam, K, ss=1, adaptive=True, lod_bias=0.0, min_cos=0.1):
    """(image, depth, faces) exactly as the kernel defines them, one ray at a time."""
    R, o = T_world_cam[:3, :3], T_world_cam[:3, 3]
    h, w = K.height, K.width
    img = np.zeros((h, w))
    depth = np.zeros((h, w))
    faces = np.full((h, w), -1, np.int64)
    f_mean = 0.5 * (K.fx + K.fy)

    def ray(px, py):
        return R @ np.array([(px - K.cx) / K.fx, (py - K.cy) / K.fy, 1.0])

    for v in range(h):
        for u in range(w):
            d = ray(u, v)
            t, face = naive_cast(o, d, scene.room_lo, scene.room_hi, scene.box_lo, scene.box_hi)
            faces[v, u] = face
            if face >= 0:
                depth[v, u] = t
                img[v, u] = naive_shade(scene, o + t * d, d, face, t, 1.0 / f_mean, lod_bias,
                                        min_cos)
    if ss > 1:
        out = img.copy()
        for v in range(h):
            for u in range(w):
                nb = faces[max(v - 1, 0):v + 2, max(u - 1, 0):u + 2]
                if adaptive and np.all(nb == faces[v, u]):
                    continue
                acc = 0.0
                for sy in range(ss):
                    for sx in range(ss):
                        px = u - 0.5 + (sx + 0.5) / ss
                        py = v - 0.5 + (sy + 0.5) / ss
                        d = ray(px, py)
                        t, face = naive_cast(o, d, scene.room_lo, scene.room_hi, scene.box_lo,
                                             scene.box_hi)
                        if face >= 0:
                            acc += naive_shade(scene, o + t * d, d, face, t, 1.0 / (f_mean * ss),
                                               lod_bias, min_cos)
                out[v, u] = acc / ss ** 2
        img = out
    return img, depth, faces
