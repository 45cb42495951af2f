"""Cameras: pinhole intrinsics (per pyramid level), lens distortion, rectification.

:class:`PinholeIntrinsics` is the undistorted camera the whole pipeline works with after
rectification: ``u = fx * x / z + cx`` with pixel centres at integer coordinates.
Pyramid level l+1 halves fx, fy and maps ``c -> (c + 0.5) / 2 - 0.5`` (2x2 box averaging).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PinholeIntrinsics:
    """Undistorted pinhole camera of an image of ``width`` x ``height`` pixels."""
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def level(self, lvl: int) -> "PinholeIntrinsics":
        """Intrinsics of pyramid level ``lvl`` (each level halves the size, 2x2 box average)."""
        fx, fy, cx, cy, w, h = self.fx, self.fy, self.cx, self.cy, self.width, self.height
        for _ in range(lvl):
            fx, fy = fx * 0.5, fy * 0.5
            cx, cy = (cx + 0.5) * 0.5 - 0.5, (cy + 0.5) * 0.5 - 0.5
            w, h = w // 2, h // 2
        return PinholeIntrinsics(fx, fy, cx, cy, w, h)

    def scaled(self, width: int, height: int) -> "PinholeIntrinsics":
        """The same camera resampled to ``width`` x ``height`` (pixel-area convention)."""
        sx, sy = width / self.width, height / self.height
        return PinholeIntrinsics(self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5,
                                 (self.cy + 0.5) * sy - 0.5, int(width), int(height))

    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Pixel coordinates (N, 2) of camera-frame points (N, 3) (z must be > 0)."""
        p = np.asarray(points_cam, dtype=np.float64)
        z = p[:, 2]
        return np.stack([self.fx * p[:, 0] / z + self.cx, self.fy * p[:, 1] / z + self.cy], axis=1)

    def unproject_idepth(self, u: np.ndarray, v: np.ndarray, idepth: np.ndarray) -> np.ndarray:
        """Camera-frame points (N, 3) of pixels (u, v) with inverse depth ``idepth`` (> 0)."""
        u = np.asarray(u, dtype=np.float64)
        v = np.asarray(v, dtype=np.float64)
        z = 1.0 / np.asarray(idepth, dtype=np.float64)
        return np.stack([(u - self.cx) / self.fx * z, (v - self.cy) / self.fy * z, z], axis=-1)
