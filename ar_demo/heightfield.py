"""The persistent AR world: a gravity-aligned height field over the ground plane, fused over keyframes.

The paper's collision mesh covers the current view only; its stated future work is merged geometry.
Here every keyframe of the VO (:class:`lite_vo.keyframes.KeyframeStore`) contributes its in-painted
inverse depth (thesis eq. 5.6, on a ``fuse_grid`` grid, only near cells that had map data) as points
in the physics frame (z up, ground plane at z = 0). Each point votes in the cell of a square grid
centred on the physics origin:

* **floor** when its height is within ``floor_band`` of the ground plane;
* **obstacle** when it lies between ``obstacle_step`` and ``obstacle_top`` above it (walls, furniture;
  points higher up, e.g. the ceiling, say nothing about what stands on the floor).

A cell is an obstacle when it has at least ``min_obstacle_votes`` obstacle votes making at least
``obstacle_share`` of its votes, floor when it has ``min_floor_votes`` floor votes and is no obstacle,
else unknown. Floor grows by ``floor_margin`` cells into unknown ones. The fusion is a pure function
of the keyframes (recomputed from the cached per-keyframe points at each rebuild), so a surface
seen once stays as long as its keyframe does, re-observations add votes, corrected keyframe poses
move their points and thinned keyframes drop out.

**Local floor height**: the ground plane is estimated once, but the camera pose drifts against it
(ICL: the fused floor is 3-4 cm off late in the run), so a car on the plane sinks into the floor the
camera sees. Each floor cell therefore gets the mean height of its floor votes, blended over the
keyframes from old to new with weight ``floor_height_recency`` for the newer ones (the newest agree
best with the current camera) and smoothed over ``floor_smooth`` cells (drift is smooth; single-cell
noise would be bumps the car gets stuck on).

For pybullet the field becomes heights: floor cells their local floor height (within the floor
band), obstacles and unknown cells a wall (the car never
drives where nothing was seen), the outer ring a wall, and one border cell pinned to the lowest height
so that every replacement has the same height range (pybullet centres a height field on
(min + max) / 2 and keeps the first bounds on an in-place replacement).

Imports: numpy, OpenCV (box filter, lazily), lite_vo (camera, geometry), ar_demo (inpaint, ground).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lite_vo.geometry import transform_points

from .inpaint import inpaint, reduce_idepth

UNKNOWN, FLOOR, OBSTACLE = 0, 1, 2


@dataclass(frozen=True)
class FieldSpec:
    """Geometry of the grid (physics units): ``n x n`` cells of size ``cell`` centred on the origin."""
    n: int
    cell: float
    wall: float          # height of obstacles / unknown cells
    low: float           # the pinned lowest height (below the floor)

    def index(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ix, iy, inside) of physics-frame points (N, 2+)."""
        xy = np.asarray(xy, dtype=np.float64)
        f = xy[..., :2] / self.cell + self.n / 2.0
        ix = np.floor(f[..., 0]).astype(np.int64)
        iy = np.floor(f[..., 1]).astype(np.int64)
        inside = (ix >= 0) & (ix < self.n) & (iy >= 0) & (iy < self.n)
        return ix, iy, inside

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        c = (np.arange(self.n) + 0.5 - self.n / 2.0) * self.cell
        return np.meshgrid(c, c, indexing="ij")


