"""Public rendering wrapper: validates inputs, allocates outputs, calls the numba ray caster.

``render_frame(scene, T_world_cam, intrinsics)`` is exact geometry (analytic ray/box
intersection) with anti-aliased, mip-mapped textures. Imports numpy, the synth kernels and
:mod:`lite_vo.camera` only (no GL).
"""
from __future__ import annotations

import numpy as np

from ..camera import PinholeIntrinsics
from ..errors import InputError
from . import _kernels
from .config import SynthConfig
from .scenes import Scene

_DEFAULT = SynthConfig()


def default_intrinsics(width: int = 640, height: int = 480,
                       config: SynthConfig | None = None) -> PinholeIntrinsics:
    """The generator's pinhole camera: ``fx = fy = focal_640_px * width / 640``, centred."""
    cfg = config or _DEFAULT
    if width < 2 or height < 2:
        raise InputError(f"synthetic image size {width}x{height} is too small")
    f = cfg.focal_640_px * width / 640.0
    return PinholeIntrinsics(f, f, (width - 1) / 2.0, (height - 1) / 2.0, int(width), int(height))


def box_screen_rects(scene: Scene, T_world_cam: np.ndarray, intrinsics: PinholeIntrinsics,
                     margin_px: float = 2.0, near_m: float = 1e-3) -> np.ndarray:
    """Conservative pixel rectangles (B, 4) ``(u_min, u_max, v_min, v_max)`` of the boxes, for
    culling. A box with a corner behind (or almost at) the camera plane gets an unbounded
    rectangle; a box entirely behind the camera an empty one."""
    n = scene.box_lo.shape[0]
    rects = np.empty((n, 4))
    rects[:] = (-np.inf, np.inf, -np.inf, np.inf)
    if n == 0:
        return rects
    sel = np.array([[i >> k & 1 for k in range(3)] for i in range(8)], bool)  # (8, 3)
    corners = np.where(sel[None], scene.box_hi[:, None, :], scene.box_lo[:, None, :])  # (B,8,3)
    R, t = T_world_cam[:3, :3], T_world_cam[:3, 3]
    pc = (corners - t) @ R  # camera frame: R^T (p - t)
    z = pc[..., 2]
    for b in range(n):
        if np.all(z[b] <= 0.0):
            rects[b] = (np.inf, -np.inf, np.inf, -np.inf)
        elif np.all(z[b] > near_m):
            u = intrinsics.fx * pc[b, :, 0] / z[b] + intrinsics.cx
            v = intrinsics.fy * pc[b, :, 1] / z[b] + intrinsics.cy
            rects[b] = (u.min() - margin_px, u.max() + margin_px,
                        v.min() - margin_px, v.max() + margin_px)
    return rects


def render_frame(scene: Scene, T_world_cam: np.ndarray, intrinsics: PinholeIntrinsics,
                 supersample: int | None = None, config: SynthConfig | None = None,
                 return_faces: bool = False):
    """Render ``scene`` seen by a camera at ``T_world_cam`` (4x4, camera x right, y down, z
    forward).

    Returns ``(image, depth)``: image float32 (H, W) in 0..255 (average of ss x ss samples per
    pixel), depth float32 (H, W) z-depth in metres of the ray through the pixel centre (0 where
    nothing is hit, which cannot happen inside the closed room). With ``return_faces=True`` also
    an int32 (H, W) array of the face index hit by the pixel-centre ray (see
    :meth:`Scene.face_name`).
    """
    cfg = config or _DEFAULT
    ss = int(cfg.supersample if supersample is None else supersample)
    if ss < 1:
        raise InputError(f"supersample must be >= 1, got {ss}")
    T = np.asarray(T_world_cam, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InputError("render_frame: T_world_cam must be a finite 4x4 matrix")
    h, w = int(intrinsics.height), int(intrinsics.width)
    img = np.empty((h, w), np.float32)
    depth = np.empty((h, w), np.float32)
    faces = np.empty((h, w), np.int32)
    R = np.ascontiguousarray(T[:3, :3])
    t = np.ascontiguousarray(T[:3, 3])
    _kernels.render_image(R, t, float(intrinsics.fx), float(intrinsics.fy), float(intrinsics.cx),
                          float(intrinsics.cy), ss, bool(cfg.adaptive_aa), scene.room_lo, scene.room_hi, scene.box_lo,
                          scene.box_hi, box_screen_rects(scene, T, intrinsics), scene.tex_data, scene.tex_meta, scene.tex_nlev,
                          scene.tex_origin, scene.tex_texel, float(cfg.lod_bias),
                          float(cfg.min_cos), 1e-9, min(h, 64), img, depth, faces)
    if return_faces:
        return img, depth, faces
    return img, depth
