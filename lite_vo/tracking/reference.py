"""TrackingReference: the immutable per-level point arrays tracking aligns against.

Built once per map update (by the mapping thread, or by the system in ``--depth images`` mode) and
then only read, by the tracking thread: every array is set read-only. Imports numpy, the camera
intrinsics, :mod:`lite_vo.image` and the tracking kernels' layout constants only.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..camera import PinholeIntrinsics
from ..image import gaussian_blur, idepth_pyramid
from ._kernels import PTS_COLS, extract_points
from .config import TrackingConfig


def _ro(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.flags.writeable = False
    return a


@functools.lru_cache(maxsize=16)
def _stride_mask(shape: tuple, stride: int) -> np.ndarray:
    """``(x + y) % stride == 0`` over an image of ``shape`` (read-only; made once per shape and stride:
    a map is published at every mapping iteration)."""
    yy, xx = np.indices(shape)
    return _ro((xx + yy) % stride == 0)


@dataclass(frozen=True)
class ReferenceLevel:
    """Valid points of one pyramid level, flat contiguous read-only arrays of length N.

    ``x, y``: pixel coordinates at this level (float32, pixel centres at integers);
    ``intensity``: reference image value (after the reference's ``smooth_sigma`` blur); ``idepth``, ``idepth_var``: from the depth pyramid;
    ``points``: (N, 5) float32 packed ``[X, Y, Z, intensity, idepth_var]`` with ``(X, Y, Z)`` the
    point in the reference camera (``Z = 1/idepth``), the layout the tracking kernel reads.
    """
    lvl: int
    intrinsics: PinholeIntrinsics
    x: np.ndarray
    y: np.ndarray
    intensity: np.ndarray
    idepth: np.ndarray
    idepth_var: np.ndarray
    points: np.ndarray

    @property
    def num_points(self) -> int:
        return int(self.x.shape[0])

    @property
    def num_pixels(self) -> int:
        return int(self.intrinsics.width * self.intrinsics.height)


class TrackingReference:
    """A keyframe-like reference: per-level point arrays built from an image pyramid and its inverse-depth pyramid.

    Immutable after :meth:`build` (arrays read-only); safe to share between the tracking and the
    mapping thread, swapped as a whole under the system's lock.
    """

    __slots__ = ("frame_id", "intrinsics0", "levels", "smooth_sigma", "_frozen")

    def __init__(self, frame_id, intrinsics0, levels, smooth_sigma=0.0):
        self.frame_id = frame_id
        self.smooth_sigma = float(smooth_sigma)
        self.intrinsics0 = intrinsics0
        self.levels = tuple(levels)
        self._frozen = True

    def __setattr__(self, name, value):
        if getattr(self, "_frozen", False):
            raise AttributeError("TrackingReference is immutable")
        object.__setattr__(self, name, value)

    def __repr__(self) -> str:
        counts = ", ".join(str(lv.num_points) for lv in self.levels)
        return f"TrackingReference(frame_id={self.frame_id!r}, points per level=[{counts}])"

    @property
    def num_levels(self) -> int:
        return len(self.levels)

    def num_points(self, lvl: int) -> int:
        return self.levels[lvl].num_points if 0 <= lvl < len(self.levels) else 0

    @classmethod
    def build(cls, image_pyr, idepth, idepth_var, valid, intrinsics0: PinholeIntrinsics,
              frame_id=0, smooth_sigma: float | None = None, min_level: int = 0,
              point_stride: int = 1, coarse_point_stride: int = 1) -> "TrackingReference":
        """Build from the reference image pyramid and its level-0 inverse-depth map.

        ``image_pyr``: list of float32 images (level 0 = mapping resolution, as from
        :func:`lite_vo.image.image_pyramid`); ``idepth``, ``idepth_var``: HxW float (level 0);
        ``valid``: HxW bool. Pixels with non-finite values, ``idepth <= 0`` or ``idepth_var <= 0``
        are treated as invalid. The depth pyramid (eq. 5.2/5.3) gets as many levels as ``image_pyr``.
        ``smooth_sigma``: Gaussian blur of each level before its intensities are sampled (None: the
        ``TrackingConfig`` default; pass ``config.tracking.smooth_sigma`` when it is overridden). The
        tracker blurs new images with the reference's ``smooth_sigma``, so both always match.
        ``min_level``: levels below it get no points (pass the profile's ``track_level``: the phone
        profile never tracks on level 0, and skipping it halves the build time).
        ``point_stride``: on level ``min_level`` keep only the pixels with ``(x + y) % point_stride == 0``
        (2: a checkerboard; thin edges keep every other pixel in any direction).
        ``coarse_point_stride``: the same on level ``min_level + 1`` (that level only has to bring the pose
        into the finest level's basin).
        """
        if smooth_sigma is None:
            smooth_sigma = TrackingConfig().smooth_sigma
        n_lvl = len(image_pyr)
        if n_lvl < 1:
            raise ValueError("image_pyr is empty")
        img0 = np.asarray(image_pyr[0])
        if img0.shape != (intrinsics0.height, intrinsics0.width):
            raise ValueError(f"image level 0 has shape {img0.shape}, intrinsics say "
                             f"{(intrinsics0.height, intrinsics0.width)}")
        if np.shape(idepth) != img0.shape:
            raise ValueError(f"idepth has shape {np.shape(idepth)}, image level 0 has {img0.shape}")
        ds, vs, ms = idepth_pyramid(idepth, idepth_var, valid, n_lvl)
        levels = []
        for lvl in range(n_lvl):
            img = np.ascontiguousarray(image_pyr[lvl], dtype=np.float32)
            if img.shape != ms[lvl].shape:
                raise ValueError(f"image level {lvl} has shape {img.shape}, expected {ms[lvl].shape}")
            intr = intrinsics0.level(lvl)
            mask = ms[lvl]
            stride = point_stride if lvl == min_level else coarse_point_stride if lvl == min_level + 1 else 1
            if stride > 1:
                mask = mask & _stride_mask(mask.shape, stride)
            n = int(np.count_nonzero(mask)) if lvl >= min_level else 0
            pts = np.empty((n, PTS_COLS), np.float32)
            xs = np.empty(n, np.float32)
            ys = np.empty(n, np.float32)
            if n:
                src = gaussian_blur(img, smooth_sigma) if smooth_sigma > 0 else img
                extract_points(mask, ds[lvl], vs[lvl], src, np.array([intr.fx, intr.fy, intr.cx, intr.cy]), pts, xs, ys)
            levels.append(ReferenceLevel(
                lvl=lvl, intrinsics=intr, x=_ro(xs), y=_ro(ys), intensity=_ro(pts[:, 3].copy()),
                idepth=_ro(1.0 / pts[:, 2]), idepth_var=_ro(pts[:, 4].copy()), points=_ro(pts)))
        return cls(frame_id, intrinsics0, levels, smooth_sigma)
