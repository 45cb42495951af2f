"""Keyframe history: a bounded, thread-safe store of keyframes, and the whole-scene point cloud.

A :class:`Keyframe` is an immutable snapshot of a published map (pose, grey image, colour image when
the source has colour, converged inverse depth and variance at mapping resolution), stored compactly:
the grey image as it is, the inverse depth and variance only at the pixels that have a hypothesis (a
packed mask and float32 values), the colour image as a JPEG (quality 95: it is only looked at, in the
point cloud and the AR world's textures); the dense arrays are decoded on access (320x240 on ICL: about
0.37 MB instead of 0.92 MB). The
:class:`KeyframeStore` is owned by :class:`~lite_vo.system.VisualOdometry` (which offers it every
published map) and read by everyone else: the whole-scene map (:func:`scene_cloud`, ``map.ply``), the
persistent AR world and, later, relocalisation.

* **When a map becomes a keyframe**: the camera moved more than ``min_translation_rel`` times the map's
  median depth or turned more than ``min_rotation_deg`` since the newest keyframe, or the map has a new
  scale (a new monocular map).
* **Memory bound**: at most ``max_bytes`` of stored (compact) arrays (and ``max_keyframes``). When a new keyframe does not fit,
  keyframes are thinned in this order: those of an older monocular scale (they cannot be fused with the
  current map), then the most *redundant* one (the smallest sum of pose distances to its two nearest keyframes;
  ties: the oldest). The newest keyframe is never removed, so the store keeps covering the whole scene
  rather than only the recent past.
* **Pose corrections** (two-view bootstrap, relocalisation) replace the moved keyframes by copies with
  the corrected pose (``None`` removes a keyframe).

Thread safety: every method takes the store's lock; keyframes are frozen dataclasses with read-only
arrays, so a snapshot (a list) can be used without the lock while the store moves on.

Imports: numpy, OpenCV, lite_vo (camera, geometry) only; the point cloud loads its numba kernels
(:mod:`lite_vo._cloud_kernels`) when it is made.
"""
from __future__ import annotations

import dataclasses
import math
import threading
from dataclasses import dataclass, field

import cv2
import numpy as np

from .camera import PinholeIntrinsics
from .geometry import inverse_se3, transform_points


def _frozen(a: np.ndarray | None, dtype=None) -> np.ndarray | None:
    if a is None:
        return None
    out = np.array(a, dtype=dtype, copy=True)
    out.setflags(write=False)
    return out


