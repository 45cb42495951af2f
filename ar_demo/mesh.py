"""Collision mesh of the AR world model (thesis 5.3.1): the in-painted inverse-depth grid read as
the corners of a regular triangle grid, unprojected with the frame pose into the world.

Each grid cell ``(y, x)`` is a vertex at the ray through the cell centre (grid intrinsics: the map
camera scaled to the grid size) at depth ``1 / idepth``. Every quad of four neighbouring vertices
gives two triangles; triangles whose corner depths differ by more than ``max_depth_ratio`` span an
occluding edge and are dropped (they would be walls that do not exist). Vertices far away (tiny or
zero inverse depth: sky, horizon) are clamped to ``idepth_floor``.

Imports: numpy, trimesh (export only), lite_vo (camera, errors, geometry) only.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lite_vo.camera import PinholeIntrinsics
from lite_vo.errors import InputError
from lite_vo.geometry import transform_points


@dataclass
class CollisionMesh:
    vertices_world: np.ndarray     # (N, 3) float64
    faces: np.ndarray              # (M, 3) int32
    T_world_cam: np.ndarray        # pose of the frame it was built from
    frame_id: int = -1
    timestamp: float = 0.0

    def to_trimesh(self):
        import trimesh
        return trimesh.Trimesh(vertices=self.vertices_world, faces=self.faces, process=False)

    def export(self, path: str | Path) -> None:
        """Write the mesh as OBJ or PLY (by extension)."""
        path = Path(path)
        if path.suffix.lower() not in (".obj", ".ply"):
            raise InputError(f"{path}: mesh export supports .obj and .ply")
        self.to_trimesh().export(str(path))


def grid_faces(h: int, w: int) -> np.ndarray:
    """All (2 (h-1) (w-1), 3) triangles of a regular h x w vertex grid (row-major vertex ids)."""
    y, x = np.mgrid[0:h - 1, 0:w - 1]
    a = (y * w + x).ravel()
    b, c, d = a + 1, a + w, a + w + 1
    return np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)]).astype(np.int32)


def grid_mesh(idepth_grid: np.ndarray, intrinsics_grid: PinholeIntrinsics, T_world_cam: np.ndarray,
              max_depth_ratio: float = 1.6, idepth_floor: float = 0.0, frame_id: int = -1,
              timestamp: float = 0.0) -> CollisionMesh:
    """Triangle grid mesh of an (h, w) inverse-depth grid in the world frame."""
    u_id = np.asarray(idepth_grid, dtype=np.float64)
    h, w = u_id.shape
    if (intrinsics_grid.height, intrinsics_grid.width) != (h, w):
        raise InputError(f"grid_mesh: intrinsics {intrinsics_grid.width}x{intrinsics_grid.height} "
                         f"do not match the grid {w}x{h}")
    floor = max(float(idepth_floor), 1e-12)
    idepth = np.where(np.isfinite(u_id), np.maximum(u_id, floor), floor)
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    pts = intrinsics_grid.unproject_idepth(u.ravel(), v.ravel(), idepth.ravel())
    T = np.asarray(T_world_cam, dtype=np.float64)
    verts = transform_points(T, pts)
    faces = grid_faces(h, w)
    if max_depth_ratio and max_depth_ratio > 0:
        d = idepth.ravel()[faces]
        keep = d.max(axis=1) <= max_depth_ratio * d.min(axis=1)
        faces = faces[keep]
    return CollisionMesh(verts, faces, T.copy(), frame_id, timestamp)
