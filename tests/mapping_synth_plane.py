"""A tiny textured-plane renderer for the mapping tests (no dependency on lite_vo.synth).

The world plane z = ``plane_z`` carries a smooth random texture; cameras look roughly along +z.
"""
from __future__ import annotations

import cv2
import numpy as np

from lite_vo.camera import PinholeIntrinsics


def make_texture(seed: int = 0, size: int = 1024, cells: int = 96) -> np.ndarray:
    rng = np.random.default_rng(seed)
    coarse = rng.random((cells, cells)).astype(np.float32)
    tex = cv2.resize(coarse, (size, size), interpolation=cv2.INTER_CUBIC)
    tex = (tex - tex.min()) / (tex.max() - tex.min())
    return (20.0 + 215.0 * tex).astype(np.float32)


def render_plane(tex: np.ndarray, T_world_cam: np.ndarray, K: PinholeIntrinsics, plane_z: float = 2.0,
                 tex_m: float = 4.0, normal=(0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """(image float32, depth float32 m) of the plane n.x = plane_z seen from ``T_world_cam``.
    The texture spans ``tex_m`` metres centred on the world origin (x, y)."""
    h, w = K.height, K.width
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    rays = np.stack([(xx - K.cx) / K.fx, (yy - K.cy) / K.fy, np.ones_like(xx)], -1)
    R, c = T_world_cam[:3, :3], T_world_cam[:3, 3]
    d = rays @ R.T
    n = np.asarray(normal, float)
    n = n / np.linalg.norm(n)
    tt = (plane_z - c @ n) / (d @ n)
    P = c + tt[..., None] * d
    size = tex.shape[0]
    mx = ((P[..., 0] / tex_m + 0.5) * size).astype(np.float32)
    my = ((P[..., 1] / tex_m + 0.5) * size).astype(np.float32)
    img = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return img.astype(np.float32), tt.astype(np.float32)