def _read_only(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


#: JPEG parameters of the stored colour image: quality 95 without chroma subsampling (colour edges stay
#: sharp). On ICL at 320x240: 35 KB, 0.5 ms to encode, a mean error of 1.3 grey levels (99.9 % of the
#: values within 10); the fastest lossless PNG took 105 KB and 3.8 ms, about 0.9 ms per frame on the
#: `board` profile, where a keyframe is made every 4-5 frames.
_JPEG_PARAMS = (cv2.IMWRITE_JPEG_QUALITY, 95, cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444)


@dataclass(frozen=True, eq=False)
class Keyframe:
    """One keyframe at mapping resolution, stored compactly (see :meth:`make`).

    The public arrays are read-only and exactly those the keyframe was made from: ``image`` (uint8
    (H, W) grey, stored as it is: relocalisation tracks against it), ``idepth`` and ``idepth_var``
    (float32 (H, W), NaN where there is no hypothesis: decoded on access from the hypotheses' pixels and
    values); ``color`` (uint8 (H, W, 3) BGR or None) is the one lossy part, decoded on access from a
    JPEG (quality 95, no chroma subsampling: only looked at, never computed with). ``nbytes``
    is what the keyframe really holds."""
    index: int                     # frame index in the run
    timestamp: float
    T_world_cam: np.ndarray        # (4, 4)
    camera: PinholeIntrinsics      # mapping-resolution intrinsics
    image: np.ndarray              # uint8 (H, W) grey
    valid_bits: np.ndarray         # uint8, np.packbits of the (H, W) mask of the pixels with a hypothesis
    idepth_values: np.ndarray      # float32 (N,): idepth of those pixels, row-major order
    var_values: np.ndarray         # float32 (N,): their idepth variance
    color_jpg: np.ndarray | None = None  # uint8 (bytes) JPEG of the BGR colour image, None for grey sources
    scale_id: int = 0              # maps of different monocular scale have different ids
    median_depth: float = field(default=float("nan"))

    @classmethod
    def make(cls, index, timestamp, T_world_cam, camera, image, idepth, idepth_var, color=None,
             scale_id: int = 0) -> "Keyframe":
        img = np.clip(np.asarray(image, dtype=np.float32) + 0.5, 0, 255).astype(np.uint8) \
            if np.asarray(image).dtype != np.uint8 else image
        d = np.asarray(idepth, dtype=np.float32)
        ok = np.isfinite(d) & (d > 0)
        # the hypotheses' pixels as flat indices, gathered with take: the values of d[ok] in the same
        # order, without numpy's slow 2-D boolean indexing (0.28 ms per array at 320x240 -> 0.03)
        flat = np.flatnonzero(ok)
        d_ok = d.reshape(-1).take(flat)
        med = float(np.median(1.0 / d_ok)) if d_ok.size else float("nan")
        jpg = None
        if color is not None:
            col = np.clip(np.asarray(color, dtype=np.float32) + 0.5, 0, 255).astype(np.uint8) \
                if np.asarray(color).dtype != np.uint8 else np.asarray(color)
            good, buf = cv2.imencode(".jpg", np.ascontiguousarray(col), _JPEG_PARAMS)
            if not good:
                raise ValueError(f"keyframe {index}: the colour image could not be encoded")
            jpg = _frozen(buf.reshape(-1))
        var = np.asarray(idepth_var, dtype=np.float32)
        if var.shape != d.shape:
            raise ValueError(f"keyframe {index}: idepth_var {var.shape} and idepth {d.shape} differ in shape")
        return cls(int(index), float(timestamp), _frozen(T_world_cam, np.float64), camera, _frozen(img),
                   _frozen(np.packbits(ok, axis=None)), _frozen(d_ok), _frozen(var.reshape(-1).take(flat)), jpg,
                   int(scale_id), med)

    @property
    def shape(self) -> tuple[int, int]:
        return self.image.shape

    def valid_flat(self) -> np.ndarray:
        """Row-major indices (N,) of the pixels with a hypothesis (the order of the stored values)."""
        h, w = self.image.shape
        return np.flatnonzero(np.unpackbits(self.valid_bits, count=h * w))

    def _dense(self, values: np.ndarray) -> np.ndarray:
        out = np.full(self.image.shape, np.nan, np.float32)
        out.reshape(-1)[self.valid_flat()] = values
        return _read_only(out)

    @property
    def idepth(self) -> np.ndarray:
        """float32 (H, W) inverse depth, NaN where there is no hypothesis (a new read-only array)."""
        return self._dense(self.idepth_values)

    @property
    def idepth_var(self) -> np.ndarray:
        """float32 (H, W) inverse-depth variance, NaN where there is no hypothesis (a new read-only array)."""
        return self._dense(self.var_values)

    @property
    def color(self) -> np.ndarray | None:
        """uint8 (H, W, 3) BGR colour image (decoded from the stored JPEG), None for grey sources."""
        if self.color_jpg is None:
            return None
        return _read_only(cv2.imdecode(self.color_jpg, cv2.IMREAD_COLOR))

    @property
    def nbytes(self) -> int:
        """Bytes of the stored arrays (the compact form, not the decoded one)."""
        n = (self.image.nbytes + self.valid_bits.nbytes + self.idepth_values.nbytes + self.var_values.nbytes
             + self.T_world_cam.nbytes)
        return n + (self.color_jpg.nbytes if self.color_jpg is not None else 0)

    def with_pose(self, T_world_cam: np.ndarray) -> "Keyframe":
        return dataclasses.replace(self, T_world_cam=_frozen(T_world_cam, np.float64))

    def points(self, max_rel_std: float = np.inf):
        """Camera-frame points (N, 3), their pixels ``(v, u)`` and idepth variance (N,) of the
        hypotheses whose relative depth standard deviation ``sqrt(var) / idepth`` is below ``max_rel_std``."""
        d, var = self.idepth_values, self.var_values
        ok = np.isfinite(var)
        if np.isfinite(max_rel_std):
            ok &= np.sqrt(np.where(ok, var, 0.0)) < max_rel_std * np.where(ok, d, 0.0)
        v, u = np.divmod(self.valid_flat()[ok], self.image.shape[1])
        return self.camera.unproject_idepth(u, v, d[ok]), (v, u), var[ok].astype(np.float64)


def pose_distance(T_a: np.ndarray, T_b: np.ndarray, scene_depth: float) -> float:
    """Translation (in scene depths) plus rotation angle (radians) between two camera poses."""
    dt = float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3])) / max(scene_depth, 1e-12)
    c = (np.trace(T_a[:3, :3].T @ T_b[:3, :3]) - 1.0) / 2.0
    return dt + math.acos(float(np.clip(c, -1.0, 1.0)))