@dataclass
class HeightField:
    """A fused world: per-cell ``state`` (UNKNOWN/FLOOR/OBSTACLE), votes and obstacle heights."""
    spec: FieldSpec
    state: np.ndarray            # (n, n) int8, indexed [ix, iy]
    floor_votes: np.ndarray
    obstacle_votes: np.ndarray
    obstacle_height: np.ndarray  # mean obstacle height per cell (physics units), 0 elsewhere
    keyframes: int = 0
    floor_height: np.ndarray | None = None   # floor cells: the fused local floor height (physics units)

    def at(self, xy) -> np.ndarray:
        """States at physics-frame points (UNKNOWN outside the grid)."""
        ix, iy, inside = self.spec.index(np.atleast_2d(xy))
        out = np.full(len(ix), UNKNOWN, np.int8)
        out[inside] = self.state[ix[inside], iy[inside]]
        return out

    def free_disc(self, xy, radius: float) -> bool:
        """All cells within ``radius`` of ``xy`` are floor."""
        r = np.arange(-radius, radius + 1e-9, self.spec.cell * 0.5)
        gx, gy = np.meshgrid(r, r)
        m = gx ** 2 + gy ** 2 <= radius ** 2
        pts = np.stack([gx[m] + xy[0], gy[m] + xy[1]], 1)
        return bool(np.all(self.at(pts) == FLOOR))

    def heights(self, upsample: int = 1) -> np.ndarray:
        """Physics heights (k n, k n) for pybullet, ``k = upsample`` vertices per cell and side (vertex
        spacing ``cell / k``): floor cells their fused floor height (within the floor band), everything
        else a wall, fixed range. pybullet interpolates linearly between vertices, so a wall is a ramp
        ``cell / k`` wide: with ``k = 2`` a wheel meets a steep face instead of climbing a slope and
        rolling the car over."""
        s = self.spec
        fh = 0.0 if self.floor_height is None else np.clip(self.floor_height, s.low, -s.low)
        h = np.where(self.state == FLOOR, fh, s.wall)
        if upsample > 1:
            h = np.repeat(np.repeat(h, upsample, axis=0), upsample, axis=1)
        h[0, :] = h[-1, :] = h[:, 0] = h[:, -1] = s.wall
        h[0, 0] = s.low
        return h

    def extent(self, to_world: float = 1.0) -> dict:
        """Seen floor / obstacles: cell counts, areas and the bounding box of the known cells on the
        ground plane, in world units (``to_world``: world units per physics unit)."""
        known = self.state != UNKNOWN
        cell = self.spec.cell * to_world
        out = {"floor_cells": int(np.sum(self.state == FLOOR)), "obstacle_cells": int(np.sum(self.state == OBSTACLE)),
               "cell": cell, "floor_area": float(np.sum(self.state == FLOOR) * cell ** 2),
               "keyframes": self.keyframes}
        if known.any():
            X, Y = self.spec.centres()
            out["bbox_on_ground_plane"] = [float(v * to_world) for v in
                                           (X[known].min(), Y[known].min(), X[known].max(), Y[known].max())]
        return out


def keyframe_points(idepth, idepth_var, camera, T_world_cam, ground, cfg) -> np.ndarray:
    """World points (N, 3) of a keyframe's in-painted inverse depth on the ``fuse_grid`` grid, at the
    cells with map data or next to one, skipping depth discontinuities (occluding edges)."""
    gi = camera.scaled(cfg.fuse_grid_width, cfg.fuse_grid_height)
    prior = ground.idepth_grid(T_world_cam, gi)
    D, V, _ = reduce_idepth(idepth, idepth_var, prior.shape)
    if not np.any(np.isfinite(D)):
        return np.zeros((0, 3))
    res = inpaint(D, V, prior, cfg.alpha, cfg.huber_delta, cfg.ground_var, cfg.min_var, cfg.solver_iterations,
                  cfg.solver_tol)
    u_id = res.idepth
    near = res.data_mask.copy()
    for _ in range(cfg.fuse_data_dilate):
        g = near.copy()
        g[1:] |= near[:-1]
        g[:-1] |= near[1:]
        g[:, 1:] |= near[:, :-1]
        g[:, :-1] |= near[:, 1:]
        near = g
    pos = np.where(u_id > 0, u_id, np.nan)
    ratio = np.ones_like(pos)
    for a, b in ((pos[1:], pos[:-1]), (pos[:, 1:], pos[:, :-1])):
        r = np.fmax(a / b, b / a)
        if a.shape[0] != pos.shape[0]:
            ratio[1:] = np.fmax(ratio[1:], r)
            ratio[:-1] = np.fmax(ratio[:-1], r)
        else:
            ratio[:, 1:] = np.fmax(ratio[:, 1:], r)
            ratio[:, :-1] = np.fmax(ratio[:, :-1], r)
    ok = near & np.isfinite(pos) & (ratio <= cfg.fuse_max_depth_ratio)
    v, u = np.nonzero(ok)
    return transform_points(np.asarray(T_world_cam, dtype=np.float64), gi.unproject_idepth(u, v, pos[v, u]))


