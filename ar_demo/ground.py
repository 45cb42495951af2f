"""Ground plane of the AR world model (thesis 5.3.2).

* The **normal** is the up direction: the low-pass filtered accelerometer. The accelerometer
  measures the specific force in the camera frame, which reads ``+g`` pointing *up* at rest, so
  ``up_world = normalize(lowpass(R_world_cam @ acc_cam))`` (filtering in the world frame, where
  gravity is constant, so camera rotation does not smear the estimate).
* The **height** is the lowest height supported by at least ``min_support`` depth-map samples
  within a band, and then the highest of those supporting samples, so small bumps are covered by a
  smooth surface to drive on.
* **Refinement** (our addition, ``ground_refine_max_deg``): a short low-pass of a hand-held
  accelerometer is biased by the motion (~1 deg, i.e. several cm of height error a few metres
  away), so the normal is replaced by that of the dominant map plane (RANSAC + least squares)
  within a few degrees of the IMU direction when there is one. Any plane parallel to the floor
  (e.g. a table top) gives the right normal; the height rule then still picks the floor.
* **Fallback without an IMU** (documented choice): RANSAC over the map points for the dominant
  plane whose normal lies within ``ransac_max_angle_deg`` of the first camera's up direction
  (``-y`` of the first camera; handheld sequences start roughly upright), refined by a least-squares
  fit to its inliers, oriented towards the camera; its height is then chosen by the same
  lowest-supported rule along the refined normal.

The plane is ``{X : n . X = height}`` in world coordinates, ``n`` pointing up (towards the camera).

Imports: numpy, lite_vo (camera/geometry) only.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lite_vo.camera import PinholeIntrinsics
from lite_vo.errors import InputError
from lite_vo.geometry import transform_points


@dataclass(frozen=True)
class GroundPlane:
    """``n . X = height`` in world coordinates; ``normal_world`` is the unit up direction."""
    normal_world: np.ndarray
    height: float
    source: str = "imu"            # "imu" | "ransac" | "given"

    def signed_distance(self, points_world: np.ndarray) -> np.ndarray:
        return np.asarray(points_world, dtype=np.float64) @ self.normal_world - self.height

    def idepth_grid(self, T_world_cam: np.ndarray, intrinsics: PinholeIntrinsics) -> np.ndarray:
        """Inverse depth of the plane along each pixel ray of ``intrinsics`` (0 where the ray misses)."""
        h, w = intrinsics.height, intrinsics.width
        v, u = np.mgrid[0:h, 0:w].astype(np.float64)
        return self.idepth_at(T_world_cam, intrinsics, u, v)

    def idepth_at(self, T_world_cam, intrinsics: PinholeIntrinsics, u, v) -> np.ndarray:
        """Inverse depth (z-depth) of the plane seen through pixels (u, v); 0 where it is not hit."""
        T = np.asarray(T_world_cam, dtype=np.float64)
        R, C = T[:3, :3], T[:3, 3]
        n_cam = R.T @ self.normal_world            # plane normal in the camera frame
        ray_dot = ((np.asarray(u) - intrinsics.cx) / intrinsics.fx * n_cam[0]
                   + (np.asarray(v) - intrinsics.cy) / intrinsics.fy * n_cam[1] + n_cam[2])
        dist = self.height - float(self.normal_world @ C)   # < 0 when the camera is above the plane
        # depth z along the ray with z-component 1: n.(C + z R d) = height  ->  z = dist / (n_cam . d)
        with np.errstate(divide="ignore", invalid="ignore"):
            idepth = ray_dot / dist
        idepth = np.where(np.isfinite(idepth) & (idepth > 0), idepth, 0.0)
        return idepth


class GravityFilter:
    """Streaming low-pass filter of the accelerometer, in the world frame.

    First-order filter with time constant ``tau_s``: ``g <- g + a (R acc - g)`` with
    ``a = max(dt / (tau + dt), 1 / k)`` for the k-th sample, i.e. a plain running mean until the
    exponential window is full (so the first sample does not dominate). ``update(acc_cam,
    R_world_cam, timestamps)`` with one or N specific-force samples in the camera frame;
    ``up_world`` is the current unit up direction (None before the first sample).
    """

    def __init__(self, tau_s: float):
        self.tau_s = float(tau_s)
        self._state: np.ndarray | None = None
        self._count = 0
        self._last_t: float | None = None

    def update(self, acc_cam: np.ndarray, R_world_cam: np.ndarray | None = None, timestamps=None) -> None:
        acc = np.atleast_2d(np.asarray(acc_cam, dtype=np.float64))
        R = np.eye(3) if R_world_cam is None else np.asarray(R_world_cam, dtype=np.float64)
        acc_world = acc @ R.T if R.ndim == 2 else np.einsum("nij,nj->ni", R, acc)
        ts = (np.full(len(acc), np.nan) if timestamps is None
              else np.atleast_1d(np.asarray(timestamps, dtype=np.float64)))
        for a, t in zip(acc_world, ts):
            if not np.all(np.isfinite(a)):
                continue
            self._count += 1
            dt = (t - self._last_t) if (self._last_t is not None and np.isfinite(t)) else 0.0
            if np.isfinite(t):
                self._last_t = float(t)
            k = 1.0 / self._count
            if self.tau_s > 0 and dt > 0:
                k = max(k, dt / (self.tau_s + dt))
            elif self.tau_s == 0:
                k = 1.0
            self._state = a.copy() if self._state is None else self._state + k * (a - self._state)

    @property
    def up_world(self) -> np.ndarray | None:
        if self._state is None:
            return None
        n = np.linalg.norm(self._state)
        return self._state / n if n > 0 else None


def up_from_accelerometer(acc_cam: np.ndarray, tau_s: float, R_world_cam: np.ndarray | None = None,
                          timestamps=None) -> np.ndarray:
    """Unit up direction from accelerometer samples (N, 3) (camera frame, +g up at rest).

    ``R_world_cam``: (3, 3) or per-sample (N, 3, 3) camera orientations; without it the result is in
    the camera frame of the samples. Without timestamps the filter is the plain mean.
    """
    f = GravityFilter(tau_s)
    f.update(acc_cam, R_world_cam, timestamps)
    if f.up_world is None:
        raise InputError("accelerometer: no finite samples to estimate gravity")
    return f.up_world


def map_points_world(idepth: np.ndarray, intrinsics: PinholeIntrinsics, T_world_cam: np.ndarray,
                     valid: np.ndarray | None = None) -> np.ndarray:
    """World points (N, 3) of the valid pixels of an inverse-depth map (idepth > 0, finite)."""
    idepth = np.asarray(idepth, dtype=np.float64)
    ok = np.isfinite(idepth) & (idepth > 0)
    if valid is not None:
        ok &= valid
    v, u = np.nonzero(ok)
    return transform_points(T_world_cam, intrinsics.unproject_idepth(u, v, idepth[v, u]))


def lowest_supported_height(heights: np.ndarray, min_support: int, band: float) -> float | None:
    """Lowest height with >= ``min_support`` samples within ``band`` above it; returns the highest of
    those supporting samples (None if no height has enough support)."""
    h = np.sort(np.asarray(heights, dtype=np.float64)[np.isfinite(heights)])
    n = int(min_support)
    if h.size < n or n < 1:
        return None
    spread = h[n - 1:] - h[:h.size - n + 1]        # window of n consecutive samples starting at i
    ok = np.nonzero(spread <= band)[0]
    if ok.size == 0:
        return None
    i = int(ok[0])
    hi = np.searchsorted(h, h[i] + band, side="right")
    return float(h[hi - 1])


def _subsample(points: np.ndarray, max_points: int, rng: np.random.Generator) -> np.ndarray:
    if len(points) > max_points:
        return points[rng.choice(len(points), max_points, replace=False)]
    return points


def ground_from_up(points_world: np.ndarray, up_world: np.ndarray, min_support: int, band: float,
                   source: str = "imu") -> GroundPlane | None:
    """Ground plane with the given up direction and the lowest-supported height rule."""
    n = np.asarray(up_world, dtype=np.float64)
    n = n / np.linalg.norm(n)
    h = lowest_supported_height(np.asarray(points_world) @ n, min_support, band)
    if h is None:
        return None
    return GroundPlane(n, h, source)


def ransac_ground(points_world: np.ndarray, up_hint: np.ndarray, iterations: int, inlier_dist: float,
                  max_angle_deg: float, rng: np.random.Generator) -> np.ndarray | None:
    """Fallback: normal (unit, oriented along ``up_hint``) of the dominant plane whose normal lies
    within ``max_angle_deg`` of ``up_hint``; None if no such plane is found."""
    P = np.asarray(points_world, dtype=np.float64)
    if len(P) < 3:
        return None
    up_hint = up_hint / np.linalg.norm(up_hint)
    cos_max = np.cos(np.deg2rad(max_angle_deg))
    best, best_count = None, 0
    idx = rng.integers(0, len(P), size=(int(iterations), 3))
    for a, b, c in idx:
        nrm = np.cross(P[b] - P[a], P[c] - P[a])
        ln = np.linalg.norm(nrm)
        if ln < 1e-12:
            continue
        nrm /= ln
        if nrm @ up_hint < 0:
            nrm = -nrm
        if nrm @ up_hint < cos_max:
            continue
        count = int(np.count_nonzero(np.abs((P - P[a]) @ nrm) < inlier_dist))
        if count > best_count:
            best, best_count = (nrm, P[a]), count
    if best is None:
        return None
    nrm, p0 = best
    inl = P[np.abs((P - p0) @ nrm) < inlier_dist]
    centred = inl - inl.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    refined = vt[-1]
    if refined @ up_hint < 0:
        refined = -refined
    return refined if refined @ up_hint >= cos_max else nrm


def estimate_ground_plane(points_world: np.ndarray, cfg, up_world: np.ndarray | None = None,
                          T_world_cam0: np.ndarray | None = None, scene_depth: float | None = None,
                          seed: int = 0) -> GroundPlane | None:
    """Ground plane from world map points and (optionally) the IMU up direction.

    ``cfg``: :class:`ar_demo.config.ARConfig`. ``T_world_cam0``: the camera the map was seen from
    (points farther than ``ground_max_dist_rel`` times the median distance are ignored). ``scene_depth``: typical (median) scene depth, the
    unit of the relative thresholds (estimated from the points and ``T_world_cam0`` when None).
    Without ``up_world`` the RANSAC fallback needs ``T_world_cam0`` (the first camera).
    """
    rng = np.random.default_rng(seed)
    P = np.asarray(points_world, dtype=np.float64)
    P = P[np.all(np.isfinite(P), axis=1)]
    if len(P) < max(3, cfg.ground_min_support):
        return None
    P = _subsample(P, cfg.ground_max_points, rng)
    centre = np.zeros(3) if T_world_cam0 is None else np.asarray(T_world_cam0)[:3, 3]
    dist = np.linalg.norm(P - centre, axis=1)
    if scene_depth is None:
        scene_depth = float(np.median(dist))
    # far points are noisy and amplify a small error of the normal into a height error
    P = P[dist <= cfg.ground_max_dist_rel * float(np.median(dist))]
    support = min(cfg.ground_min_support, len(P))
    band = cfg.ground_band_rel * scene_depth
    if up_world is not None:
        n = np.asarray(up_world, dtype=np.float64)
        source = "imu"
        if cfg.ground_refine_max_deg > 0:
            refined = ransac_ground(P, n, cfg.ransac_iterations, cfg.ransac_inlier_rel * scene_depth,
                                    cfg.ground_refine_max_deg, rng)
            if refined is not None:
                n, source = refined, "imu+map"
        return ground_from_up(P, n, support, band, source)
    if T_world_cam0 is None:
        raise InputError("ground plane: need either an accelerometer or the first camera pose")
    up_hint = -np.asarray(T_world_cam0, dtype=np.float64)[:3, 1]
    n = ransac_ground(P, up_hint, cfg.ransac_iterations, cfg.ransac_inlier_rel * scene_depth,
                      cfg.ransac_max_angle_deg, rng)
    if n is None:
        return None
    return ground_from_up(P, n, support, band, "ransac")