def pose_distances(poses: np.ndarray, scene_depth: float) -> np.ndarray:
    """:func:`pose_distance` of every pair of the poses ``(n, 4, 4)``: an ``(n, n)`` matrix (vectorised:
    the store's thinning compares every pair of up to ``max_keyframes`` keyframes on each add)."""
    t = poses[:, :3, 3]
    dt = np.linalg.norm(t[:, None, :] - t[None, :, :], axis=-1) / max(scene_depth, 1e-12)
    R = poses[:, :3, :3]
    c = (np.einsum("aij,bij->ab", R, R) - 1.0) / 2.0            # trace(R_a^T R_b)
    return dt + np.arccos(np.clip(c, -1.0, 1.0))


class KeyframeStore:
    """Bounded, thread-safe keyframe store (see the module docstring)."""

    def __init__(self, max_bytes: int = 32 * 2**20, max_keyframes: int = 200, min_translation_rel: float = 0.03,
                 min_rotation_deg: float = 3.0) -> None:
        if max_bytes <= 0 or max_keyframes < 1:
            raise ValueError("KeyframeStore: max_bytes and max_keyframes must be positive")
        self.max_bytes = int(max_bytes)
        self.max_keyframes = int(max_keyframes)
        self.min_translation_rel = float(min_translation_rel)
        self.min_rotation_deg = float(min_rotation_deg)
        self._lock = threading.Lock()
        self._kfs: list[Keyframe] = []
        self._version = 0
        self.added = 0
        self.removed = 0

    # ------------------------------------------------------------------ reading
    def snapshot(self) -> list[Keyframe]:
        """The keyframes, oldest first (an immutable snapshot)."""
        with self._lock:
            return list(self._kfs)

    def __iter__(self):
        return iter(self.snapshot())

    def __len__(self) -> int:
        with self._lock:
            return len(self._kfs)

    @property
    def version(self) -> int:
        """Increases with every change (add, removal, correction)."""
        with self._lock:
            return self._version

    @property
    def nbytes(self) -> int:
        with self._lock:
            return sum(k.nbytes for k in self._kfs)

    @property
    def scale_id(self) -> int | None:
        with self._lock:
            return self._kfs[-1].scale_id if self._kfs else None

    def current(self) -> list[Keyframe]:
        """The keyframes of the newest scale (those that can be fused with the current map)."""
        kfs = self.snapshot()
        return [k for k in kfs if k.scale_id == kfs[-1].scale_id] if kfs else []

    # ------------------------------------------------------------------ writing
    def wants(self, T_world_cam: np.ndarray, scale_id: int) -> bool:
        """Whether a map seen from ``T_world_cam`` would become a keyframe (the camera moved enough)."""
        with self._lock:
            last = self._kfs[-1] if self._kfs else None
        if last is None or last.scale_id != scale_id:
            return True
        depth = last.median_depth if np.isfinite(last.median_depth) else 1.0
        T = np.asarray(T_world_cam, dtype=np.float64)
        moved = np.linalg.norm(T[:3, 3] - last.T_world_cam[:3, 3]) > self.min_translation_rel * depth
        c = (np.trace(last.T_world_cam[:3, :3].T @ T[:3, :3]) - 1.0) / 2.0
        turned = math.degrees(math.acos(float(np.clip(c, -1.0, 1.0)))) > self.min_rotation_deg
        return bool(moved or turned)

    def add(self, kf: Keyframe) -> None:
        """Add a keyframe, thinning older ones to stay within the memory bound."""
        if kf.nbytes > self.max_bytes:
            raise ValueError(f"a keyframe of {kf.nbytes} bytes exceeds the store's bound of {self.max_bytes}")
        with self._lock:
            self._kfs.append(kf)
            self.added += 1
            while len(self._kfs) > self.max_keyframes or sum(k.nbytes for k in self._kfs) > self.max_bytes:
                self._kfs.pop(self._thin_index())
                self.removed += 1
            self._version += 1

    def rescale_images(self, ratio: np.ndarray) -> None:
        """Multiply every keyframe's image by ``ratio`` (an (H, W) map at mapping resolution, rounded back
        to uint8): the run's photometric correction changed (``system.auto_vignette``) and relocalisation
        compares the keyframes with images corrected the new way."""
        ratio = np.asarray(ratio, np.float32)
        with self._lock:
            out = []
            for k in self._kfs:
                if k.image.shape == ratio.shape:
                    img = np.clip(k.image.astype(np.float32) * ratio + 0.5, 0, 255).astype(np.uint8)
                    k = dataclasses.replace(k, image=_frozen(img))
                out.append(k)
            self._kfs = out
            self._version += 1

    def apply_corrections(self, corrections: dict) -> int:
        """Move keyframes whose frame was re-estimated (``{frame index: T_world_cam or None}``;
        None removes the keyframe). Returns the number of keyframes changed."""
        changed = 0
        with self._lock:
            out = []
            for k in self._kfs:
                if k.index in corrections:
                    changed += 1
                    T = corrections[k.index]
                    if T is None:
                        self.removed += 1
                        continue
                    k = k.with_pose(T)
                out.append(k)
            self._kfs = out
            if changed:
                self._version += 1
        return changed

    def _thin_index(self) -> int:
        """Index of the keyframe to drop (lock held): an older scale first, else the most redundant."""
        kfs = self._kfs
        newest = kfs[-1].scale_id
        for i, k in enumerate(kfs[:-1]):
            if k.scale_id != newest:
                return i
        depth = kfs[-1].median_depth if np.isfinite(kfs[-1].median_depth) else 1.0
        best, best_d = 0, np.inf
        n = len(kfs)
        if n < 2:
            return best
        dist = pose_distances(np.stack([k.T_world_cam for k in kfs]), depth)
        np.fill_diagonal(dist, np.inf)
        # redundancy: distance to its two nearest keyframes
        near = np.sort(dist[:-1], axis=1)[:, :min(2, n - 1)].sum(axis=1)
        for i, d in enumerate(near.tolist()):
            if d < best_d - 1e-12:
                best, best_d = i, d
        return best