class WorldFusion:
    """Keeps the per-keyframe points (a cache keyed by keyframe index and pose) and fuses them into a
    :class:`HeightField`. Used by one thread (the world-model worker)."""

    def __init__(self, cfg, ground, frame, spec: FieldSpec, car_length_phys: float) -> None:
        self.cfg, self.ground, self.frame, self.spec = cfg, ground, frame, spec
        self.car = car_length_phys
        self._cache: dict = {}

    def _points(self, kf) -> np.ndarray:
        key = (kf.index, kf.T_world_cam.tobytes())
        pts = self._cache.get(key)
        if pts is None:
            pts = self.frame.to_phys(keyframe_points(kf.idepth, kf.idepth_var, kf.camera, kf.T_world_cam,
                                                     self.ground, self.cfg))
            self._cache[key] = pts
        return pts

    def fuse(self, keyframes, extra=()) -> HeightField:
        """The height field of ``keyframes`` (objects with index, T_world_cam, camera, idepth,
        idepth_var) plus ``extra`` maps (points not cached, e.g. the newest map)."""
        keys = set()
        sets = []
        for kf in sorted(keyframes, key=lambda k: k.index):
            sets.append(self._points(kf))
            keys.add((kf.index, kf.T_world_cam.tobytes()))
        for key in list(self._cache):
            if key not in keys:
                del self._cache[key]
        for m in extra:
            sets.append(self.frame.to_phys(keyframe_points(m.idepth, m.idepth_var, m.camera, m.T_world_cam,
                                                           self.ground, self.cfg)))
        P = np.concatenate(sets) if sets else np.zeros((0, 3))
        source = np.repeat(np.arange(len(sets)), [len(p) for p in sets])
        return fuse_points(P, self.spec, self.cfg, self.car, keyframes=len(sets), source=source)


