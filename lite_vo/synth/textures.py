"""Procedural face textures (seeded, physical scales in metres) and their mip-map packing.

A texture mixes smooth value-noise octaves (0.5 m .. 2 cm), painted rectangles, ellipses and
line segments with slightly softened edges (anti-aliased drawing + a one-texel Gaussian), so
both blobs and edges exist at several scales. Nothing is periodic. Imports numpy and cv2 only.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

NOISE_OCTAVES_M = ((0.6, 28.0), (0.2, 20.0), (0.07, 12.0), (0.025, 7.0))
"""(cell size in metres, amplitude in grey levels) of the value-noise octaves."""


def _value_noise(rng: np.random.Generator, w: int, h: int, texel_m: float, cell_m: float
                 ) -> np.ndarray:
    """Smooth noise of unit std-ish with features of ``cell_m`` metres (bicubic upsampling)."""
    gw = max(2, int(math.ceil(w * texel_m / cell_m)) + 1)
    gh = max(2, int(math.ceil(h * texel_m / cell_m)) + 1)
    grid = rng.standard_normal((gh, gw)).astype(np.float32)
    return cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)


def face_texture(rng: np.random.Generator, width_m: float, height_m: float, texel_m: float,
                 base: float, contrast: float = 1.0, shapes_per_m2: float = 25.0,
                 feature_scale: float = 1.0) -> np.ndarray:
    """A float32 (h, w) texture of a ``width_m`` x ``height_m`` face, grey levels ~ 0..255.

    ``feature_scale`` multiplies every physical feature size (noise cells, shapes; the shape
    density scales with its inverse square): < 1 for close-range scenes."""
    w = max(2, int(math.ceil(width_m / texel_m)))
    h = max(2, int(math.ceil(height_m / texel_m)))
    img = np.full((h, w), base, dtype=np.float32)
    fs = float(feature_scale)
    for cell_m, amp in NOISE_OCTAVES_M[:2]:
        img += (amp * contrast) * _value_noise(rng, w, h, texel_m, cell_m * fs)
    area = width_m * height_m
    n_shapes = int(rng.poisson(shapes_per_m2 * area / fs ** 2)) + (1 if area > 0.02 * fs else 0)
    shift = 4  # cv2 sub-pixel drawing with 1/16 texel precision
    scale = (1 << shift) / texel_m
    extent = min(max(width_m, height_m), 0.6 * fs)
    for _ in range(n_shapes):
        kind = rng.integers(0, 3)
        size = math.exp(rng.uniform(math.log(0.02 * fs), math.log(max(0.03 * fs, extent * 0.7))))
        cx, cy = rng.uniform(0, width_m), rng.uniform(0, height_m)
        value = float(rng.uniform(15.0, 240.0))
        alpha = float(rng.uniform(0.45, 1.0))
        # work on the shape's bounding box only (texel ROI), coordinates relative to it
        r_tx = size / texel_m + 4
        x0, x1 = max(0, int(cx / texel_m - r_tx)), min(w, int(cx / texel_m + r_tx) + 1)
        y0, y1 = max(0, int(cy / texel_m - r_tx)), min(h, int(cy / texel_m + r_tx) + 1)
        if x1 <= x0 or y1 <= y0:
            continue
        roi = img[y0:y1, x0:x1]
        layer = roi.copy()
        cxr, cyr = cx - x0 * texel_m, cy - y0 * texel_m
        if kind == 0:  # (rotated) rectangle
            ang = rng.uniform(0, math.pi) if rng.random() < 0.4 else 0.0
            a = size * rng.uniform(0.3, 1.0)
            b = size * rng.uniform(0.3, 1.0)
            corners = np.array([[-a, -b], [a, -b], [a, b], [-a, b]]) * 0.5
            c, s = math.cos(ang), math.sin(ang)
            pts = corners @ np.array([[c, s], [-s, c]]) + (cxr, cyr)
            cv2.fillPoly(layer, [np.round(pts * scale).astype(np.int32)], value,
                         lineType=cv2.LINE_AA, shift=shift)
        elif kind == 1:  # ellipse (blob)
            axes = (int(size * 0.5 * scale), int(size * rng.uniform(0.2, 0.5) * scale))
            cv2.ellipse(layer, (int(cxr * scale), int(cyr * scale)), axes,
                        float(rng.uniform(0, 180)), 0, 360, value, -1, cv2.LINE_AA, shift)
        else:  # line segment (edge-like)
            ang = rng.uniform(0, math.pi)
            dx, dy = math.cos(ang) * size * 0.5, math.sin(ang) * size * 0.5
            thick = max(1, int(round(rng.uniform(0.004, 0.02) * fs / texel_m)))
            cv2.line(layer, (int((cxr - dx) * scale), int((cyr - dy) * scale)),
                     (int((cxr + dx) * scale), int((cyr + dy) * scale)), value, thick,
                     cv2.LINE_AA, shift)
        roi[...] = alpha * layer + (1.0 - alpha) * roi
    for cell_m, amp in NOISE_OCTAVES_M[2:]:
        img += (amp * contrast) * _value_noise(rng, w, h, texel_m, cell_m * fs)
    img = cv2.GaussianBlur(img, (0, 0), 1.0)
    return np.clip(img, 5.0, 250.0).astype(np.float32)


def mip_levels(tex: np.ndarray) -> list[np.ndarray]:
    """Mip pyramid: each level is the 2x2 box average of the previous (edge-replicated when odd)."""
    levels = [np.ascontiguousarray(tex, dtype=np.float32)]
    while min(levels[-1].shape) > 1:
        t = levels[-1]
        h, w = t.shape
        if h % 2 or w % 2:
            t = np.pad(t, ((0, h % 2), (0, w % 2)), mode="edge")
        levels.append(0.25 * (t[0::2, 0::2] + t[1::2, 0::2] + t[0::2, 1::2] + t[1::2, 1::2]))
    return levels


def pack_textures(textures: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flat storage of all faces' mip pyramids: ``(data (N,) float32, meta (F, L, 3) int64
    [offset, w, h], nlev (F,) int64)``."""
    pyramids = [mip_levels(t) for t in textures]
    n_lev = max(len(p) for p in pyramids)
    meta = np.zeros((len(textures), n_lev, 3), dtype=np.int64)
    nlev = np.array([len(p) for p in pyramids], dtype=np.int64)
    total = sum(lvl.size for p in pyramids for lvl in p)
    data = np.empty(total, dtype=np.float32)
    off = 0
    for f, pyr in enumerate(pyramids):
        for lvl_i, lvl in enumerate(pyr):
            h, w = lvl.shape
            data[off:off + lvl.size] = lvl.ravel()
            meta[f, lvl_i] = (off, w, h)
            off += lvl.size
    return data, meta, nlev