# ----------------------------------------------------------------------------------------------
# Whole-scene point cloud
# ----------------------------------------------------------------------------------------------

@dataclass
class PointCloud:
    points: np.ndarray             # (N, 3) float32, world frame
    colors: np.ndarray             # (N, 3) uint8 RGB
    idepth_var: np.ndarray         # (N,) float32
    keyframe: np.ndarray           # (N,) int32 index of the keyframe each point comes from
    pixel: np.ndarray              # (N, 2) int16 (u, v) pixel in that keyframe (mapping resolution)


def _neighbours(kfs: list[Keyframe], i: int, n: int, depth: float) -> list[int]:
    d = [(pose_distance(kfs[i].T_world_cam, k.T_world_cam, depth), j) for j, k in enumerate(kfs) if j != i]
    return [j for _, j in sorted(d)[:n]]


def depth_jump(idepth: np.ndarray, radius: int = 2) -> np.ndarray:
    """Per pixel, the largest relative inverse-depth difference ``|d_q - d_p| / d_p`` to a hypothesis
    ``q`` within ``radius`` pixels (0 where there is none; NaN where ``p`` has no hypothesis)."""
    from ._cloud_kernels import depth_jump_kernel
    D = np.array(idepth, np.float64)
    out = np.empty_like(D)
    depth_jump_kernel(D, int(radius), out)
    return out


def _flat_clipped(image: np.ndarray, level: float) -> np.ndarray:
    """Pixels that, with their 8 neighbours, are at or above ``level`` (clipped flat)."""
    return cv2.erode((np.asarray(image) >= level).astype(np.uint8), np.ones((3, 3), np.uint8),
                     borderType=cv2.BORDER_REPLICATE) > 0


def scene_cloud(keyframes, max_rel_std: float = 0.5, rel_tol: float = 0.07, neighbours: int = 10,
                min_support: int = 1, min_agree: float = 0.5, window: int = 1, max_jump: float = 0.1,
                voxel: float = 0.0, clipped: float = 250.0) -> PointCloud:
    """All keyframes' converged points in the world frame, coloured from their images.

    Outliers are removed four times:

    * by variance: the relative depth standard deviation is below ``max_rel_std``;
    * where clipping flattened the image: a point whose keyframe pixel and its 8 neighbours are all at or
      above ``clipped`` (grey level; 256 keeps them) is a hypothesis the filter kept unobserved through
      the clipping (``mapping.keep_clipped``): it could not be checked against that image;
    * at depth discontinuities: no hypothesis within 2 pixels of the point (in its keyframe) differs
      from it by more than ``max_jump`` in relative inverse depth. Points on an occlusion boundary are
      where the semi-dense map smears foreground into background; they were most of the far outliers
      on ICL (``benchmarks/cloud_icl_variants.md``);
    * by cross-keyframe consistency: a point is kept when at least ``min_support`` of its
      ``neighbours`` nearest keyframes (by pose) have a hypothesis within ``window`` pixels of its
      projection whose inverse depth agrees within ``rel_tol``, and at least ``min_agree`` of the
      neighbours that have a hypothesis there agree (the others contradict the point).

    ``voxel > 0`` (world units) averages the points (and colours) per voxel. Only keyframes of the
    newest scale are used. :func:`scene_cloud_parts` gives the same points one keyframe at a time.
    """
    parts = list(scene_cloud_parts(keyframes, max_rel_std, rel_tol, neighbours, min_support, min_agree, window,
                                   max_jump, clipped))
    if not parts:
        return PointCloud(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8), np.zeros(0, np.float32),
                          np.zeros(0, np.int32), np.zeros((0, 2), np.int16))
    cloud = PointCloud(*(np.concatenate([getattr(p, f.name) for p in parts])
                         for f in dataclasses.fields(PointCloud)))
    return voxel_downsample(cloud, voxel) if voxel > 0 else cloud