def _cell_means(key: np.ndarray, z: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Per flat key in ``[0, size)``: (count, mean of ``z``)."""
    cnt = np.bincount(key, minlength=size).astype(np.float64)
    tot = np.bincount(key, weights=z, minlength=size)
    return cnt, np.where(cnt > 0, tot / np.maximum(cnt, 1.0), 0.0)


def fuse_points(P: np.ndarray, spec: FieldSpec, cfg, car_length: float, keyframes: int = 0,
                source: np.ndarray | None = None) -> HeightField:
    """Classify the cells from physics-frame points (see the module docstring). ``source``: per point,
    the keyframe it comes from, oldest first (default: every point its own keyframe)."""
    n = spec.n
    ix, iy, inside = spec.index(P)
    z = P[:, 2] if len(P) else np.zeros(0)
    src = np.arange(len(z)) if source is None else np.asarray(source, dtype=np.int64)
    band = cfg.floor_band * car_length
    floor = inside & (np.abs(z) <= band)
    obst = inside & (z > cfg.obstacle_step * car_length) & (z <= cfg.obstacle_top * car_length)
    cell = np.where(inside, ix * n + iy, 0)
    fv, _ = _cell_means(cell[floor], z[floor], n * n)
    ov, oh = _cell_means(cell[obst], z[obst], n * n)
    fv, ov, oh = fv.reshape(n, n), ov.reshape(n, n), oh.reshape(n, n)
    is_obst = (ov >= cfg.min_obstacle_votes) & (ov >= cfg.obstacle_share * (ov + fv))
    is_floor = (fv >= cfg.min_floor_votes) & ~is_obst
    state = np.where(is_obst, OBSTACLE, np.where(is_floor, FLOOR, UNKNOWN)).astype(np.int8)
    floor_h = _smooth(_floor_heights(cell[floor], z[floor], src[floor], n, cfg.floor_height_recency), fv > 0,
                      cfg.floor_smooth)
    for _ in range(cfg.floor_margin):
        f = state == FLOOR
        g = f.copy()
        g[1:] |= f[:-1]
        g[:-1] |= f[1:]
        g[:, 1:] |= f[:, :-1]
        g[:, :-1] |= f[:, 1:]
        new = g & (state == UNKNOWN)
        floor_h[new] = _neighbour_mean(floor_h, f)[new]
        state[new] = FLOOR
    return HeightField(spec, state, fv, ov, oh, keyframes, np.where(state == FLOOR, floor_h, 0.0))


def _floor_heights(cell: np.ndarray, z: np.ndarray, src: np.ndarray, n: int, recency: float) -> np.ndarray:
    """Per-cell floor height: the keyframes' mean floor-vote heights, blended oldest to newest with
    weight ``recency`` for the newer one (1: the newest keyframe that saw the cell decides). The camera
    pose drifts against the ground plane: the newest keyframes agree best with the current camera."""
    h = np.zeros(n * n)
    seen = np.zeros(n * n, bool)
    if len(z) == 0:
        return h.reshape(n, n)
    order = np.argsort(src, kind="stable")
    cell, z, src = cell[order], z[order], src[order]
    bounds = np.flatnonzero(np.diff(src)) + 1
    for c, zz in zip(np.split(cell, bounds), np.split(z, bounds)):
        cnt, mean = _cell_means(c, zz, n * n)
        m = cnt > 0
        h[m] = np.where(seen[m], (1.0 - recency) * h[m] + recency * mean[m], mean[m])
        seen |= m
    return h.reshape(n, n)


def _smooth(h: np.ndarray, mask: np.ndarray, size: int) -> np.ndarray:
    """Mean of ``h`` over the cells of ``mask`` in a ``size`` x ``size`` window (normalised box filter):
    the drift of the floor is smooth, the noise of single cells would be bumps for the car."""
    if size <= 1:
        return h
    import cv2
    w = mask.astype(np.float64)
    num = cv2.blur(h * w, (size, size), borderType=cv2.BORDER_CONSTANT)
    den = cv2.blur(w, (size, size), borderType=cv2.BORDER_CONSTANT)
    return np.where(den > 0, num / np.maximum(den, 1e-12), 0.0)


def _neighbour_mean(h: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Mean of ``h`` over the 4-neighbours inside ``mask`` (0 where there is none)."""
    tot = np.zeros_like(h)
    cnt = np.zeros_like(h)
    for sl_to, sl_from in (((slice(1, None),), (slice(None, -1),)), ((slice(None, -1),), (slice(1, None),)),
                           ((slice(None), slice(1, None)), (slice(None), slice(None, -1))),
                           ((slice(None), slice(None, -1)), (slice(None), slice(1, None)))):
        tot[sl_to] += np.where(mask[sl_from], h[sl_from], 0.0)
        cnt[sl_to] += mask[sl_from]
    return np.where(cnt > 0, tot / np.maximum(cnt, 1.0), 0.0)


def field_mesh(field: HeightField, frame) -> tuple[np.ndarray, np.ndarray]:
    """World-frame triangles of the known cells (for the video panel): floor cells as flat squares,
    obstacle cells as boxes of their mean observed height."""
    spec = field.spec
    X, Y = spec.centres()
    h = spec.cell / 2
    verts, faces = [], []
    top = {FLOOR: np.zeros_like(X), OBSTACLE: np.maximum(field.obstacle_height, spec.cell)}
    for kind in (FLOOR, OBSTACLE):
        m = field.state == kind
        if not m.any():
            continue
        x, y, z = X[m], Y[m], top[kind][m]
        base = len(verts) and sum(len(v) for v in verts)
        corners = np.stack([np.stack([x - h, y - h, z], 1), np.stack([x + h, y - h, z], 1),
                            np.stack([x + h, y + h, z], 1), np.stack([x - h, y + h, z], 1)], 1)   # (k, 4, 3)
        k = len(x)
        idx = base + 4 * np.arange(k)[:, None]
        quads = [corners]
        f = [np.concatenate([idx + [0, 1, 2], idx + [0, 2, 3]])]
        if kind == OBSTACLE:
            bottom = corners.copy()
            bottom[..., 2] = 0.0
            quads.append(bottom)
            b = idx + 4 * k
            for a0, a1 in ((0, 1), (1, 2), (2, 3), (3, 0)):
                f.append(np.concatenate([np.stack([idx[:, 0] + a0, b[:, 0] + a0, b[:, 0] + a1], 1),
                                         np.stack([idx[:, 0] + a0, b[:, 0] + a1, idx[:, 0] + a1], 1)]))
        verts.append(np.concatenate(quads).reshape(-1, 3))
        faces.append(np.concatenate(f))
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int32)
    return frame.to_world(np.concatenate(verts)), np.concatenate(faces).astype(np.int32)