def scene_cloud_parts(keyframes, max_rel_std: float = 0.5, rel_tol: float = 0.07, neighbours: int = 10,
                      min_support: int = 1, min_agree: float = 0.5, window: int = 1, max_jump: float = 0.1,
                      clipped: float = 250.0):
    """The points of :func:`scene_cloud` (without ``voxel``), one :class:`PointCloud` per keyframe
    that keeps points, in the same order: a large cloud can be written without holding all of it."""
    from ._cloud_kernels import support_counts
    kfs = keyframes.current() if isinstance(keyframes, KeyframeStore) else list(keyframes)
    if kfs:
        kfs = [k for k in kfs if k.scale_id == kfs[-1].scale_id]
    depths = [k.median_depth for k in kfs if np.isfinite(k.median_depth)]
    depth = float(np.median(depths)) if depths else 1.0
    for i, kf in enumerate(kfs):
        p_cam, (v, u), var = kf.points(max_rel_std)
        if np.isfinite(max_jump) and len(u):
            smooth = depth_jump(kf.idepth)[v, u] <= max_jump
            p_cam, u, v, var = p_cam[smooth], u[smooth], v[smooth], var[smooth]
        if clipped <= 255 and len(u):
            seen = ~_flat_clipped(kf.image, clipped)[v, u]
            p_cam, u, v, var = p_cam[seen], u[seen], v[seen], var[seen]
        if len(u) == 0:
            continue
        p_world = transform_points(kf.T_world_cam, p_cam)
        if min_support > 0 and len(kfs) > 1:
            count = np.zeros(len(u), np.int64)      # neighbours that agree with each point
            seen_n = np.zeros(len(u), np.int64)     # neighbours with a hypothesis near it
            for j in _neighbours(kfs, i, neighbours, depth):
                kj = kfs[j]
                c = kj.camera
                support_counts(transform_points(inverse_se3(kj.T_world_cam), p_world), c.fx, c.fy, c.cx, c.cy,
                               int(c.width), int(c.height), kj.idepth, float(rel_tol), int(window), count, seen_n)
            keep = (count >= min_support) & (count >= min_agree * seen_n)
            p_world, u, v, var = p_world[keep], u[keep], v[keep], var[keep]
        if len(u) == 0:
            continue
        if kf.color_jpg is not None:
            col = kf.color[v, u][:, ::-1]                   # BGR -> RGB
        else:
            col = np.repeat(kf.image[v, u][:, None], 3, axis=1)
        # compact types (a run's cloud has millions of points): float32 positions and variances,
        # int32 keyframe indices, int16 pixels (mapping resolution)
        yield PointCloud(p_world.astype(np.float32), np.asarray(col, np.uint8), var.astype(np.float32),
                         np.full(len(u), kf.index, np.int32), np.stack([u, v], axis=1).astype(np.int16))


def voxel_downsample(cloud: PointCloud, voxel: float) -> PointCloud:
    """One point per ``voxel``-sized cell: the mean position and colour, the smallest variance."""
    if len(cloud.points) == 0:
        return cloud
    key = np.floor(cloud.points.astype(np.float64) / voxel).astype(np.int64)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    m = len(counts)
    pts = np.zeros((m, 3))
    col = np.zeros((m, 3))
    np.add.at(pts, inv, cloud.points)
    np.add.at(col, inv, cloud.colors.astype(np.float64))
    var = np.full(m, np.inf)
    np.minimum.at(var, inv, cloud.idepth_var)
    first = np.zeros(m, np.int64)
    first[inv[::-1]] = np.arange(len(inv))[::-1]
    return PointCloud((pts / counts[:, None]).astype(np.float32), np.rint(col / counts[:, None]).astype(np.uint8),
                      var.astype(np.float32), cloud.keyframe[first], cloud.pixel[first])
